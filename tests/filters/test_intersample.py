"""Inter-sample rows: a plan inside them is safe at every intermediate time (swept check)."""

from __future__ import annotations

import numpy as np
import pytest

from filters import Disc, MPCSafetyFilter, safe_halfspaces
from filters.intersample import arc_margin, intersample_rows
from filters.risk import risk_of_samples
from safe_nav_env.dynamics import double_integrator

DT, T = 0.2, 10
LOW, HIGH = np.full(2, -10.0), np.full(2, 10.0)


def test_arc_margin_is_the_largest_bow():
    rng = np.random.default_rng(0)
    normals = rng.normal(size=(50, 2))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    margin = arc_margin(normals, (LOW, HIGH), DT)
    lam = np.linspace(0.0, 1.0, 1001)[:, None]
    for h, m in zip(normals, margin, strict=True):
        corners = np.array([[a, b] for a in (-10, 10) for b in (-10, 10)])
        bow = -(DT**2 / 2) * lam * (1 - lam) * (corners @ h)[None, :]  # h . (y - chord)
        assert bow.max() == pytest.approx(m, rel=1e-6)
    assert margin.max() <= DT**2 / 8 * 10 * np.sqrt(2) + 1e-12


def _crossing_instance(rng, n_obstacles):
    """An ego running at 5 m/s along x, obstacles crossing its path, paired sample paths."""
    x0 = np.array([-2.0, rng.uniform(-0.3, 0.3), 5.0, 0.0])
    steps = np.arange(1, T + 1)[:, None] * DT
    starts = np.column_stack([rng.uniform(-0.5, 2.5, n_obstacles),
                              rng.uniform(-2.5, -1.0, n_obstacles)])
    velocity = np.column_stack([np.zeros(n_obstacles), rng.uniform(0.5, 1.5, n_obstacles)])
    nominal = starts[:, None, None] + velocity[:, None, None] * steps[None, None]
    walk = np.cumsum(rng.normal(0.0, 0.1, (n_obstacles, 100, T, 2)), axis=2)
    samples = nominal + walk  # (k, N, T, 2): each sample a path, random-walk noise
    reference = np.array([x0 + np.array([5.0 * DT * t, 0, 0, 0]) for t in range(T + 1)])
    return x0, reference, samples


def _worst_intermediate_risk(hs, samples, states, inputs, risk):
    """max over intervals [t, t+1], t >= 1, obstacles and 201 instants of R(loss)."""
    lam = np.linspace(0.0, 1.0, 201)
    s = lam * DT
    worst = -np.inf
    for t in range(1, T):  # interval [t, t+1] (step t is samples[:, :, t-1])
        y = states[t, :2] + s[:, None] * states[t, 2:] + 0.5 * s[:, None] ** 2 * inputs[t]
        for i in range(samples.shape[0]):
            h = hs.normals[i, t]  # the normal of step t+1
            o = ((1 - lam)[:, None, None] * samples[i, :, t - 1][None]
                 + lam[:, None, None] * samples[i, :, t][None])  # (L, N, 2): chords
            losses = (y @ h)[:, None] + 0.6 - o @ h  # intrusion depth per sample
            worst = max(worst, float(risk_of_samples(losses, risk, 0.2, 0.05).max()))
    return worst


def _filtered(risk, seed, *, intersample):
    rng = np.random.default_rng(seed)
    k = int(rng.integers(1, 4))
    x0, reference, samples = _crossing_instance(rng, k)
    A, B, C = double_integrator(DT)
    ego, shapes = Disc(0.3), [Disc(0.3)] * k
    hs = safe_halfspaces(reference[1:, :2], samples, ego_shape=ego, obstacle_shapes=shapes,
                         risk=risk, alpha=0.2, delta=0.1, epsilon=0.05)
    rows = (hs.normals, hs.offsets)
    if intersample:
        extra = intersample_rows(hs, samples, ego_shape=ego, obstacle_shapes=shapes,
                                 input_bounds=(LOW, HIGH), dt=DT)
        rows = (extra.normals, extra.offsets)
    mpc = MPCSafetyFilter(A, B, C, horizon=T, Q=4 * np.eye(4), Q_terminal=25 * np.eye(4),
                          R=np.eye(2), input_bounds=(LOW, HIGH), n_obstacles=2 * k)
    result = mpc.solve(x0, reference, rows)
    if result.status.value != "optimal":
        return None
    return _worst_intermediate_risk(hs, samples, np.asarray(result.states),
                                    np.asarray(result.inputs), risk)


@pytest.mark.parametrize("risk", ["mean", "cvar", "dr_cvar"])
def test_plan_inside_the_rows_is_safe_between_samples(risk):
    worst = [_filtered(risk, seed, intersample=True) for seed in range(30)]
    solved = [w for w in worst if w is not None]
    assert len(solved) >= 20  # most crossing instances are feasible
    assert max(solved) <= 0.1 + 1e-6  # R(loss) <= delta at every intermediate time


@pytest.mark.parametrize("risk", ["cvar", "dr_cvar"])
def test_the_sample_rows_alone_are_not_safe_between_samples(risk):
    """The same check fails with the paper's rows only: it can fail, and the rows matter."""
    worst = [_filtered(risk, seed, intersample=False) for seed in range(30)]
    assert max(w for w in worst if w is not None) > 0.1 + 1e-3


def test_start_violation_reports_the_first_interval():
    samples = np.zeros((1, 5, T, 2)) + np.array([1.0, 0.0])
    hs = safe_halfspaces(np.zeros((T, 2)), samples, ego_shape=Disc(0.3),
                         obstacle_shapes=[Disc(0.3)], risk="mean", delta=0.0)
    rows = intersample_rows(hs, samples, ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.3)],
                            input_bounds=(LOW, HIGH), dt=DT, current_position=np.zeros(2),
                            current_obstacles=np.array([[0.5, 0.0]]))
    # now: obstacle 0.5 m ahead, discs 0.6: overlap of 0.1 plus the bow
    assert rows.start_violation[0] == pytest.approx(0.1 + rows.margins[0, 0])

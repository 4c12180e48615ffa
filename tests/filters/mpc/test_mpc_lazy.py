"""The DAQP back end's lazy (screened) rows are exact: they equal the QP with every row.

:mod:`filters.mpc.backends.daqp` solves long horizons with the rows near-active at a
guess, checks every row at the answer and adds the violated ones. These tests compare
that path with the same back end holding every row (``lazy=False``) and with the CVXPY
reference, on hard, soft and recovery QPs, feasible and infeasible, at short and long
horizons; they force extra rounds by screening nothing in, and check that the warm start
from the previous step changes nothing but the time.
"""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.filter_qp import double_integrator, filter_kwargs
from filters.mpc import FilterStatus, MPCSafetyFilter, stopping_terminal_set
from filters.mpc.backends import daqp as daqp_module
from filters.mpc.backends.daqp import DAQPBackend

TS = 0.2
A, B, C = double_integrator(TS)
K = 3
MODES = ["hard", "soft", "recovery"]


def make(horizon: int, mode: str, *, lazy: bool, objective: str = "trajectory",
         backend: str = "daqp") -> MPCSafetyFilter:
    """A filter whose DAQP QPs (hard and recovery) have the given ``lazy``."""
    kwargs = filter_kwargs(horizon, K)
    if objective == "first_input":
        kwargs.pop("Q")
        kwargs.pop("Q_terminal")
    kwargs.update(objective=objective, soft=mode == "soft", skip_feasible_reference=False)
    if mode == "recovery":
        kwargs["terminal_set"] = stopping_terminal_set(
            TS, kwargs["input_bounds"], kwargs["position_bounds"])
    if backend == "cvxpy":
        return MPCSafetyFilter(A, B, C, backend="cvxpy", **kwargs)
    mpc = MPCSafetyFilter(A, B, C, backend="daqp", **kwargs)
    mpc._primary = DAQPBackend(mpc.problem, lazy=lazy)
    mpc._recovery = DAQPBackend(mpc._recovery.problem, lazy=lazy)
    return mpc


def crossing(rng: np.random.Generator, horizon: int, mode: str, x0=None,
             wall: bool = True) -> dict:
    """The ego crossing toward obstacles; tightened rows (soft, recovery), the ego outside
    the arena (recovery), an unreachable wall now and then (hard: infeasible)."""
    speed = min(1.5, 8.0 / (horizon * TS))
    if x0 is None:
        x0 = np.array([rng.uniform(-4.5, -2.0), rng.uniform(-1, 1), speed, rng.normal(0, 0.2)])
    steps = np.arange(horizon + 1)
    reference = np.zeros((horizon + 1, 4))
    reference[:, 0] = x0[0] + speed * TS * steps
    reference[:, 1] = x0[1] + rng.normal(0, 0.3)
    reference[:, 2] = speed
    start = x0[:2] + np.column_stack([rng.uniform(0.8, 4.0, K), rng.uniform(-1.0, 1.0, K)])
    velocity = rng.normal(0.0, 0.4, (K, 2))
    predicted = start[:, None] + velocity[:, None] * TS * steps[None, 1:, None]
    direction = predicted - reference[None, 1:, :2]
    normals = direction / np.linalg.norm(direction, axis=-1, keepdims=True)
    offsets = np.einsum("ktd,ktd->kt", normals, predicted) - rng.uniform(0.5, 0.9, (K, 1))
    if mode in ("soft", "recovery"):
        offsets = offsets - rng.uniform(0.0, 2.0)
    if mode == "recovery" and rng.random() < 0.5:
        x0 = x0.copy()
        x0[0], x0[2] = -5.0 - rng.uniform(0.05, 0.5), -rng.uniform(0.0, 1.0)
    if mode == "hard" and rng.random() < 0.25 and wall:
        offsets = offsets.copy()
        offsets[0] = -100.0 * np.abs(normals[0, :, 0]) - 10.0  # unreachable: infeasible
    return {"x0": x0, "reference_states": reference, "halfspaces": (normals, offsets)}


def solve(mpc: MPCSafetyFilter, case: dict):
    return mpc.solve(case["x0"], case["reference_states"], case["halfspaces"])


def penalised(result, rho: float = 1e6) -> float:
    """Cost (8) plus the L1 penalty of every violation: what the soft QPs minimise."""
    slack = 0.0 if result.slack is None else float(result.slack.sum())
    return result.objective + rho * (slack + result.bound_slack)


def assert_same(lazy, full):
    """Same status; without slack the same inputs (1e-6). With slack the L1 penalty
    (rho = 1e6) dominates the cost, so the soft QP pins its minimiser only loosely (as
    in test_mpc_backends.py): the same penalised objective, slacks and first input."""
    assert lazy.status == full.status, (lazy.solver_status, full.solver_status)
    if lazy.status in (FilterStatus.SOFT, FilterStatus.RECOVERY):
        # DAQP resolves each violation to ~1e-6 m (its primal tolerance), so with tens of
        # violated rows and rho = 1e6 the penalised objectives agree to ~1e-5 relative.
        assert penalised(lazy) == pytest.approx(penalised(full), rel=3e-5, abs=1e-6)
        np.testing.assert_allclose(lazy.inputs[0], full.inputs[0], rtol=0, atol=3e-3)
        np.testing.assert_allclose(lazy.slack, full.slack, rtol=0, atol=1e-4)
        assert lazy.bound_slack == pytest.approx(full.bound_slack, abs=1e-4)
    else:
        np.testing.assert_allclose(lazy.inputs, full.inputs, rtol=0, atol=1e-6)
        assert lazy.objective == pytest.approx(full.objective, rel=1e-7, abs=1e-7)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("horizon", [10, 40])
@pytest.mark.parametrize("objective", ["trajectory", "first_input"])
def test_lazy_rows_equal_every_row(horizon, mode, objective):
    lazy = make(horizon, mode, lazy=True, objective=objective)
    full = make(horizon, mode, lazy=False, objective=objective)
    rng = np.random.default_rng([horizon, MODES.index(mode), len(objective)])
    statuses, rounds = set(), []
    for _ in range(8):
        case = crossing(rng, horizon, mode)
        ours, theirs = solve(lazy, case), solve(full, case)
        assert_same(ours, theirs)
        statuses.add(ours.status)
        rounds.append(lazy._primary.rounds)
    assert len(statuses) >= 2 or mode == "soft", statuses  # feasible and infeasible steps


@pytest.mark.parametrize("mode", MODES)
def test_rows_missed_by_the_screening_are_added_until_none_is_violated(monkeypatch, mode):
    """With no margin only the rows violated at the guess enter; the check then adds the
    ones the relaxed answers violate, over several rounds, to the same optimum."""
    monkeypatch.setattr(daqp_module, "SCREEN_MARGIN", 0.0)
    horizon = 30
    lazy = make(horizon, mode, lazy=True)
    full = make(horizon, mode, lazy=False)
    rng = np.random.default_rng([5, MODES.index(mode)])
    rounds = []
    for _ in range(8):
        case = crossing(rng, horizon, mode)
        lazy.reset()
        ours, theirs = solve(lazy, case), solve(full, case)
        assert_same(ours, theirs)
        rounds.append(lazy._primary.rounds)
    assert max(rounds) >= 2, rounds


def test_the_warm_start_changes_the_time_not_the_answer():
    """Along a closed-loop episode the lazy back end is warm-started from the previous
    step; it returns what a fresh back end returns (to 1e-7), and after reset() what a
    fresh one returns (to 1e-9)."""
    horizon = 40
    persistent = make(horizon, "hard", lazy=True)
    rng = np.random.default_rng(21)
    case = crossing(rng, horizon, "hard", x0=np.array([-4.5, 0.0, 1.0, 0.0]))
    x = case["x0"]
    warm_used = 0
    for _ in range(15):
        case = crossing(np.random.default_rng(21), horizon, "hard", x0=x, wall=False)
        warm_used += persistent._primary._guess is not None
        kept = solve(persistent, case)
        fresh = solve(make(horizon, "hard", lazy=True), case)
        assert kept.status == fresh.status
        np.testing.assert_allclose(kept.inputs, fresh.inputs, rtol=0, atol=1e-7)
        x = A @ x + B @ kept.inputs[0]
    assert warm_used >= 10
    persistent.reset()
    assert persistent._primary._guess is None
    again = solve(persistent, case)
    fresh = solve(make(horizon, "hard", lazy=True), case)
    np.testing.assert_allclose(again.inputs, fresh.inputs, rtol=0, atol=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("mode", MODES)
def test_lazy_rows_equal_the_cvxpy_reference_at_t80(mode):
    horizon = 80
    lazy = make(horizon, mode, lazy=True)
    reference = make(horizon, mode, lazy=True, backend="cvxpy")
    rng = np.random.default_rng([80, MODES.index(mode)])
    for _ in range(3):
        case = crossing(rng, horizon, mode)
        ours, theirs = solve(lazy, case), solve(reference, case)
        assert ours.status == theirs.status, (ours.solver_status, theirs.solver_status)
        if ours.status is FilterStatus.OPTIMAL:
            np.testing.assert_allclose(ours.inputs, theirs.inputs, atol=2e-4)
            assert ours.objective == pytest.approx(theirs.objective, rel=1e-5, abs=1e-4)
        else:
            np.testing.assert_allclose(ours.inputs[0], theirs.inputs[0], atol=3e-3)
            assert ours.bound_slack == pytest.approx(theirs.bound_slack, abs=1e-4)

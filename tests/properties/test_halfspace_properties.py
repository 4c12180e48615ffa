"""Hypothesis properties of the empirical CVaR and the safe halfspaces (the paper's claims)."""

from __future__ import annotations

import warnings

import hypothesis.extra.numpy as hnp
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from filters.geometry import Disc
from filters.halfspace_cvxpy import TIGHT_CLARABEL, cvxpy_halfspace
from filters.halfspaces import safe_halfspaces
from filters.risk import empirical_cvar

DISC = Disc(0.3)
Y_REF = np.array([-0.9, -0.8])

coordinates = st.floats(-2.0, 2.0, allow_nan=False, allow_infinity=False)
alphas = st.floats(0.05, 1.0)
epsilons = st.floats(0.0, 0.5)
deltas = st.floats(-0.5, 0.5)


@st.composite
def sample_sets(draw, max_samples: int = 40) -> np.ndarray:
    """Planar samples (N, 2), with duplicates and ties allowed."""
    n = draw(st.integers(1, max_samples))
    return draw(hnp.arrays(np.float64, (n, 2), elements=coordinates))


def offset(samples: np.ndarray, **options) -> float:
    """Offset of one obstacle at one step."""
    hs = safe_halfspaces(
        Y_REF[None], samples[None, :, None, :], ego_shape=DISC, obstacle_shapes=[DISC], **options
    )
    return float(hs.offsets[0, 0])


def normal(samples: np.ndarray) -> np.ndarray:
    hs = safe_halfspaces(
        Y_REF[None], samples[None, :, None, :], ego_shape=DISC, obstacle_shapes=[DISC]
    )
    return hs.normals[0, 0]


def solve(samples, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        result = cvxpy_halfspace(
            samples, normal(samples), 0.6, solver_options=TIGHT_CLARABEL, **options
        )
    assert result.status.startswith("optimal"), result.status
    return result


@given(
    x=hnp.arrays(np.float64, st.integers(1, 60), elements=st.floats(-1e3, 1e3)),
    alpha=st.floats(1e-3, 1.0),
)
def test_cvar_is_the_minimum_over_tau(x, alpha):
    """CVaR = min_tau tau + mean((x - tau)+)/alpha; the minimum sits at a sample value."""
    objective = x + np.mean(np.maximum(x[None, :] - x[:, None], 0.0), axis=1) / alpha
    exact = np.min(objective)
    assert abs(empirical_cvar(x, alpha) - exact) <= 1e-9 * (1.0 + np.max(np.abs(x)))
    assert np.min(x) - 1e-9 <= empirical_cvar(x, alpha) <= np.max(x) + 1e-9


@given(samples=sample_sets(), alpha=alphas, delta=deltas, epsilon=epsilons)
def test_offsets_are_ordered_mean_cvar_dr_cvar(samples, alpha, delta, epsilon):
    options = dict(alpha=alpha, delta=delta)
    b_mean = offset(samples, risk="mean", **options)
    b_cvar = offset(samples, risk="cvar", **options)
    b_dr = offset(samples, risk="dr_cvar", epsilon=epsilon, **options)
    assert b_mean >= b_cvar - 1e-12 and b_cvar >= b_dr - 1e-12
    assert abs(b_dr - (b_cvar - epsilon / alpha)) <= 1e-9


@given(samples=sample_sets(), alpha=alphas, d1=deltas, d2=deltas, e1=epsilons, e2=epsilons)
def test_offsets_monotone_in_delta_and_epsilon(samples, alpha, d1, d2, e1, e2):
    (d_lo, d_hi), (e_lo, e_hi) = sorted((d1, d2)), sorted((e1, e2))
    options = dict(alpha=alpha, risk="dr_cvar")
    assert (
        offset(samples, delta=d_hi, epsilon=e_lo, **options)
        >= offset(samples, delta=d_lo, epsilon=e_lo, **options) - 1e-12
    )
    assert (
        offset(samples, delta=d_lo, epsilon=e_hi, **options)
        <= offset(samples, delta=d_lo, epsilon=e_lo, **options) + 1e-12
    )


@given(samples=sample_sets(), delta=deltas)
def test_limits_epsilon_zero_and_alpha_one(samples, delta):
    cvar = offset(samples, risk="cvar", delta=delta)
    assert abs(offset(samples, risk="dr_cvar", epsilon=0.0, delta=delta) - cvar) <= 1e-12
    mean = offset(samples, risk="mean", delta=delta)
    assert abs(offset(samples, risk="cvar", alpha=1.0, delta=delta) - mean) <= 1e-12


@given(
    samples=sample_sets(max_samples=30),
    risk=st.sampled_from(["mean", "cvar", "dr_cvar"]),
    alpha=alphas,
    delta=deltas,
    epsilon=epsilons,
)
def test_closed_forms_equal_proposition_one_lp(samples, risk, alpha, delta, epsilon):
    """Unbounded support: the closed forms are the optimum of the CVXPY LPs (to 1e-6)."""
    options = dict(risk=risk, alpha=alpha, delta=delta, epsilon=epsilon)
    assert abs(offset(samples, **options) - solve(samples, **options).offset) <= 1e-6


@st.composite
def supported_instances(draw):
    """Samples, and a polytope {V p <= v} holding them (possibly unbounded)."""
    samples = draw(sample_sets(max_samples=25))
    n_faces = draw(st.integers(1, 5))
    angles = draw(hnp.arrays(np.float64, n_faces, elements=st.floats(0.0, 2 * np.pi)))
    V = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    slack = draw(hnp.arrays(np.float64, n_faces, elements=st.floats(0.0, 1.0)))
    v = (samples @ V.T).max(axis=0) + slack
    return samples, V, v


@given(instance=supported_instances(), alpha=alphas, epsilon=epsilons)
def test_polytope_support_is_proposition_one_and_never_more_conservative(instance, alpha, epsilon):
    samples, V, v = instance
    options = dict(alpha=alpha, epsilon=epsilon)
    bounded = offset(samples, support=(V, v), **options)
    assert bounded >= offset(samples, **options) - 1e-9
    assert abs(bounded - solve(samples, support=(V, v), **options).offset) <= 1e-6


@given(
    seed=st.integers(0, 2**32 - 1),
    n_obstacles=st.integers(0, 3),
    horizon=st.integers(1, 4),
    n_samples=st.integers(1, 20),
    risk=st.sampled_from(["mean", "cvar", "dr_cvar"]),
)
def test_vectorised_call_equals_per_obstacle_per_step_calls(
    seed, n_obstacles, horizon, n_samples, risk
):
    rng = np.random.default_rng(seed)
    y_ref = rng.normal(size=(horizon, 2))
    samples = rng.normal(size=(n_obstacles, n_samples, horizon, 2))
    shapes = [Disc(float(r)) for r in rng.uniform(0, 0.5, n_obstacles)]
    hs = safe_halfspaces(y_ref, samples, ego_shape=DISC, obstacle_shapes=shapes, risk=risk)
    assert hs.offsets.shape == (n_obstacles, horizon)
    for i in range(n_obstacles):
        for t in range(horizon):
            single = safe_halfspaces(
                y_ref[t : t + 1],
                samples[i : i + 1, :, t : t + 1],
                ego_shape=DISC,
                obstacle_shapes=[shapes[i]],
                risk=risk,
            )
            assert abs(hs.offsets[i, t] - single.offsets[0, 0]) <= 1e-12
            assert np.allclose(hs.normals[i, t], single.normals[0, 0], rtol=0, atol=1e-14)

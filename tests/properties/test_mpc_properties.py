"""Property tests of the MPC safety filter on random instances (hypothesis, CI profile).

Invariants: the fast filter agrees with the CVXPY reference; an OPTIMAL answer
meets every halfspace and bound; a safe, dynamically consistent reference passes
through unchanged; the result is never NaN and its states follow the dynamics;
the fallback sequence is SHIFTED x (T - 1) then BRAKE whatever the instance.
"""

from __future__ import annotations

from functools import cache

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from filters.mpc import FilterResult, FilterStatus, MPCSafetyFilter
from tests.test_mpc import (
    KWARGS,
    A,
    B,
    C,
    T,
    cvxpy_filter,
    infeasible_halfspaces,
    random_instance,
    solve,
)

seeds = st.integers(min_value=0, max_value=2**32 - 1)


@cache
def fast(n_obstacles: int = 3, soft: bool = False) -> MPCSafetyFilter:
    """One filter per configuration, reused across examples (update, not rebuild)."""
    return MPCSafetyFilter(A, B, C, soft=soft, **{**KWARGS, "n_obstacles": n_obstacles})


def assert_well_formed(result: FilterResult, x0: np.ndarray) -> None:
    assert result.inputs.shape == (T, 2) and result.states.shape == (T + 1, 4)
    assert np.all(np.isfinite(result.inputs)) and np.all(np.isfinite(result.states))
    assert np.isfinite(result.objective) and np.isfinite(result.solve_time)
    assert np.all(np.abs(result.inputs) <= 5.0)
    np.testing.assert_array_equal(result.states[0], x0)
    np.testing.assert_allclose(
        result.states[1:], result.states[:-1] @ A.T + result.inputs @ B.T, atol=1e-10
    )
    if result.slack is not None:
        assert np.all(np.isfinite(result.slack)) and np.all(result.slack >= 0.0)


@given(seed=seeds, k=st.integers(0, 3), soft=st.booleans(), with_inputs=st.booleans())
def test_fast_filter_equals_cvxpy_reference(seed, k, soft, with_inputs):
    instance = random_instance(np.random.default_rng(seed), k, with_inputs=with_inputs)
    ours_filter, reference = fast(soft=soft), cvxpy_filter(soft=soft)
    ours_filter.reset()
    reference.reset()
    ours, theirs = solve(ours_filter, instance), solve(reference, instance)
    assert_well_formed(ours, instance["x0"])
    assert ours.status == theirs.status
    if ours.solved:
        np.testing.assert_allclose(ours.inputs, theirs.inputs, atol=1e-4)
        assert abs(ours.objective - theirs.objective) <= 1e-4 + 1e-6 * abs(theirs.objective)


@given(seed=seeds, k=st.integers(1, 3))
def test_optimal_answers_satisfy_every_halfspace(seed, k):
    instance = random_instance(np.random.default_rng(seed), k)
    result = solve(fast(), instance)
    assert_well_formed(result, instance["x0"])
    if result.status is FilterStatus.OPTIMAL:
        normals, offsets = instance["halfspaces"]
        positions = result.states[1:] @ C.T
        assert np.max(np.einsum("ktd,td->kt", normals, positions) - offsets) <= 1e-6
        assert np.max(np.abs(positions)) <= 5.0 + 1e-6


@given(
    seed=seeds,
    k=st.integers(0, 3),
    margin=st.floats(min_value=1e-3, max_value=2.0),
)
def test_safe_reference_passes_through(seed, k, margin):
    """Unchanged to 1e-6 when every halfspace has at least 1 mm of margin.

    (The interior-point answer is biased away from nearly active rows, by less
    than 1e-7 m/s^2 at 1 mm; see MPCSafetyFilter.solve.)
    """
    rng = np.random.default_rng(seed)
    x0 = np.array([rng.uniform(-2, 0), rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-1, 1)])
    inputs = rng.uniform(-1.0, 1.0, (T, 2))
    states = [x0]
    for u in inputs:
        states.append(A @ states[-1] + B @ u)
    states = np.array(states)
    normals = rng.normal(size=(k, T, 2))
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    offsets = np.einsum("ktd,td->kt", normals, states[1:, :2]) + margin
    result = fast().solve(x0, states, (normals, offsets), reference_inputs=inputs)
    assert result.status is FilterStatus.OPTIMAL
    np.testing.assert_allclose(result.inputs, inputs, atol=1e-6)
    np.testing.assert_allclose(result.states, states, atol=1e-6)


@given(seed=seeds, k=st.integers(1, 3), soft=st.booleans())
def test_soft_mode_is_never_worse_than_hard_mode(seed, k, soft):
    """Soft mode answers whenever hard mode does, with zero slack then."""
    instance = random_instance(np.random.default_rng(seed), k)
    hard = solve(fast(), instance)
    softened = solve(fast(soft=True), instance)
    assert_well_formed(softened, instance["x0"])
    assert softened.solved
    if hard.status is FilterStatus.OPTIMAL:
        assert softened.status is FilterStatus.OPTIMAL
        np.testing.assert_allclose(softened.inputs, hard.inputs, atol=1e-4)


@given(seed=seeds, k=st.integers(1, 3))
def test_fallback_sequence_is_shifted_then_brake(seed, k):
    instance = random_instance(np.random.default_rng(seed), k)
    mpc = MPCSafetyFilter(A, B, C, **{**KWARGS, "horizon": 4, "n_obstacles": k})
    x0 = instance["x0"]
    reference = instance["reference_states"][:5]
    normals, offsets = instance["halfspaces"]
    first = mpc.solve(x0, reference, (normals[:, :4], offsets[:, :4]))
    wall = infeasible_halfspaces(k)
    statuses = []
    for _ in range(5):
        result = mpc.solve(x0, reference, (wall[0][:, :4], wall[1][:, :4]))
        assert np.all(np.isfinite(result.inputs))
        statuses.append(result.status)
    if first.status is FilterStatus.OPTIMAL:
        assert statuses == [FilterStatus.SHIFTED] * 3 + [FilterStatus.BRAKE] * 2
    else:
        assert statuses == [FilterStatus.BRAKE] * 5

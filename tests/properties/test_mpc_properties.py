"""Property tests of the MPC safety filter on random instances (hypothesis, CI profile).

Invariants: the fast filter agrees with the CVXPY reference; an OPTIMAL answer
meets every halfspace, bound and terminal row; a safe, dynamically consistent
reference passes through unchanged; the result is never NaN and its states follow
the dynamics; the recovery answers whenever the hard QP does, with the same plan;
the paper's fallback sequence is SHIFTED x (T - 1) then BRAKE whatever the instance.
"""

from __future__ import annotations

from functools import cache

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from filters.mpc import FilterResult, FilterStatus, MPCSafetyFilter
from tests.builders import (
    TERMINAL,
    A,
    B,
    T,
    hard_violation,
    infeasible_halfspaces,
    make_filter,
    random_instance,
    rollout,
    solve,
)

seeds = st.integers(min_value=0, max_value=2**32 - 1)


@cache
def fast(soft: bool = False, objective: str = "trajectory", terminal: bool = False,
         backend: str = "clarabel") -> MPCSafetyFilter:
    """One filter per configuration, reused across examples (update, not rebuild)."""
    return make_filter(backend, soft=soft, objective=objective,
                       terminal_set=TERMINAL if terminal else None)


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


@given(seed=seeds, k=st.integers(0, 3), soft=st.booleans(), with_inputs=st.booleans(),
       objective=st.sampled_from(["trajectory", "first_input"]), terminal=st.booleans())
def test_fast_filter_equals_cvxpy_reference(seed, k, soft, with_inputs, objective, terminal):
    instance = random_instance(np.random.default_rng(seed), k, with_inputs=with_inputs)
    ours_filter = fast(soft=soft, objective=objective, terminal=terminal)
    reference = fast(soft=soft, objective=objective, terminal=terminal, backend="cvxpy")
    ours_filter.reset()
    reference.reset()
    ours, theirs = solve(ours_filter, instance), solve(reference, instance)
    assert_well_formed(ours, instance["x0"])
    assert ours.status == theirs.status
    if ours.status is FilterStatus.OPTIMAL:
        np.testing.assert_allclose(ours.inputs, theirs.inputs, atol=1e-4)
        assert abs(ours.objective - theirs.objective) <= 1e-4 + 1e-5 * abs(theirs.objective)
    else:  # a violation dominates the cost: the first input to ~1e-3 (see test_mpc)
        np.testing.assert_allclose(ours.inputs[0], theirs.inputs[0], atol=3e-3)


@given(seed=seeds, k=st.integers(1, 3), terminal=st.booleans())
def test_optimal_answers_satisfy_every_row(seed, k, terminal):
    instance = random_instance(np.random.default_rng(seed), k)
    result = solve(fast(terminal=terminal), instance)
    assert_well_formed(result, instance["x0"])
    if result.status is FilterStatus.OPTIMAL:
        assert hard_violation(result, instance["halfspaces"], terminal=terminal) <= 1e-6


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
    states = rollout(x0, inputs)
    normals = rng.normal(size=(k, T, 2))
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    offsets = np.einsum("ktd,td->kt", normals, states[1:, :2]) + margin
    result = fast().solve(x0, states, (normals, offsets), reference_inputs=inputs)
    assert result.status is FilterStatus.OPTIMAL
    np.testing.assert_allclose(result.inputs, inputs, atol=1e-6)
    np.testing.assert_allclose(result.states, states, atol=1e-6)


@given(seed=seeds, k=st.integers(1, 3), tighten=st.floats(0.0, 3.0))
def test_the_recovery_is_never_worse_than_the_hard_qp(seed, k, tighten):
    """The default filter answers (never a fallback) and equals the hard QP when it is
    feasible; the paper's fallback is used only when the hard QP fails."""
    instance = random_instance(np.random.default_rng(seed), k)
    normals, offsets = instance["halfspaces"]
    instance["halfspaces"] = (normals, offsets - tighten)
    hard = solve(fast_paper(), instance)
    recovered = solve(fast(), instance)
    assert_well_formed(recovered, instance["x0"])
    assert recovered.solved
    if hard.status is FilterStatus.OPTIMAL:
        assert recovered.status is FilterStatus.OPTIMAL
        np.testing.assert_allclose(recovered.inputs, hard.inputs, atol=1e-4)
    else:
        assert hard.fallback and recovered.slack is not None


@cache
def fast_paper() -> MPCSafetyFilter:
    return make_filter(fallback="paper")


@given(seed=seeds, k=st.integers(1, 3))
def test_fallback_sequence_is_shifted_then_brake(seed, k):
    instance = random_instance(np.random.default_rng(seed), k)
    mpc = make_filter(horizon=4, n_obstacles=k, fallback="paper")
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

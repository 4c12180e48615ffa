"""The filter's lean per-step path against straightforward recomputations.

:meth:`MPCSafetyFilter.solve` validates with one reduction per array, writes into
preallocated buffers and evaluates with precomputed maps (issue 12). These tests rebuild
what it returns by the obvious loops (roll-out step by step, halfspace excess row by row,
the cost (8) by :meth:`MPCProblem.cost`, the DAQP data by its formulas) on the benchmark's
crossing instances, and check that nothing a result holds is a buffer reused later.
"""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.filter_qp import double_integrator, filter_kwargs, make_instances
from filters.errors import InvalidArrayError
from filters.mpc import FilterStatus, MPCSafetyFilter, stopping_terminal_set
from filters.mpc.checks import parse_halfspaces
from filters.mpc.filter import FEASIBILITY_TOLERANCE, SLACK_TOLERANCE

pytest.importorskip("daqp")

T, K = 10, 3


@pytest.fixture(scope="module")
def instances():
    return make_instances(60, K, T, np.random.default_rng(12))


def _filter(soft: bool, terminal: bool) -> MPCSafetyFilter:
    A, B, C = double_integrator()
    extra = {"terminal_set": stopping_terminal_set(0.2, (-5, 5), (-5, 5))} if terminal else {}
    return MPCSafetyFilter(A, B, C, **filter_kwargs(T, K), soft=soft, backend="daqp", **extra)


def _rollout(A: np.ndarray, B: np.ndarray, x0: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    states = [x0]
    for u in inputs:
        states.append(A @ states[-1] + B @ u)
    return np.array(states)


@pytest.mark.parametrize("soft", [False, True])
@pytest.mark.parametrize("terminal", [False, True])
def test_step_results_equal_a_straightforward_recomputation(instances, soft, terminal):
    mpc = _filter(soft, terminal)
    p = mpc.problem
    low, high = p.input_bounds
    y_low, y_high = p.position_bounds
    statuses, active = set(), 0
    for index, case in enumerate(instances):
        if case.new_episode:
            mpc.reset()
        k = 2 if index % 5 == 0 else K  # fewer rows than the QP holds: padding
        normals, offsets = case.normals[:k], case.offsets[:k]
        if index % 4 == 3:  # pushed far in: active rows, infeasible steps, the recovery QP
            offsets = offsets - 1.5
        result = mpc.solve(case.x0, case.reference_states, (normals, offsets))
        statuses.add(result.status)
        inputs = result.inputs
        assert np.all(inputs >= low) and np.all(inputs <= high)
        states = _rollout(p.A, p.B, case.x0, inputs)
        np.testing.assert_allclose(result.states, states, rtol=0, atol=1e-10)
        cost = p.cost(inputs, states, case.reference_states[1:], np.zeros((T, p.m)))
        assert result.objective == pytest.approx(cost, rel=1e-10, abs=1e-10)
        excess = np.array([[normals[i, t] @ (p.C @ states[t + 1]) - offsets[i, t]
                            for t in range(T)] for i in range(k)]).reshape(k, T)
        positions = states[1:] @ p.C.T
        arena = np.concatenate([(positions - y_high).ravel(), (y_low - positions).ravel()])
        if terminal:
            G, g = p.terminal_set
            arena = np.concatenate([arena, G @ states[-1] - g])
        arena_total = float(arena[arena > SLACK_TOLERANCE].sum())
        active += bool(k) and abs(excess.max()) <= 1e-6
        if result.status is FilterStatus.OPTIMAL:
            assert excess.max(initial=-np.inf) <= FEASIBILITY_TOLERANCE
            assert arena.max() <= FEASIBILITY_TOLERANCE
        if result.slack is not None:
            expected = np.where(excess > SLACK_TOLERANCE, excess, 0.0)
            clear = np.abs(excess - SLACK_TOLERANCE) > 1e-9  # away from the cut
            np.testing.assert_allclose(result.slack[clear], expected[clear], atol=1e-10)
        else:
            assert not soft and result.status in (FilterStatus.OPTIMAL, FilterStatus.SOFT)
        assert result.bound_slack == pytest.approx(arena_total, abs=1e-9)
        assert result.status is not FilterStatus.OPTIMAL or mpc.last_qp_solves == 1
    assert FilterStatus.OPTIMAL in statuses and FilterStatus.SOFT in statuses, statuses
    assert active >= 5, active  # steps with an active halfspace row


def test_results_share_no_memory_with_the_buffers_reused_by_later_steps(instances):
    mpc = _filter(soft=False, terminal=True)
    first = instances[3]
    result = mpc.solve(first.x0, first.reference_states, (first.normals, first.offsets))
    kept = [result.inputs.copy(), result.states.copy(), result.objective]
    for case in instances[4:20]:
        mpc.solve(case.x0, case.reference_states, (case.normals, case.offsets))
    assert np.array_equal(result.inputs, kept[0]) and np.array_equal(result.states, kept[1])
    assert result.objective == kept[2]
    assert not result.inputs.flags.writeable and not result.states.flags.writeable
    again = _filter(soft=False, terminal=True).solve(
        first.x0, first.reference_states, (first.normals, first.offsets))
    assert np.array_equal(again.inputs, result.inputs)  # bit for bit, whatever ran between
    assert np.array_equal(again.states, result.states)


def test_daqp_step_data_equals_its_formulas(instances):
    """The whitened condensed QP (filters.mpc.condensed) against its formulas: H = U U'
    with U upper triangular, f_z = U^{-1} f, every row a' u written as a' U^{-T} z, the
    bounds shifted by the current state."""
    mpc = _filter(soft=False, terminal=True)
    p, backend = mpc.problem, mpc._primary
    qp = backend.qp
    phi, gamma = p.rollout
    n, m, nu = p.n, p.m, T * p.m
    R_bar = np.zeros((nu, nu))
    for t, Rt in enumerate(p.input_weights):
        R_bar[t * m:(t + 1) * m, t * m:(t + 1) * m] = Rt
    Q_bar = np.zeros((T * n, T * n))
    for t, Qt in enumerate(p.state_weights):
        Q_bar[t * n:(t + 1) * n, t * n:(t + 1) * n] = Qt
    H = 2 * (R_bar + gamma.T @ Q_bar @ gamma)
    U = qp.z_of_u.T
    np.testing.assert_allclose(U @ U.T, H, rtol=1e-12, atol=1e-10)
    assert np.array_equal(np.triu(U), U) and np.array_equal(np.tril(qp.u_of_z), qp.u_of_z)
    np.testing.assert_allclose(qp.u_of_z @ U.T, np.eye(nu), atol=1e-12)
    G, g = p.terminal_set
    for case in instances[:15]:
        mpc.solve(case.x0, case.reference_states, (case.normals, case.offsets))
        step = mpc._last_step
        rows = qp.step_rows(step.x0, step.ref_states, step.ref_inputs, step.normals,
                            step.offsets)
        x_ref = case.reference_states[1:].reshape(-1)
        f = 2 * gamma.T @ Q_bar @ (phi @ case.x0 - x_ref)
        np.testing.assert_allclose(U @ rows.f, f, rtol=1e-12, atol=1e-10)
        for t in range(T):
            C_gamma_t = p.C @ gamma[t * n:(t + 1) * n]
            C_phi_t = p.C @ phi[t * n:(t + 1) * n]
            for i in range(K):
                a = case.normals[i, t]
                row = qp.halfspace_rows(rows, np.array([t]), np.array([i]))[0]
                np.testing.assert_allclose(row @ U.T, a @ C_gamma_t, atol=1e-12)
                assert rows.hs_upper[t, i] == pytest.approx(
                    case.offsets[i, t] - a @ C_phi_t @ case.x0, abs=1e-12)
        # fixed rows: the input box, the arena per step and axis, the terminal rows
        inputs, arena, terminal = qp.row_slices
        np.testing.assert_allclose(qp.fixed_rows[inputs] @ U.T, np.eye(nu), atol=1e-12)
        np.testing.assert_allclose(rows.upper[inputs], 5.0)
        positions0 = (phi @ case.x0).reshape(T, n)[:, :2]
        np.testing.assert_allclose(rows.upper[arena], (5.0 - positions0).ravel(), atol=1e-12)
        np.testing.assert_allclose(rows.lower[arena], (-5.0 - positions0).ravel(), atol=1e-12)
        np.testing.assert_allclose(qp.fixed_rows[terminal] @ U.T, G @ gamma[(T - 1) * n:],
                                   atol=1e-12)
        np.testing.assert_allclose(rows.upper[terminal], g - G @ phi[(T - 1) * n:] @ case.x0,
                                   atol=1e-12)


def test_parse_halfspaces_fast_path_agrees_with_the_full_check():
    rng = np.random.default_rng(3)
    normals, offsets = rng.normal(size=(2, T, 2)), rng.normal(size=(2, T))
    got = parse_halfspaces((normals, offsets), T, 2, K)
    assert got[0] is normals and got[1] is offsets
    for form in ([normals.tolist(), offsets.tolist()], (normals.astype(np.float32), offsets)):
        slow = parse_halfspaces(form, T, 2, K)
        assert np.array_equal(slow[0], np.asarray(form[0], dtype=np.float64))
    huge = np.full((1, T, 2), 1e308)  # finite entries whose sum overflows: accepted
    assert parse_halfspaces((huge, np.zeros((1, T))), T, 2, K)[0] is huge
    bad = normals.copy()
    bad[1, 4, 0] = np.nan
    cases = [
        ((bad, offsets), "finite"),
        ((normals, np.where(offsets > 0, np.inf, offsets)), "finite"),
        ((normals[:, :-1], offsets), "shape"),
        ((normals, offsets[:1]), "shape"),
        ((rng.normal(size=(K + 1, T, 2)), np.zeros((K + 1, T))), "n_obstacles"),
        ((np.concatenate([huge, -huge]) * 10, np.zeros((2, T))), "finite"),  # inf entries
    ]
    for halfspaces, words in cases:
        with pytest.raises(InvalidArrayError, match=words):
            parse_halfspaces(halfspaces, T, 2, K)

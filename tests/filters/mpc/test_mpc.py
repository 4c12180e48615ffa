"""Tests of the MPC safety filter, one suite over the back ends (qpsolvers-style).

The Clarabel back end is checked against the CVXPY reference for every objective, mode
(hard, soft, recovery) and terminal set; every status is reached and reported; a
used filter returns what a fresh one returns; bad input raises the package's errors.
"""

from __future__ import annotations

import dataclasses
import inspect
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from filters.errors import InvalidArrayError, InvalidParameterError, InvalidTypeError, SafeNavError
from filters.mpc import FilterResult, FilterStatus, MPCProblem, MPCSafetyFilter
from filters.mpc.result import QPSolution
from tests.builders import (
    ARENA,
    KWARGS,
    TERMINAL,
    TS,
    A,
    B,
    C,
    T,
    consistent_reference,
    halfspace_violation,
    hard_violation,
    infeasible_halfspaces,
    make_filter,
    random_instance,
    rollout,
    solve,
)

BACKENDS = ["clarabel", "daqp", "cvxpy"]
FAST = ["clarabel", "daqp"]
OBJECTIVES = ["trajectory", "first_input"]
MODES = ["hard", "soft", "recovery"]
NO_QP = "unconstrained optimum feasible (no QP needed)"


def mode_instances(mode: str, seed: int, count: int) -> list[dict]:
    """Random instances for a mode: as drawn (hard), tightened (soft), ego outside (recovery)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        instance = random_instance(rng, int(rng.integers(0, 4)), with_inputs=rng.random() < 0.5)
        normals, offsets = instance["halfspaces"]
        if mode in ("soft", "recovery"):
            instance["halfspaces"] = (normals, offsets - rng.uniform(0.0, 2.0))
        if mode == "recovery" and rng.random() < 0.7:  # outside the arena, moving out
            x0 = instance["x0"].copy()
            x0[0], x0[2] = -ARENA - rng.uniform(0.05, 0.5), -rng.uniform(0.0, 1.0)
            instance["x0"] = x0
        out.append(instance)
    return out


def filter_for(backend: str, objective: str, mode: str, terminal: bool, **extra):
    return make_filter(
        backend, objective=objective, soft=mode == "soft",
        terminal_set=TERMINAL if terminal else None, **extra,
    )


# --------------------------------------------------------------------------- vs CVXPY
@pytest.mark.parametrize("terminal", [False, True])
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("objective", OBJECTIVES)
@pytest.mark.parametrize("backend", FAST)
def test_fast_backends_equal_the_cvxpy_reference(backend, objective, mode, terminal):
    fast = filter_for(backend, objective, mode, terminal, skip_feasible_reference=False)
    reference = filter_for("cvxpy", objective, mode, terminal)
    statuses = set()
    for instance in mode_instances(mode, 1 + MODES.index(mode), 8):
        fast.reset()
        reference.reset()
        ours, theirs = solve(fast, instance), solve(reference, instance)
        assert ours.status == theirs.status, (ours.solver_status, theirs.solver_status)
        statuses.add(ours.status)
        violated = ours.slack is not None and ours.slack.sum() > 1e-6 or ours.bound_slack > 1e-6
        if not violated:
            np.testing.assert_allclose(ours.inputs, theirs.inputs, atol=1e-4)
        else:
            # A violation of metres costs rho * sum(s) ~ 1e6, which dwarfs the quadratic
            # cost: at the gap 1e-10 the solvers pin u_0 to ~1e-3 and the slacks to ~1e-5;
            # the later inputs, weighted 1e-2 by first_input and by the recovery QP's
            # braking objective, only to ~0.1.
            np.testing.assert_allclose(ours.inputs[0], theirs.inputs[0], atol=3e-3)
            loose = 3e-3 if objective == "trajectory" and mode != "recovery" else 0.15
            np.testing.assert_allclose(ours.inputs, theirs.inputs, atol=loose)
        if ours.slack is not None:
            np.testing.assert_allclose(ours.slack, theirs.slack, atol=1e-4)
        assert ours.bound_slack == pytest.approx(theirs.bound_slack, abs=1e-4)
        if not violated:
            assert ours.objective == pytest.approx(theirs.objective, rel=1e-5, abs=1e-4)
    expected = {"hard": FilterStatus.OPTIMAL, "soft": FilterStatus.SOFT,
                "recovery": FilterStatus.RECOVERY}[mode]
    assert expected in statuses


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("terminal", [False, True])
@pytest.mark.parametrize("objective", OBJECTIVES)
def test_optimal_plans_satisfy_every_hard_row(backend, objective, terminal):
    mpc = filter_for(backend, objective, "hard", terminal)
    optimal = 0
    for instance in mode_instances("hard", 2, 10):
        result = solve(mpc, instance)
        assert result.solved
        np.testing.assert_allclose(result.states, rollout(instance["x0"], result.inputs),
                                   atol=1e-12)
        if result.status is FilterStatus.OPTIMAL:
            optimal += 1
            assert hard_violation(result, instance["halfspaces"], terminal=terminal) <= 1e-6
    assert optimal >= 7


@pytest.mark.parametrize("backend", BACKENDS)
def test_recovery_rows_hold_to_their_slack_and_slacks_are_the_violations(backend):
    mpc = make_filter(backend, terminal_set=TERMINAL)
    reached = 0
    for instance in mode_instances("recovery", 3, 8):
        result = solve(mpc, instance)
        assert result.solved
        slack = np.zeros((len(instance["halfspaces"][1]), T)) if result.slack is None else (
            result.slack)
        violation = np.maximum(halfspace_violation(result.states, instance["halfspaces"]), 0.0)
        np.testing.assert_allclose(slack, np.where(violation > 1e-6, violation, 0.0), atol=1e-6)
        positions = result.states[1:] @ C.T
        G, g = TERMINAL
        outside = np.maximum(np.abs(positions) - ARENA, 0.0).sum()
        outside += np.maximum(G @ result.states[-1] - g, 0.0).sum()
        assert result.bound_slack == pytest.approx(outside, abs=1e-5)
        if result.status is FilterStatus.RECOVERY:
            reached += 1
            assert result.bound_slack > 1e-6
            assert "recovery QP" in result.solver_status
            assert np.all(np.abs(result.inputs) <= 5.0)
    assert reached >= 3


def test_exact_penalty_recovery_qps_equal_their_hard_form_when_feasible():
    """Where every row can hold, both recovery QPs (soft rows, exact L1 penalty) return the
    minimiser of their braking objective with every row hard (CVXPY), without slack."""
    from filters.mpc.backends.cvxpy import CVXPYBackend
    from filters.mpc.result import StepData

    mpc = make_filter(terminal_set=TERMINAL, skip_feasible_reference=False)
    hard_form = CVXPYBackend(dataclasses.replace(mpc._recovery.problem, soft_rows=frozenset()),
                             solver_settings={"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10})
    compared = 0
    for instance in mode_instances("hard", 4, 12):
        if solve(mpc, instance).status is not FilterStatus.OPTIMAL:
            continue
        step = mpc._step
        braking = StepData(step.x0, np.zeros_like(step.ref_states),
                           np.zeros_like(step.ref_inputs), step.normals, step.offsets)
        expected = hard_form.solve(braking)
        assert expected.found
        for backend in (mpc._recovery, mpc._rescue):
            recovered = backend.solve(braking)
            assert recovered.found
            np.testing.assert_allclose(recovered.inputs, expected.inputs, atol=1e-4)
            assert np.max(recovered.halfspace_slack) <= 1e-7
            assert recovered.bound_slack is None or np.max(recovered.bound_slack) <= 1e-7
        compared += 1
    assert compared >= 8


def test_recovery_slack_is_the_minimal_l1_violation():
    import cvxpy as cp

    mpc = make_filter(n_obstacles=3)
    checked = 0
    for instance in mode_instances("recovery", 5, 10):
        result = solve(mpc, instance)
        normals, offsets = instance["halfspaces"]
        u = cp.Variable((T, 2))
        x = cp.Variable((T + 1, 4))
        s = cp.Variable((normals.shape[0], T), nonneg=True)
        box = cp.Variable((T, 2), nonneg=True)
        rows = [x[0] == instance["x0"], cp.abs(u) <= 5.0, cp.abs(x[1:, :2]) <= ARENA + box]
        rows += [x[t + 1] == A @ x[t] + B @ u[t] for t in range(T)]
        rows += [cp.sum(cp.multiply(normals[i], x[1:, :2]), axis=1) <= offsets[i] + s[i]
                 for i in range(normals.shape[0])]
        lp = cp.Problem(cp.Minimize(cp.sum(s) + cp.sum(box)), rows)
        lp.solve(solver=cp.CLARABEL)
        total = result.bound_slack + (0.0 if result.slack is None else result.slack.sum())
        assert total == pytest.approx(lp.value, abs=1e-5)
        checked += total > 1e-3
    assert checked >= 5


@pytest.mark.parametrize("excess", [2e-5, 2e-3])
def test_answers_slightly_outside_the_input_box_are_clipped_and_checked(excess):
    """A back end answer up to INPUT_CLIP_TOLERANCE outside the input box is clipped and
    its rows are checked on the clipped plan (a recovery answer 2e-5 outside was once
    rejected, and the filter braked); beyond it, the answer is rejected."""
    from filters.mpc.filter import INPUT_CLIP_TOLERANCE

    mpc = make_filter("daqp", n_obstacles=3)
    answers = []

    def pushed(real):
        def outside(step):  # the true recovery answer, pushed out of the box where it binds
            solution = real(step)
            if solution.inputs is None:
                return solution
            answers.append(solution.inputs)
            inputs = solution.inputs.copy()
            inputs[inputs >= 5.0 - 1e-9] += excess
            inputs[inputs <= -5.0 + 1e-9] -= excess
            return dataclasses.replace(solution, inputs=inputs)
        return outside

    for backend in (mpc._recovery, mpc._rescue):  # arena hard, then soft
        backend.solve = pushed(backend.solve)
    saturated = 0
    for instance in mode_instances("recovery", 5, 10):
        mpc.reset()
        answers.clear()
        result = solve(mpc, instance)
        if mpc.last_qp_solves < 2 or not answers:
            continue  # the hard QP answered, or no recovery QP did
        plan = answers[0]  # the first recovery QP that answered
        if not np.any(np.abs(plan) >= 5.0 - 1e-9):
            continue
        saturated += 1
        if excess < 1e-4:
            assert result.status in (FilterStatus.SOFT, FilterStatus.RECOVERY)
            assert np.abs(result.inputs).max() <= 5.0
            assert np.allclose(result.inputs, plan, atol=excess)
        else:
            assert result.status is FilterStatus.BRAKE
            assert "input bound violated" in result.solver_status
    assert saturated >= 3
    assert 2e-5 < INPUT_CLIP_TOLERANCE < 2e-3


# --------------------------------------------------------------------------- build once
@pytest.mark.parametrize("objective", OBJECTIVES)
@pytest.mark.parametrize("mode", MODES)
def test_update_equals_rebuild(objective, mode):
    persistent = filter_for("clarabel", objective, mode, True, skip_feasible_reference=False)
    for instance in mode_instances(mode, 6, 12):
        persistent.reset()
        updated = solve(persistent, instance)
        rebuilt = solve(
            filter_for("clarabel", objective, mode, True, skip_feasible_reference=False),
            instance,
        )
        assert updated.status == rebuilt.status
        assert updated.solver_status == rebuilt.solver_status
        np.testing.assert_allclose(updated.inputs, rebuilt.inputs, rtol=0, atol=1e-9)
        assert updated.iterations == rebuilt.iterations


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("k", [0, 1, 2])
def test_fewer_halfspaces_equal_a_filter_built_for_that_many(backend, k):
    rng = np.random.default_rng(5 + k)
    large, exact = make_filter(backend, n_obstacles=3), make_filter(backend, n_obstacles=k)
    for _ in range(5):
        instance = random_instance(rng, k)
        ours, theirs = solve(large, instance), solve(exact, instance)
        assert ours.status == theirs.status
        np.testing.assert_allclose(ours.inputs, theirs.inputs, atol=1e-5)


@pytest.mark.parametrize("backend", BACKENDS)
def test_zero_normal_rows_with_positive_offsets_are_switched_off(backend):
    rng = np.random.default_rng(7)
    mpc = make_filter(backend, n_obstacles=6)
    for _ in range(5):
        instance = random_instance(rng, 3)
        normals, offsets = instance["halfspaces"]
        padded = (np.concatenate([normals, np.zeros((3, T, 2))]),
                  np.concatenate([offsets, rng.uniform(0.01, 3.0, (3, T))]))
        ours = solve(mpc, instance)
        switched = solve(mpc, {**instance, "halfspaces": padded})
        assert ours.status == switched.status
        # a recovery answer's later inputs are weighted 1e-2: determined to ~1e-4
        np.testing.assert_allclose(ours.inputs, switched.inputs,
                                   atol=1e-5 if mpc.last_qp_solves < 2 else 1e-4)
        assert switched.slack is None or np.all(switched.slack[3:] == 0.0)


def test_no_halfspaces_accepts_none_empty_and_objects():
    instance = random_instance(np.random.default_rng(8), 0)
    mpc = make_filter()
    x0, reference = instance["x0"], instance["reference_states"]
    with_none = mpc.solve(x0, reference, None)
    empty = mpc.solve(x0, reference, instance["halfspaces"])
    as_object = mpc.solve(x0, reference, SimpleNamespace(normals=np.zeros((0, T, 2)),
                                                         offsets=np.zeros((0, T))))
    np.testing.assert_array_equal(with_none.inputs, empty.inputs)
    np.testing.assert_array_equal(with_none.inputs, as_object.inputs)


# --------------------------------------------------------------------------- shortcut
@pytest.mark.parametrize("objective", OBJECTIVES)
@pytest.mark.parametrize("soft", [False, True])
def test_feasible_reference_skips_the_qp_and_equals_the_qp_answer(objective, soft):
    rng = np.random.default_rng(20)
    fast = make_filter(objective=objective, soft=soft, terminal_set=TERMINAL)
    slow = make_filter("cvxpy", objective=objective, soft=soft, terminal_set=TERMINAL)
    for _ in range(6):
        x0, inputs, states, halfspaces = consistent_reference(rng, int(rng.integers(0, 4)), 0.3)
        x0[2:] *= 0.2  # slow enough for the terminal set
        states = rollout(x0, inputs * 0.2)
        inputs = inputs * 0.2
        normals = halfspaces[0]
        halfspaces = (normals, np.einsum("ktd,td->kt", normals, states[1:, :2]) + 0.3)
        ours = fast.solve(x0, states, halfspaces, reference_inputs=inputs)
        assert ours.status is FilterStatus.OPTIMAL and ours.solver_status == NO_QP
        assert ours.iterations == 0 and ours.solve_time == 0.0 and fast.last_qp_solves == 0
        np.testing.assert_allclose(ours.inputs, inputs, rtol=0, atol=1e-12)
        np.testing.assert_allclose(ours.states, states, rtol=0, atol=1e-12)
        assert ours.objective == pytest.approx(0.0, abs=1e-18)
        if soft:
            assert ours.slack.shape == (normals.shape[0], T) and not ours.slack.any()
        theirs = slow.solve(x0, states, halfspaces, reference_inputs=inputs)
        assert theirs.iterations > 0
        np.testing.assert_allclose(ours.inputs, theirs.inputs, atol=1e-5)
        assert not ours.inputs.flags.writeable


def test_first_input_shortcut_is_the_reference_input_and_ignores_reference_states():
    rng = np.random.default_rng(21)
    mpc = make_filter(objective="first_input")
    for _ in range(5):
        instance = random_instance(rng, 1, with_inputs=True)
        normals, offsets = instance["halfspaces"]
        instance["halfspaces"] = (normals, offsets + 20.0)  # far away
        instance["reference_inputs"] = np.clip(instance["reference_inputs"], -0.3, 0.3)
        result = solve(mpc, instance)
        assert result.solver_status == NO_QP
        np.testing.assert_array_equal(result.inputs, instance["reference_inputs"])
        wild = {**instance, "reference_states": rng.normal(0, 100, (T + 1, 4))}
        np.testing.assert_array_equal(solve(mpc, wild).inputs, result.inputs)


def test_first_input_keeps_the_first_input_closest_to_the_reference():
    """A wall ahead: first_input changes u_0 less than trajectory tracking does (it has
    no state terms pulling the plan), and both stay behind the wall."""
    x0 = np.array([0.0, 0.0, 1.5, 0.0])
    wall = (np.tile([1.0, 0.0], (1, T, 1)), np.full((1, T), 1.5))
    u_ref = np.tile([2.0, 0.5], (T, 1))
    reference = rollout(x0, u_ref)
    first = make_filter(objective="first_input").solve(x0, reference, wall,
                                                       reference_inputs=u_ref)
    tracking = make_filter().solve(x0, reference, wall, reference_inputs=u_ref)
    for result in (first, tracking):
        assert result.status is FilterStatus.OPTIMAL
        assert np.max(result.states[:, 0]) <= 1.5 + 1e-6
    assert np.linalg.norm(first.inputs[0] - u_ref[0]) < np.linalg.norm(
        tracking.inputs[0] - u_ref[0]
    )


@pytest.mark.parametrize("which", ["halfspace", "position", "input", "terminal"])
def test_shortcut_is_not_taken_when_one_row_is_violated_by_1e_9(which):
    rng = np.random.default_rng(22)
    x0, inputs, states, (normals, offsets) = consistent_reference(rng, 2, 0.5)
    kwargs: dict = {}
    if which == "halfspace":
        offsets = offsets.copy()
        offsets[0, 4] = normals[0, 4] @ states[5, :2] - 1e-9
    elif which == "position":
        kwargs["position_bounds"] = (-5.0, [states[1:, 0].max() - 1e-9, 5.0])
    elif which == "input":
        kwargs["input_bounds"] = (-5.0, [inputs[:, 0].max() - 1e-9, 5.0])
    else:
        G = np.array([[1.0, 0.0, 0.0, 0.0]])
        kwargs["terminal_set"] = (G, np.array([states[-1, 0] - 1e-9]))
    mpc = make_filter(**kwargs)
    result = mpc.solve(x0, states, (normals, offsets), reference_inputs=inputs)
    assert mpc.last_qp_solves >= 1 and result.solver_status != NO_QP
    assert result.status is FilterStatus.OPTIMAL
    np.testing.assert_allclose(result.inputs, inputs, atol=1e-4)


# --------------------------------------------------------------------------- statuses
def test_paper_fallback_shifts_the_last_plan_then_brakes():
    instance = random_instance(np.random.default_rng(9), 1)
    mpc = make_filter(n_obstacles=1, fallback="paper")
    first = solve(mpc, instance)
    assert first.status is FilterStatus.OPTIMAL
    plan = first.inputs
    x0, reference = instance["x0"], instance["reference_states"]
    for shift in range(1, T):
        result = mpc.solve(x0, reference, infeasible_halfspaces())
        assert result.status is FilterStatus.SHIFTED and result.fallback
        assert result.consecutive_failures == shift
        assert "Infeasible" in result.solver_status
        np.testing.assert_array_equal(result.inputs[: T - shift], plan[shift:])
        assert result.slack is not None and result.slack.min() >= 0.0
    result = mpc.solve(x0, reference, infeasible_halfspaces())
    assert result.status is FilterStatus.BRAKE and result.consecutive_failures == T
    again = solve(mpc, instance)
    assert again.status is FilterStatus.OPTIMAL and again.consecutive_failures == 0
    shifted = mpc.solve(x0, reference, infeasible_halfspaces())
    np.testing.assert_array_equal(shifted.first_input, again.inputs[1])


def test_soft_fallback_reports_soft_when_only_halfspaces_are_violated():
    instance = random_instance(np.random.default_rng(13), 2)
    normals, offsets = instance["halfspaces"]
    offsets = offsets.copy()
    offsets[0] = np.einsum("td,d->t", normals[0], instance["x0"][:2]) - 3.0  # 3 m behind
    mpc = make_filter(n_obstacles=2)
    result = mpc.solve(instance["x0"], instance["reference_states"], (normals, offsets))
    assert result.status is FilterStatus.SOFT and mpc.last_qp_solves == 2
    assert result.consecutive_failures == 1 and result.bound_slack == 0.0
    assert result.slack.shape == (2, T) and result.slack.sum() > 0.1
    assert "PrimalInfeasible" in result.solver_status
    assert "recovery QP: Solved" in result.solver_status


def test_soft_mode_is_hard_mode_when_feasible_and_soft_when_not():
    hard, soft = make_filter(), make_filter(soft=True)
    statuses = []
    for instance in mode_instances("soft", 14, 12):
        ours, softened = solve(hard, instance), solve(soft, instance)
        statuses.append(softened.status)
        assert soft.last_qp_solves <= 1  # the arena is never violated here
        if ours.status is FilterStatus.OPTIMAL:
            assert softened.status is FilterStatus.OPTIMAL and not softened.slack.any()
            np.testing.assert_allclose(softened.inputs, ours.inputs, atol=1e-5)
    assert FilterStatus.SOFT in statuses and FilterStatus.OPTIMAL in statuses


def test_recovery_brings_the_ego_back_into_the_arena():
    """Outside the arena with the terminal set: the recovery QP steers back, and the
    closed loop is inside again within a few steps, never worse than at the start."""
    mpc = make_filter(terminal_set=TERMINAL, n_obstacles=1)
    x = np.array([-5.4, 0.0, -1.0, 0.0])
    outside = []
    for _ in range(8):
        reference = np.tile([-4.0, 0.0, 0.0, 0.0], (T + 1, 1))
        result = mpc.solve(x, reference, None)
        outside.append(max(0.0, -ARENA - x[0]))
        x = A @ x + B @ result.first_input
    assert outside[0] > 0 and outside[-1] == 0.0
    assert result.status is FilterStatus.OPTIMAL


class Broken:
    """Stands in for a back end: raises, or returns a NaN 'solution'."""

    def __init__(self, backend, mode: str):
        self.problem, self.mode = backend.problem, mode

    def solve(self, step):
        if self.mode == "raise":
            raise RuntimeError("solver exploded")
        return QPSolution(True, "Solved", np.full((T, 2), np.nan), iterations=3)


@pytest.mark.parametrize(("mode", "message"), [("raise", "exception"), ("nan", "non-finite")])
def test_failed_solvers_give_a_status_not_an_exception(mode, message):
    instance = random_instance(np.random.default_rng(11), 2)
    soft = make_filter()
    soft._primary = Broken(soft._primary, mode)
    result = solve(soft, instance)  # the recovery QP answers
    assert result.status is FilterStatus.OPTIMAL and message in result.solver_status
    soft._recovery = Broken(soft._recovery, mode)
    soft._rescue = Broken(soft._rescue, mode)
    result = solve(soft, instance)
    assert result.status is FilterStatus.BRAKE and result.consecutive_failures == 2
    paper = make_filter(fallback="paper")
    plan = solve(paper, instance).inputs
    paper._primary = Broken(paper._primary, mode)
    result = solve(paper, instance)
    assert result.status is FilterStatus.SHIFTED and message in result.solver_status
    np.testing.assert_array_equal(result.first_input, plan[1])
    assert np.all(np.isfinite(result.inputs)) and np.isfinite(result.objective)


def test_iteration_limit_is_a_failure_not_an_exception():
    mpc = make_filter(solver_settings={"max_iter": 1}, skip_feasible_reference=False)
    result = solve(mpc, random_instance(np.random.default_rng(12), 3))
    assert result.status is FilterStatus.BRAKE
    assert result.solver_status.startswith("hard QP: MaxIterations")


def test_brake_without_plan_cancels_velocity_within_input_bounds():
    mpc = make_filter(n_obstacles=1, fallback="paper")
    x0 = np.array([0.0, 0.0, 0.8, -0.4])
    result = mpc.solve(x0, np.tile(x0, (T + 1, 1)), infeasible_halfspaces())
    assert result.status is FilterStatus.BRAKE
    np.testing.assert_allclose(result.first_input, -x0[2:] / TS)
    np.testing.assert_allclose(result.states[1:, 2:], 0.0, atol=1e-12)
    fast = np.array([0.0, 0.0, 3.0, 0.0])  # -v / Ts = -15 m/s^2 is clipped to -5
    result = mpc.solve(fast, np.tile(fast, (T + 1, 1)), infeasible_halfspaces())
    np.testing.assert_allclose(result.first_input, [-5.0, 0.0])
    np.testing.assert_allclose(mpc.braking_input(fast), [-5.0, 0.0])


def test_custom_brake_gain_is_used():
    gain = np.hstack([np.zeros((2, 2)), 2.0 * np.eye(2)])  # u = -2 v
    mpc = make_filter(n_obstacles=1, brake_gain=gain, fallback="paper")
    x0 = np.array([0.0, 0.0, 1.0, -0.5])
    result = mpc.solve(x0, np.tile(x0, (T + 1, 1)), infeasible_halfspaces())
    assert result.status is FilterStatus.BRAKE
    np.testing.assert_allclose(result.first_input, [-2.0, 1.0])


def test_reset_forgets_the_plan():
    instance = random_instance(np.random.default_rng(10), 1)
    mpc = make_filter(n_obstacles=1, fallback="paper")
    assert solve(mpc, instance).status is FilterStatus.OPTIMAL and mpc.last_plan is not None
    mpc.reset()
    assert mpc.last_plan is None
    x0, reference = instance["x0"], instance["reference_states"]
    assert mpc.solve(x0, reference, infeasible_halfspaces()).status is FilterStatus.BRAKE


def test_every_status_is_documented_and_a_string():
    assert {s.value for s in FilterStatus} == {
        "optimal", "soft", "recovery", "shifted", "brake", "error"}
    assert FilterStatus.SHIFTED == "shifted"
    source = inspect.getsource(FilterStatus)
    for status in FilterStatus:
        assert f'{status.name} = "{status.value}"\n    """' in source


# --------------------------------------------------------------------------- bad input
BAD_CONSTRUCTOR = [
    ({"A": np.ones((4, 3))}, InvalidArrayError, "A must have shape"),
    ({"A": np.full((4, 4), np.nan)}, InvalidArrayError, "A"),
    ({"B": np.ones((3, 2))}, InvalidArrayError, "B"),
    ({"C": np.ones((2, 3))}, InvalidArrayError, "C"),
    ({"horizon": 0}, InvalidParameterError, "horizon"),
    ({"horizon": 2.5}, InvalidTypeError, "horizon"),
    ({"n_obstacles": -1}, InvalidParameterError, "n_obstacles"),
    ({"Q": -np.eye(4)}, InvalidParameterError, "Q"),
    ({"Q": np.ones((4, 4)) + np.diag([0, 0, 0, 1]) - np.eye(4)[::-1]}, InvalidParameterError, "Q"),
    ({"Q_terminal": np.diag([1.0, 1.0, 1.0, -1.0])}, InvalidParameterError, "Q_terminal"),
    ({"Q": np.eye(3)}, InvalidArrayError, "Q"),
    ({"Q": None}, InvalidParameterError, "Q is required"),
    ({"R": np.zeros((2, 2))}, InvalidParameterError, "R"),
    ({"R": np.diag([1.0, 0.0])}, InvalidParameterError, "positive definite"),
    ({"input_bounds": (5.0, -5.0)}, InvalidParameterError, "input_bounds"),
    ({"input_bounds": ([0.0, 1.0], [1.0, 0.5])}, InvalidParameterError, "index 1"),
    ({"input_bounds": (np.nan, 1.0)}, InvalidArrayError, "input_bounds"),
    ({"input_bounds": 5.0}, InvalidTypeError, "input_bounds"),
    ({"input_bounds": ([0, 0, 0], 1.0)}, InvalidArrayError, "input_bounds"),
    ({"position_bounds": (np.inf, 1.0)}, InvalidParameterError, "position_bounds"),
    ({"position_bounds": (1.0, -1.0)}, InvalidParameterError, "position_bounds"),
    ({"slack_penalty": 0.0}, InvalidParameterError, "slack_penalty"),
    ({"slack_penalty": np.nan}, InvalidParameterError, "slack_penalty"),
    ({"soft": "yes"}, InvalidTypeError, "soft"),
    ({"skip_feasible_reference": "yes"}, InvalidTypeError, "skip_feasible_reference"),
    ({"brake_gain": np.zeros((4, 2))}, InvalidArrayError, "brake_gain"),
    ({"brake_gain": np.full((2, 4), np.inf)}, InvalidArrayError, "brake_gain"),
    ({"objective": "fastest"}, InvalidParameterError, "objective"),
    ({"objective": "first_input", "later_input_weight": 0.0}, InvalidParameterError,
     "later_input_weight"),
    ({"terminal_set": np.eye(4)}, InvalidTypeError, "terminal_set"),
    ({"terminal_set": (np.eye(3), np.ones(3))}, InvalidArrayError, "terminal_set G"),
    ({"terminal_set": (np.eye(4), np.ones(3))}, InvalidArrayError, "terminal_set g"),
    ({"terminal_set": (np.eye(4), np.full(4, np.nan))}, InvalidArrayError, "terminal_set g"),
    ({"fallback": "pray"}, InvalidParameterError, "fallback"),
    ({"backend": "osqp"}, InvalidParameterError, "backend"),
]
BAD_SETTINGS = [  # the CVXPY back end passes its settings to problem.solve unchecked
    ({"solver_settings": {"presolve_enable": True}}, InvalidParameterError, "presolve"),
    ({"solver_settings": {"input_sparse_dropzeros": True}}, InvalidParameterError, "dropzeros"),
    ({"solver_settings": {"no_such_setting": 1}}, InvalidParameterError, "no_such_setting"),
    ({"solver_settings": [("max_iter", 1)]}, InvalidTypeError, "solver_settings"),
]


def _construct(backend, change):
    kwargs = {"A": A, "B": B, "C": C, **KWARGS, **change}
    matrices = [kwargs.pop(key) for key in ("A", "B", "C")]
    kwargs.setdefault("backend", backend)
    return MPCSafetyFilter(*matrices, **kwargs)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize(("change", "error", "name"), BAD_CONSTRUCTOR)
def test_bad_constructor_arguments_raise(backend, change, error, name):
    with pytest.raises(error, match=name):
        _construct(backend, change)


@pytest.mark.parametrize(("change", "error", "name"), BAD_SETTINGS)
def test_bad_solver_settings_raise(change, error, name):
    with pytest.raises(error, match=name):
        _construct("clarabel", change)


def test_first_input_needs_no_state_weights():
    mpc = _construct("clarabel", {"objective": "first_input", "Q": None, "Q_terminal": None})
    assert mpc.objective == "first_input" and mpc.problem.Q is None
    assert not mpc.problem.state_weights.any() and not mpc.problem.gain.any()


def _with(instance, **change):
    return {**instance, **change}


BAD_SOLVE = [
    (lambda g: _with(g, x0=np.array([0.0, np.nan, 1.0, 0.0])), InvalidArrayError, "x0"),
    (lambda g: _with(g, x0=np.zeros(3)), InvalidArrayError, "x0"),
    (lambda g: _with(g, x0="fast"), InvalidArrayError, "x0"),
    (lambda g: _with(g, reference_states=np.zeros((T, 4))), InvalidArrayError,
     "reference_states"),
    (lambda g: _with(g, reference_states=np.full((T + 1, 4), np.inf)), InvalidArrayError,
     "reference_states"),
    (lambda g: _with(g, reference_inputs=np.zeros((T, 3))), InvalidArrayError,
     "reference_inputs"),
    (lambda g: _with(g, reference_inputs=np.full((T, 2), np.nan)), InvalidArrayError,
     "reference_inputs"),
    (lambda g: _with(g, halfspaces=(np.zeros((4, T, 2)), np.zeros((4, T)))), InvalidArrayError,
     "n_obstacles"),
    (lambda g: _with(g, halfspaces=(np.zeros((2, T, 3)), np.zeros((2, T)))), InvalidArrayError,
     "halfspaces.normals"),
    (lambda g: _with(g, halfspaces=(np.zeros((2, T, 2)), np.zeros((1, T)))), InvalidArrayError,
     "halfspaces.offsets"),
    (lambda g: _with(g, halfspaces=(np.full((2, T, 2), np.nan), np.zeros((2, T)))),
     InvalidArrayError, "halfspaces.normals"),
    (lambda g: _with(g, halfspaces=(np.zeros((2, T, 2)), np.full((2, T), np.inf))),
     InvalidArrayError, "halfspaces.offsets"),
    (lambda g: _with(g, halfspaces=np.zeros((2, T, 2))), InvalidTypeError, "halfspaces"),
    (lambda g: _with(g, halfspaces=(np.zeros(3), np.zeros(3))), InvalidArrayError,
     "halfspaces.normals"),
]


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize(("make", "error", "name"), BAD_SOLVE)
def test_bad_solve_arguments_raise(backend, make, error, name):
    instance = make(random_instance(np.random.default_rng(16), 2))
    with pytest.raises(error, match=name):
        solve(make_filter(backend), instance)


def test_step_arrays_accept_finite_data_whose_sum_overflows():
    """The one-reduction finiteness check falls back to the per-array checks, which pass
    finite data whose total overflows (the offsets of switched-off rows may be huge)."""
    from filters.mpc.checks import step_arrays

    x0, states = np.zeros(4), np.zeros((T + 1, 4))
    normals, offsets = np.zeros((2, T, 2)), np.full((2, T), 1e308)
    checked = step_arrays(x0, states, None, (normals, offsets), T, 4, 2, 2, 3)
    assert checked[3] is normals and checked[4] is offsets and checked[2] is None
    offsets[1, 3] = np.nan
    with pytest.raises(InvalidArrayError, match=r"halfspaces.offsets .*\(1, 3\)"):
        step_arrays(x0, states, None, (normals, offsets), T, 4, 2, 2, 3)


def test_errors_share_the_package_base_and_subclass_builtins():
    for error in (InvalidArrayError, InvalidParameterError, InvalidTypeError):
        assert issubclass(error, SafeNavError)
    assert issubclass(InvalidArrayError, ValueError) and issubclass(InvalidTypeError, TypeError)


# --------------------------------------------------------------------------- values, API
def test_result_is_a_frozen_value():
    result = solve(make_filter(), random_instance(np.random.default_rng(16), 2))
    assert isinstance(result, FilterResult) and result.status.value == "optimal"
    assert result.inputs.shape == (T, 2) and result.states.shape == (T + 1, 4)
    assert result.slack is None and result.bound_slack == 0.0
    assert result.solve_time > 0.0 and result.total_time >= result.solve_time
    assert result.iterations > 0 and result.solver_status == "Solved"
    np.testing.assert_array_equal(result.first_input, result.inputs[0])
    assert result.solved and not result.fallback
    with pytest.raises(dataclasses.FrozenInstanceError):
        result.status = FilterStatus.BRAKE  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        result.inputs[0, 0] = 1.0


def test_problem_is_a_frozen_validated_value():
    problem = MPCProblem(A, B, C, T, np.eye(2), 4 * np.eye(4), 25 * np.eye(4))
    with pytest.raises(dataclasses.FrozenInstanceError):
        problem.horizon = 3  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        problem.A[0, 0] = 2.0
    phi, gamma = problem.rollout
    u = np.random.default_rng(0).normal(size=(T, 2))
    x0 = np.array([0.1, 0.2, 0.3, 0.4])
    np.testing.assert_allclose((phi @ x0 + gamma @ u.ravel()).reshape(T, 4), rollout(x0, u)[1:])
    with pytest.raises(InvalidParameterError, match="soft_rows"):
        problem.with_soft_rows({"arena"})


def test_scalar_and_infinite_bounds_are_accepted():
    mpc = make_filter(input_bounds=(-np.inf, [5.0, np.inf]), position_bounds=None)
    assert mpc.input_bounds[0].shape == (2,)
    assert solve(mpc, random_instance(np.random.default_rng(16), 2)).status is FilterStatus.OPTIMAL


@pytest.mark.slow
def test_importing_the_filter_does_not_import_cvxpy():
    # the CVXPY reference filter imports CVXPY when it builds its first QP, not before
    code = ("import sys, filters, filters.mpc; assert 'cvxpy' not in sys.modules; "
            "filters.CVXPYSafetyFilter; sys.exit(int('cvxpy' in sys.modules))")
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


@pytest.mark.parametrize("soft", [False, True])
def test_a_general_output_map_matches_the_reference(soft):
    """C mixes state entries (not [I 0]): the halfspace entries a' C are written through
    the index map instead of copied from the normals."""
    mixed = np.array([[1.0, 0.0, 0.3, 0.0], [0.2, 1.0, 0.0, -0.1]])
    fast = MPCSafetyFilter(A, B, mixed, **{**KWARGS, "soft": soft})
    reference = MPCSafetyFilter(A, B, mixed, backend="cvxpy", **{**KWARGS, "soft": soft})
    for instance in mode_instances("soft", 17, 6):
        ours, theirs = solve(fast, instance), solve(reference, instance)
        assert ours.status == theirs.status
        np.testing.assert_allclose(ours.inputs[0], theirs.inputs[0], atol=3e-3)
        if ours.status is FilterStatus.OPTIMAL:
            np.testing.assert_allclose(ours.inputs, theirs.inputs, atol=1e-4)

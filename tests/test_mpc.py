"""Tests of the MPC safety filter (Problem 2): fast Clarabel filter vs CVXPY reference."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from functools import cache
from types import SimpleNamespace

import cvxpy as cp
import numpy as np
import pytest

from filters.benchmarks.filter_qp import (
    benchmark_filter_qp,
    double_integrator,
    filter_kwargs,
    format_filter_qp,
)
from filters.errors import InvalidArrayError, InvalidParameterError, InvalidTypeError
from filters.mpc import FilterResult, FilterStatus, MPCSafetyFilter
from filters.mpc_cvxpy import CVXPYSafetyFilter

T = 10
TS = 0.2
A, B, C = double_integrator(TS)
KWARGS = filter_kwargs(T, 3)  # Q = 4 I, Q_T = 25 I, R = I, |u| <= 5, arena [-5, 5]^2


def random_instance(
    rng: np.random.Generator, k: int, *, with_inputs: bool = False
) -> dict[str, object]:
    """Ego at 1.5 m/s along +x, ``k`` obstacles ahead, halfspaces toward them."""
    x0 = np.array([rng.uniform(-4.0, 0.0), rng.uniform(-1.0, 1.0), 1.5, rng.normal(0, 0.2)])
    reference = np.empty((T + 1, 4))
    reference[:, 0] = x0[0] + 1.5 * TS * np.arange(T + 1)
    reference[:, 1] = x0[1] + rng.normal(0, 0.2)
    reference[:, 2:] = (1.5, 0.0)
    obstacles = x0[:2] + np.column_stack([rng.uniform(1.0, 4.0, k), rng.uniform(-1.0, 1.0, k)])
    velocity = rng.normal(0.0, 0.4, (k, 2))
    predicted = obstacles[:, None] + velocity[:, None] * TS * np.arange(1, T + 1)[None, :, None]
    direction = predicted - reference[None, 1:, :2]
    normals = direction / np.linalg.norm(direction, axis=-1, keepdims=True)
    offsets = np.einsum("ktd,ktd->kt", normals, predicted) - rng.uniform(0.5, 0.8, (k, 1))
    instance = {"x0": x0, "reference_states": reference, "halfspaces": (normals, offsets)}
    if with_inputs:
        instance["reference_inputs"] = rng.normal(0.0, 1.0, (T, 2))
    return instance


def solve(mpc, instance):
    x0, reference = instance["x0"], instance["reference_states"]
    extra = {"reference_inputs": instance.get("reference_inputs")}
    return mpc.solve(x0, reference, instance["halfspaces"], **extra)


@cache
def cvxpy_filter(n_obstacles: int = 3, soft: bool = False) -> CVXPYSafetyFilter:
    kwargs = {**KWARGS, "n_obstacles": n_obstacles}
    return CVXPYSafetyFilter(A, B, C, soft=soft, **kwargs)


def fast_filter(n_obstacles: int = 3, soft: bool = False, **extra) -> MPCSafetyFilter:
    kwargs = {**KWARGS, "n_obstacles": n_obstacles, **extra}
    return MPCSafetyFilter(A, B, C, soft=soft, **kwargs)


def violation(result: FilterResult, halfspaces) -> float:
    normals, offsets = halfspaces
    positions = result.states[1:] @ C.T
    return float(np.max(np.einsum("ktd,td->kt", normals, positions) - offsets, initial=-np.inf))


def infeasible_halfspaces(k: int = 1):
    """x <= -100 m at every step: unreachable."""
    normals = np.zeros((k, T, 2))
    normals[..., 0] = 1.0
    return normals, np.full((k, T), -100.0)


# --------------------------------------------------------------------------- vs CVXPY
@pytest.mark.parametrize("soft", [False, True])
def test_matches_cvxpy_on_random_instances(soft):
    rng = np.random.default_rng(1)
    fast, reference = fast_filter(soft=soft), cvxpy_filter(soft=soft)
    compared = 0
    for _ in range(25):
        instance = random_instance(rng, int(rng.integers(0, 4)), with_inputs=rng.random() < 0.5)
        fast.reset()
        reference.reset()
        ours, theirs = solve(fast, instance), solve(reference, instance)
        assert ours.status == theirs.status
        if ours.solved:
            compared += 1
            np.testing.assert_allclose(ours.inputs, theirs.inputs, atol=1e-4)
            assert ours.objective == pytest.approx(theirs.objective, rel=1e-6, abs=1e-4)
            if soft:
                np.testing.assert_allclose(ours.slack, theirs.slack, atol=1e-4)
    assert compared >= 15


def test_optimal_solution_satisfies_constraints():
    rng = np.random.default_rng(2)
    mpc = fast_filter()
    low, high = KWARGS["input_bounds"]
    for _ in range(40):
        instance = random_instance(rng, 3)
        result = solve(mpc, instance)
        if result.status is not FilterStatus.OPTIMAL:
            continue
        assert violation(result, instance["halfspaces"]) <= 1e-6
        assert np.all(result.inputs >= low) and np.all(result.inputs <= high)
        assert np.all(np.abs(result.states[:, :2]) <= 5.0 + 1e-6)
        np.testing.assert_allclose(result.states[0], instance["x0"])
        np.testing.assert_allclose(
            result.states[1:], result.states[:-1] @ A.T + result.inputs @ B.T, atol=1e-12
        )


def test_safe_reference_passes_through_unchanged():
    rng = np.random.default_rng(3)
    mpc = fast_filter()
    for _ in range(10):
        x0 = np.array([rng.uniform(-2, 0), rng.uniform(-1, 1), 1.0, 0.0])
        inputs = rng.uniform(-1.0, 1.0, (T, 2))
        states = [x0]
        for u in inputs:
            states.append(A @ states[-1] + B @ u)
        states = np.array(states)
        normals = rng.normal(size=(3, T, 2))
        normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
        offsets = np.einsum("ktd,td->kt", normals, states[1:, :2]) + rng.uniform(0.1, 1.0, (3, T))
        result = mpc.solve(x0, states, (normals, offsets), reference_inputs=inputs)
        assert result.status is FilterStatus.OPTIMAL
        np.testing.assert_allclose(result.inputs, inputs, atol=1e-6)
        np.testing.assert_allclose(result.states, states, atol=1e-6)
        assert result.objective == pytest.approx(0.0, abs=1e-9)


# --------------------------------------------------------------------------- build once
@pytest.mark.parametrize("soft", [False, True])
def test_update_equals_rebuild(soft):
    rng = np.random.default_rng(4)
    persistent = fast_filter(soft=soft)
    for _ in range(20):
        instance = random_instance(
            rng, int(rng.integers(0, 4)), with_inputs=rng.random() < 0.5
        )
        persistent.reset()
        updated = solve(persistent, instance)
        rebuilt = solve(fast_filter(soft=soft), instance)
        assert updated.status == rebuilt.status
        np.testing.assert_allclose(updated.inputs, rebuilt.inputs, atol=1e-8)
        assert updated.objective == pytest.approx(rebuilt.objective, rel=1e-10, abs=1e-8)


@pytest.mark.parametrize("k", [0, 1, 2])
def test_fewer_halfspaces_equal_filter_built_for_exactly_that_many(k):
    rng = np.random.default_rng(5 + k)
    large, exact = fast_filter(n_obstacles=3), fast_filter(n_obstacles=k)
    for _ in range(10):
        instance = random_instance(rng, k)
        ours, theirs = solve(large, instance), solve(exact, instance)
        assert ours.status == theirs.status
        np.testing.assert_allclose(ours.inputs, theirs.inputs, atol=1e-5)


def test_no_halfspaces_accepts_none_and_empty():
    rng = np.random.default_rng(8)
    instance = random_instance(rng, 0)
    mpc = fast_filter()
    with_none = mpc.solve(instance["x0"], instance["reference_states"], None)
    empty = mpc.solve(instance["x0"], instance["reference_states"], instance["halfspaces"])
    as_object = mpc.solve(
        instance["x0"], instance["reference_states"],
        SimpleNamespace(normals=np.zeros((0, T, 2)), offsets=np.zeros((0, T))),
    )
    np.testing.assert_array_equal(with_none.inputs, empty.inputs)
    np.testing.assert_array_equal(with_none.inputs, as_object.inputs)


# --------------------------------------------------------------------------- fallbacks
def test_infeasible_shifts_last_plan_then_brakes():
    rng = np.random.default_rng(9)
    instance = random_instance(rng, 1)
    mpc = fast_filter(n_obstacles=1)
    first = solve(mpc, instance)
    assert first.status is FilterStatus.OPTIMAL
    plan = first.inputs
    x0, reference = instance["x0"], instance["reference_states"]
    for shift in range(1, T):
        result = mpc.solve(x0, reference, infeasible_halfspaces())
        assert result.status is FilterStatus.SHIFTED
        assert result.consecutive_failures == shift
        assert "Infeasible" in result.solver_status
        np.testing.assert_array_equal(result.first_input, plan[shift])
        np.testing.assert_array_equal(result.inputs[: T - shift], plan[shift:])
        np.testing.assert_allclose(result.states[0], x0)
    result = mpc.solve(x0, reference, infeasible_halfspaces())
    assert result.status is FilterStatus.BRAKE
    assert result.consecutive_failures == T
    # a successful solve stores a new plan and clears the count
    again = solve(mpc, instance)
    assert again.status is FilterStatus.OPTIMAL and again.consecutive_failures == 0
    shifted = mpc.solve(x0, reference, infeasible_halfspaces())
    assert shifted.status is FilterStatus.SHIFTED
    np.testing.assert_array_equal(shifted.first_input, again.inputs[1])


def test_brake_without_plan_cancels_velocity_within_input_bounds():
    mpc = fast_filter(n_obstacles=1)
    x0 = np.array([0.0, 0.0, 0.8, -0.4])
    reference = np.tile(x0, (T + 1, 1))
    result = mpc.solve(x0, reference, infeasible_halfspaces())
    assert result.status is FilterStatus.BRAKE
    np.testing.assert_allclose(result.first_input, -x0[2:] / TS)  # inside |u| <= 5
    np.testing.assert_allclose(result.states[1:, 2:], 0.0, atol=1e-12)
    np.testing.assert_allclose(result.inputs[1:], 0.0, atol=1e-12)

    fast = np.array([0.0, 0.0, 3.0, 0.0])  # -v / Ts = -15 m/s^2 is clipped to -5
    result = mpc.solve(fast, np.tile(fast, (T + 1, 1)), infeasible_halfspaces())
    np.testing.assert_allclose(result.first_input, [-5.0, 0.0])
    np.testing.assert_allclose(result.states[3, 2], 0.0, atol=1e-12)  # 3 m/s, 1 m/s per step


def test_custom_brake_gain_is_used():
    gain = np.hstack([np.zeros((2, 2)), 2.0 * np.eye(2)])  # u = -2 v
    mpc = fast_filter(n_obstacles=1, brake_gain=gain)
    x0 = np.array([0.0, 0.0, 1.0, -0.5])
    result = mpc.solve(x0, np.tile(x0, (T + 1, 1)), infeasible_halfspaces())
    assert result.status is FilterStatus.BRAKE
    np.testing.assert_allclose(result.first_input, [-2.0, 1.0])
    np.testing.assert_allclose(result.inputs[1], -2.0 * result.states[1, 2:])


def test_reset_forgets_the_plan():
    rng = np.random.default_rng(10)
    instance = random_instance(rng, 1)
    mpc = fast_filter(n_obstacles=1)
    assert solve(mpc, instance).status is FilterStatus.OPTIMAL
    assert mpc.last_plan is not None
    mpc.reset()
    assert mpc.last_plan is None
    x0, reference = instance["x0"], instance["reference_states"]
    assert mpc.solve(x0, reference, infeasible_halfspaces()).status is FilterStatus.BRAKE


class _BrokenSolver:
    """Stands in for clarabel.DefaultSolver: raises, or returns a NaN 'solution'."""

    def __init__(self, mode: str, size: int):
        self.mode, self.size = mode, size

    def update(self, **_):
        return None

    def solve(self):
        if self.mode == "raise":
            raise RuntimeError("solver exploded")
        return SimpleNamespace(
            status="Solved", x=[np.nan] * self.size, iterations=3, obj_val=np.nan
        )


@pytest.mark.parametrize(("mode", "message"), [("raise", "exception"), ("nan", "non-finite")])
def test_solver_failure_falls_back_and_never_raises(mode, message):
    rng = np.random.default_rng(11)
    instance = random_instance(rng, 2)
    mpc = fast_filter()
    plan = solve(mpc, instance).inputs
    mpc._solver = _BrokenSolver(mode, mpc._shape[1])
    result = solve(mpc, instance)
    assert result.status is FilterStatus.SHIFTED
    assert message in result.solver_status
    np.testing.assert_array_equal(result.first_input, plan[1])
    assert np.all(np.isfinite(result.inputs)) and np.all(np.isfinite(result.states))
    assert np.isfinite(result.objective)


def test_iteration_limit_is_a_failure_not_an_exception():
    rng = np.random.default_rng(12)
    mpc = fast_filter(solver_settings={"max_iter": 1})
    result = solve(mpc, random_instance(rng, 3))
    assert result.status is FilterStatus.BRAKE
    assert result.solver_status.startswith("MaxIterations")


# --------------------------------------------------------------------------- soft mode
def test_soft_mode_on_infeasible_instance_reports_positive_slack():
    rng = np.random.default_rng(13)
    instance = random_instance(rng, 2)
    normals, offsets = instance["halfspaces"]
    offsets = offsets.copy()
    offsets[0] = np.einsum("td,d->t", normals[0], instance["x0"][:2]) - 3.0  # 3 m behind
    halfspaces = (normals, offsets)
    hard = fast_filter(n_obstacles=2).solve(
        instance["x0"], instance["reference_states"], halfspaces
    )
    assert hard.status is FilterStatus.BRAKE
    soft = fast_filter(n_obstacles=2, soft=True).solve(
        instance["x0"], instance["reference_states"], halfspaces
    )
    assert soft.status is FilterStatus.SOFT
    assert soft.slack.shape == (2, T)
    assert np.all(soft.slack >= 0.0) and soft.slack.sum() > 0.1
    # the slack is the violation of the returned trajectory
    positions = soft.states[1:] @ C.T
    violated = np.maximum(np.einsum("ktd,td->kt", normals, positions) - offsets, 0.0)
    np.testing.assert_allclose(soft.slack, violated, atol=1e-6)


def test_soft_mode_equals_hard_mode_when_feasible():
    rng = np.random.default_rng(14)
    hard, soft = fast_filter(), fast_filter(soft=True)
    compared = 0
    for _ in range(20):
        instance = random_instance(rng, 3)
        ours = solve(hard, instance)
        if ours.status is not FilterStatus.OPTIMAL:
            continue
        compared += 1
        softened = solve(soft, instance)
        assert softened.status is FilterStatus.OPTIMAL
        np.testing.assert_array_equal(softened.slack, 0.0)
        np.testing.assert_allclose(softened.inputs, ours.inputs, atol=1e-5)
    assert compared >= 10


def minimal_l1_violation(instance, n_obstacles: int) -> float:
    """min sum(s) over the dynamics, the bounds and the softened halfspaces (CVXPY LP)."""
    normals, offsets = instance["halfspaces"]
    u = cp.Variable((T, 2))
    x = cp.Variable((T + 1, 4))
    s = cp.Variable((normals.shape[0], T), nonneg=True)
    constraints = [x[0] == instance["x0"], cp.abs(u) <= 5.0, cp.abs(x[1:, :2]) <= 5.0]
    constraints += [x[t + 1] == A @ x[t] + B @ u[t] for t in range(T)]
    for i in range(normals.shape[0]):
        constraints.append(
            cp.sum(cp.multiply(normals[i], x[1:, :2]), axis=1) <= offsets[i] + s[i]
        )
    problem = cp.Problem(cp.Minimize(cp.sum(s)), constraints)
    problem.solve(solver=cp.CLARABEL)
    return float(problem.value)


def test_soft_slack_is_the_minimal_l1_violation():
    rng = np.random.default_rng(15)
    soft = fast_filter(soft=True)
    checked = 0
    for _ in range(30):
        instance = random_instance(rng, 3)
        normals, offsets = instance["halfspaces"]
        instance["halfspaces"] = (normals, offsets - rng.uniform(0.5, 2.0))  # tighter
        result = solve(soft, instance)
        if result.status is not FilterStatus.SOFT:
            continue
        checked += 1
        assert result.slack.sum() == pytest.approx(minimal_l1_violation(instance, 3), abs=1e-5)
        theirs = solve(cvxpy_filter(soft=True), instance)
        np.testing.assert_allclose(result.slack, theirs.slack, atol=1e-4)
        # Violations of metres cost rho * sum(s) ~ 1e7, which dwarfs the quadratic
        # cost: at the relative gap 1e-10 both solvers pin the inputs to ~3e-4 only.
        np.testing.assert_allclose(result.inputs, theirs.inputs, atol=2e-3)
    assert checked >= 5


# --------------------------------------------------------------------------- bad input
def _good():
    rng = np.random.default_rng(16)
    return random_instance(rng, 2)


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
    ({"brake_gain": np.zeros((4, 2))}, InvalidArrayError, "brake_gain"),
    ({"brake_gain": np.full((2, 4), np.inf)}, InvalidArrayError, "brake_gain"),
]
BAD_SETTINGS = [  # the CVXPY reference passes its settings to problem.solve unchecked
    ({"solver_settings": {"presolve_enable": True}}, InvalidParameterError, "presolve"),
    ({"solver_settings": {"input_sparse_dropzeros": True}}, InvalidParameterError, "dropzeros"),
    ({"solver_settings": {"no_such_setting": 1}}, InvalidParameterError, "no_such_setting"),
    ({"solver_settings": [("max_iter", 1)]}, InvalidTypeError, "solver_settings"),
]


def _construct(cls, change):
    kwargs = {"A": A, "B": B, "C": C, **KWARGS, **change}
    matrices = [kwargs.pop(key) for key in ("A", "B", "C")]
    return cls(*matrices, **kwargs)


@pytest.mark.parametrize("cls", [MPCSafetyFilter, CVXPYSafetyFilter])
@pytest.mark.parametrize(("change", "error", "name"), BAD_CONSTRUCTOR)
def test_bad_constructor_arguments_raise(cls, change, error, name):
    with pytest.raises(error, match=name):
        _construct(cls, change)


@pytest.mark.parametrize(("change", "error", "name"), BAD_SETTINGS)
def test_bad_solver_settings_raise(change, error, name):
    with pytest.raises(error, match=name):
        _construct(MPCSafetyFilter, change)


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


@pytest.mark.parametrize(("make", "error", "name"), BAD_SOLVE)
def test_bad_solve_arguments_raise(make, error, name):
    instance = make(_good())
    with pytest.raises(error, match=name):
        solve(fast_filter(), instance)


def test_errors_subclass_builtins():
    assert issubclass(InvalidArrayError, ValueError)
    assert issubclass(InvalidTypeError, TypeError)


# --------------------------------------------------------------------------- result, API
def test_result_is_a_frozen_value():
    result = solve(fast_filter(), _good())
    assert isinstance(result.status, FilterStatus) and result.status.value == "optimal"
    assert result.inputs.shape == (T, 2) and result.states.shape == (T + 1, 4)
    assert result.slack is None
    assert result.solve_time > 0.0 and result.total_time >= result.solve_time
    assert result.iterations > 0 and result.solver_status == "Solved"
    np.testing.assert_array_equal(result.first_input, result.inputs[0])
    assert result.solved and not result.fallback
    with pytest.raises(dataclasses.FrozenInstanceError):
        result.status = FilterStatus.BRAKE  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        result.inputs[0, 0] = 1.0


def test_status_is_a_string_enum():
    assert FilterStatus.SHIFTED == "shifted"
    assert {status.value for status in FilterStatus} == {"optimal", "soft", "shifted", "brake"}


def test_scalar_and_infinite_bounds_are_accepted():
    mpc = fast_filter(input_bounds=(-np.inf, [5.0, np.inf]), position_bounds=None)
    assert mpc.input_bounds[0].shape == (2,)
    result = solve(mpc, _good())
    assert result.status is FilterStatus.OPTIMAL


def test_importing_the_fast_filter_does_not_import_cvxpy():
    code = "import sys, filters.mpc; sys.exit(int('cvxpy' in sys.modules))"
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


def test_benchmark_runs_and_formats():
    result = benchmark_filter_qp(n_steps=15, seed=1)
    assert result.n_steps == 15 and result.ratio > 0.0
    assert result.agreement == 1.0 and result.max_input_difference < 1e-4
    text = format_filter_qp(result)
    assert "MPCSafetyFilter" in text and "speed-up" in text

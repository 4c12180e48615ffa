"""The Riccati interior-point back end (the recovery QP of long horizons) against CVXPY.

:class:`filters.mpc.backends.riccati.RiccatiBackend` solves the QP whose every row is
soft. On random instances (mildly and strongly infeasible crossings, with and without a
terminal set, both objectives, one-sided and free input bounds, fewer obstacles than
rows) at T = 10 to 80 it must reach the CVXPY reference's penalised objective, and
its inputs must agree with the reference's where the QP pins them: all of them without
a violated row, the first input with one. Bad settings and QPs with hard rows are
refused with a clear error; a failed solve is a status.
"""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.filter_qp import RADIUS, double_integrator, filter_kwargs
from benchmarks.scaling import make_scaling_instances
from filters import Disc, safe_halfspaces
from filters.errors import InvalidParameterError, InvalidTypeError
from filters.mpc import MPCSafetyFilter, stopping_terminal_set
from filters.mpc.backends.riccati import RiccatiBackend, every_row_soft
from filters.mpc.problem import MPCProblem
from filters.mpc.result import StepData

pytest.importorskip("cvxpy")
from filters.mpc.backends.cvxpy import CVXPYBackend  # noqa: E402

TS = 0.2
A, B, C = double_integrator(TS)
RHO = 1e6


def recovery_problem(horizon: int, n_obstacles: int, *, objective: str = "trajectory",
                     terminal: bool = False, input_bounds=None) -> MPCProblem:
    kwargs = filter_kwargs(horizon, n_obstacles)
    if objective == "first_input":
        kwargs.pop("Q")
        kwargs.pop("Q_terminal")
    if terminal:
        kwargs["terminal_set"] = stopping_terminal_set(
            TS, kwargs["input_bounds"], kwargs["position_bounds"])
    if input_bounds is not None:
        kwargs["input_bounds"] = input_bounds
    return MPCSafetyFilter(A, B, C, objective=objective, **kwargs)._recovery.problem


def random_step(rng: np.random.Generator, problem: MPCProblem, k: int) -> StepData:
    """A crossing whose halfspaces cut into the reference (``k`` of the rows used, the
    rest disabled as the filter pads them), sometimes with the ego outside the arena."""
    T, K = problem.horizon, problem.n_obstacles
    x0 = np.array([rng.uniform(-4.5, -2.0), rng.uniform(-1.0, 1.0), 1.0, rng.normal(0, 0.3)])
    if rng.random() < 0.3:
        x0[0], x0[2] = -5.0 - rng.uniform(0.05, 0.5), -rng.uniform(0.0, 1.0)
    steps = np.arange(1, T + 1)
    ref_states = np.zeros((T, 4))
    ref_states[:, 0] = x0[0] + rng.uniform(0.5, 2.0) * TS * steps
    ref_states[:, 1] = x0[1] + rng.normal(0.0, 0.3)
    ref_states[:, 2] = 1.0
    ref_inputs = rng.normal(0.0, 1.0, (T, 2)) if rng.random() < 0.5 else np.zeros((T, 2))
    centres = x0[:2] + np.column_stack([rng.uniform(1.0, 4.0, k), rng.uniform(-1.0, 1.0, k)])
    predicted = centres[:, None] + rng.normal(0.0, 0.4, (k, 1, 2)) * TS * steps[None, :, None]
    direction = predicted - ref_states[None, :, :2]
    normals = np.zeros((K, T, 2))
    offsets = np.ones((K, T))  # unused rows read 0 @ y <= 1, as the filter pads them
    normals[:k] = direction / np.linalg.norm(direction, axis=-1, keepdims=True)
    offsets[:k] = (np.einsum("ktd,ktd->kt", normals[:k], predicted)
                   - rng.uniform(0.5, 3.0, (k, 1)))
    return StepData(x0, ref_states, ref_inputs, normals, offsets)


def penalised(problem: MPCProblem, step: StepData, inputs: np.ndarray) -> tuple[float, float]:
    """The soft QP's objective at ``inputs`` (rows evaluated on the roll-out), and the
    total violation in m."""
    T = problem.horizon
    states = [step.x0]
    for t in range(T):
        states.append(problem.A @ states[-1] + problem.B @ inputs[t])
    states = np.array(states)
    cost = problem.cost(inputs, states, step.ref_states, step.ref_inputs)
    positions = states[1:] @ problem.C.T
    excess = [np.einsum("ktd,td->kt", step.normals, positions) - step.offsets]
    low, high = problem.position_bounds
    excess += [positions - high, low - positions]
    if problem.terminal_set is not None:
        G, g = problem.terminal_set
        excess.append(G @ states[-1] - g)
    violation = sum(float(np.maximum(e, 0.0).sum()) for e in excess)
    return cost + problem.slack_penalty * violation, violation


CASES = [
    (10, "trajectory", False, None),
    (20, "first_input", True, None),
    (20, "trajectory", True, (np.array([-10.0, -np.inf]), np.array([10.0, 4.0]))),
    pytest.param(40, "trajectory", True, None, marks=pytest.mark.slow),
    pytest.param(80, "trajectory", False, None, marks=pytest.mark.slow),
    pytest.param(80, "first_input", True, None, marks=pytest.mark.slow),
]


@pytest.mark.parametrize(("horizon", "objective", "terminal", "bounds"), CASES)
def test_it_equals_the_cvxpy_reference(horizon, objective, terminal, bounds):
    problem = recovery_problem(horizon, 3, objective=objective, terminal=terminal,
                               input_bounds=bounds)
    ours, reference = RiccatiBackend(problem), CVXPYBackend(problem)
    rng = np.random.default_rng([horizon, terminal, objective == "first_input"])
    violated = 0
    for case in range(4):
        step = random_step(rng, problem, k=1 + case % 3)
        mine, theirs = ours.solve(step), reference.solve(step)
        assert mine.found and mine.status == "Solved", mine.status
        assert theirs.found
        low, high = problem.input_bounds
        assert np.all(mine.inputs >= low - 1e-9) and np.all(mine.inputs <= high + 1e-9)
        value, violation = penalised(problem, step, mine.inputs)
        best, _ = penalised(problem, step, theirs.inputs)
        # never worse than the reference beyond its own gap tolerance (1e-10 relative)
        assert value <= best + 1e-8 * max(1.0, abs(best))
        assert value == pytest.approx(best, rel=1e-7, abs=1e-6)
        # the reported slacks are the violations of the returned inputs
        assert mine.halfspace_slack.sum() + mine.bound_slack.sum() == pytest.approx(
            violation, rel=1e-6, abs=1e-6)
        if violation <= 1e-6 and objective == "trajectory":
            np.testing.assert_allclose(mine.inputs, theirs.inputs, atol=2e-4)
        else:  # the L1 penalty dwarfs the cost: the first input is pinned
            np.testing.assert_allclose(mine.inputs[0], theirs.inputs[0], atol=3e-3)
        violated += violation > 1e-6
    assert violated  # the penalty was exercised


@pytest.mark.slow
def test_strongly_infeasible_long_horizon_steps_match_the_reference():
    """The scaling benchmark's ``straight`` crossings at T = 80: tens of violated rows."""
    T, K = 80, 10
    problem = recovery_problem(T, K)
    ours, reference = RiccatiBackend(problem), CVXPYBackend(problem)
    rng = np.random.default_rng(3)
    zero = np.zeros((T, 2))
    rows = []
    for instance in make_scaling_instances(40, K, T, 50, rng, family="straight")[::8]:
        hs = safe_halfspaces(instance.reference_states[1:, :2], instance.samples,
                             ego_shape=Disc(RADIUS), obstacle_shapes=[Disc(RADIUS)] * K,
                             risk="dr_cvar", ego_velocity=instance.x0[2:])
        step = StepData(instance.x0, instance.reference_states[1:], zero,
                        np.asarray(hs.normals), np.asarray(hs.offsets))
        mine, theirs = ours.solve(step), reference.solve(step)
        assert mine.found and theirs.found
        value, _ = penalised(problem, step, mine.inputs)
        best, _ = penalised(problem, step, theirs.inputs)
        assert value == pytest.approx(best, rel=1e-7)
        np.testing.assert_allclose(mine.inputs[0], theirs.inputs[0], atol=3e-3)
        rows.append(int(np.count_nonzero(mine.halfspace_slack > 1e-6)
                        + np.count_nonzero(mine.bound_slack > 1e-6)))
    assert min(rows) >= 20, rows  # every one strongly infeasible


def test_it_refuses_qps_with_hard_rows_and_bad_settings():
    hard = MPCSafetyFilter(A, B, C, **filter_kwargs(20, 3)).problem
    assert not every_row_soft(hard)
    with pytest.raises(InvalidParameterError, match="soft_rows"):
        RiccatiBackend(hard)
    soft_halfspaces_only = hard.with_soft_rows({"halfspaces"})  # the arena stays hard
    with pytest.raises(InvalidParameterError, match="soft_rows"):
        RiccatiBackend(soft_halfspaces_only)
    problem = recovery_problem(20, 3)
    assert every_row_soft(problem)
    for settings, match in (({"tolerance": 0.0}, "tolerance"), ({"tolerance": "a"}, "tolerance"),
                            ({"max_iterations": 0}, "max_iterations"),
                            ({"max_iterations": 2.5}, "max_iterations"),
                            ({"tol": 1e-8}, "unknown")):
        with pytest.raises(InvalidParameterError, match=match):
            RiccatiBackend(problem, solver_settings=settings)
    with pytest.raises(InvalidTypeError, match="mapping"):
        RiccatiBackend(problem, solver_settings=[("tolerance", 1e-8)])


def test_a_failed_solve_is_a_status_not_an_exception():
    problem = recovery_problem(20, 3)
    rng = np.random.default_rng(0)
    step = random_step(rng, problem, k=3)
    starved = RiccatiBackend(problem, solver_settings={"max_iterations": 1})
    answer = starved.solve(step)
    assert not answer.found and answer.status == "MaxIterations" and answer.inputs is None
    bad = StepData(step.x0, step.ref_states, step.ref_inputs,
                   np.full_like(step.normals, np.nan), step.offsets)
    answer = RiccatiBackend(problem).solve(bad)
    assert not answer.found and answer.inputs is None
    # the same backend still solves the next good step
    assert RiccatiBackend(problem).solve(step).found


def test_the_same_step_gives_the_same_bits():
    problem = recovery_problem(40, 3, terminal=True)
    step = random_step(np.random.default_rng(5), problem, k=3)
    first, second = RiccatiBackend(problem).solve(step), RiccatiBackend(problem).solve(step)
    np.testing.assert_array_equal(first.inputs, second.inputs)
    assert first.iterations == second.iterations


def test_without_rows_or_box_it_is_the_unconstrained_minimiser():
    """No halfspace, arena or terminal row and a free input: the LQ optimum
    :math:`u^\\circ = u^r + K (x^r - \\Phi x_0 - \\Gamma u^r)` of ``MPCProblem.gain``."""
    T = 15
    problem = MPCProblem(A, B, C, T, np.eye(2), 4.0 * np.eye(4), 25.0 * np.eye(4),
                         soft_rows={"halfspaces", "bounds"})
    assert every_row_soft(problem)
    rng = np.random.default_rng(2)
    step = StepData(rng.normal(size=4), rng.normal(size=(T, 4)), rng.normal(size=(T, 2)),
                    np.zeros((0, T, 2)), np.zeros((0, T)))
    answer = RiccatiBackend(problem).solve(step)
    assert answer.found and answer.status == "Solved"
    phi, gamma = problem.rollout
    u_ref = step.ref_inputs.reshape(-1)
    expected = u_ref + problem.gain @ (step.ref_states.reshape(-1) - phi @ step.x0
                                       - gamma @ u_ref)
    np.testing.assert_allclose(answer.inputs.reshape(-1), expected, atol=1e-9)

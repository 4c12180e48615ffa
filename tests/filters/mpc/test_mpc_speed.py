"""The speed limit of the MPC and the braking recovery (issue 26, items 1-3).

* the speed polygon: inside the disc, vertices on it, faces at ``v_max cos(pi/M)``;
* every back end keeps it and agrees with the CVXPY formulation by tolerance on random
  instances whose reference is faster than the limit (same status, inputs to 1e-6 when
  the hard QP answered);
* bad values raise errors naming them;
* the wrapper reads ``env.unwrapped.max_speed`` and a filtered run stays under it;
* the recovery QP brakes: on recorded infeasible steps of a dense crossing its plan has
  the least violation and, among those plans, the lowest speed (CVXPY), and the realised
  speed stays under the limit.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401  (registers the ids)
from filters import SafetyFilterWrapper
from filters.errors import InvalidParameterError
from filters.mpc import FilterStatus, MPCProblem, MPCSafetyFilter
from filters.mpc.problem import speed_polygon
from safe_nav_env import ObstacleSpec, Scenario
from tests.builders import KWARGS, TERMINAL, A, B, C, T, make_filter, random_instance, solve

#: Largest difference of the inputs (m/s²) between a back end and the CVXPY reference.
INPUT_TOLERANCE = 1e-6
TIGHT = {name: 1e-12 for name in ("tol_feas", "tol_gap_abs", "tol_gap_rel")}
LIMIT = 2.0


def _speeds(states: np.ndarray) -> np.ndarray:
    return np.hypot(states[:, 2], states[:, 3])


def _fast_instances(rng: np.random.Generator, count: int) -> list[dict]:
    """Random crossings whose reference runs at 2.5-3.5 m/s, above ``LIMIT``."""
    out = []
    for index in range(count):
        case = random_instance(rng, int(rng.integers(0, 3)), with_inputs=bool(index % 2))
        speed = rng.uniform(2.5, 3.5)
        reference = case["reference_states"]
        reference[:, 0] = case["x0"][0] + speed * 0.2 * np.arange(T + 1)
        reference[:, 2] = speed
        case["x0"][2:] = rng.uniform(-1.0, 1.0, 2) + (1.0, 0.0)
        out.append(case)
    return out


@pytest.mark.parametrize("sides", [4, 8, 16])
def test_the_speed_polygon_is_inscribed_in_the_disc(sides):
    H, h = speed_polygon(3.0, sides, 2)
    np.testing.assert_allclose(np.hypot(*H.T), 1.0, atol=1e-15)
    np.testing.assert_allclose(h, 3.0 * np.cos(np.pi / sides), atol=1e-15)
    angles = np.linspace(0.0, 2 * np.pi, 721)
    circle = 3.0 * np.column_stack([np.cos(angles), np.sin(angles)])
    assert np.all((circle @ H.T - h).max(axis=1) >= -1e-12)  # no point of the circle inside
    for axis in np.eye(2):  # the vertices are on the axes, at radius v_max
        assert np.all(H @ (3.0 * axis) <= h + 1e-12)


@pytest.mark.parametrize("backend", ["auto", "daqp", "clarabel"])
@pytest.mark.parametrize("objective", ["trajectory", "first_input"])
def test_the_speed_limit_equals_the_cvxpy_formulation(backend, objective):
    settings = TIGHT if backend == "clarabel" else None
    ours = make_filter(backend, objective=objective, skip_feasible_reference=False,
                       terminal_set=TERMINAL, max_speed=LIMIT, solver_settings=settings)
    reference = make_filter("cvxpy", objective=objective, terminal_set=TERMINAL,
                            max_speed=LIMIT, solver_settings=TIGHT)
    free = make_filter(backend, objective=objective, skip_feasible_reference=False,
                       terminal_set=TERMINAL)
    rng = np.random.default_rng([29, objective == "trajectory"])
    binding = 0
    for case in _fast_instances(rng, 12):
        mine, theirs = solve(ours, case), solve(reference, case)
        assert mine.status == theirs.status, (mine.solver_status, theirs.solver_status)
        assert np.all(_speeds(mine.states[1:]) <= LIMIT + 1e-6)
        if ours.last_qp_solves == 1:  # the hard QP answered: its unique minimiser
            assert mine.objective <= theirs.objective + 1e-9 * (1.0 + theirs.objective)
            # first_input weighs u_1.. by 1e-2: the reference's later inputs, where the speed
            # rows bind, move its cost by only ~1e-12 and are accurate to ~1e-5
            tolerance = INPUT_TOLERANCE if objective == "trajectory" else 1e-4
            np.testing.assert_allclose(mine.inputs[0], theirs.inputs[0], rtol=0,
                                       atol=INPUT_TOLERANCE)
            np.testing.assert_allclose(mine.inputs, theirs.inputs, rtol=0, atol=tolerance)
        binding += bool(np.max(_speeds(solve(free, case).states[1:])) > LIMIT + 0.1)
    assert binding >= 4  # the limit changed the answer on these


def test_the_speed_rows_are_hard_in_the_recovery_qps():
    mpc = make_filter("daqp", max_speed=LIMIT, terminal_set=TERMINAL)
    normals = np.zeros((1, T, 2))
    normals[..., 0] = 1.0
    x0 = np.array([0.0, 0.0, 1.9, 0.0])
    reference = np.zeros((T + 1, 4))
    result = mpc.solve(x0, reference, (normals, np.full((1, T), -100.0)))  # unreachable wall
    assert mpc.last_qp_solves == 2 and result.status is FilterStatus.SOFT
    # the least violation drives to -x as fast as the limit allows (a vertex, on the axis)
    np.testing.assert_allclose(_speeds(result.states[4:]), LIMIT, atol=1e-6)
    assert np.all(_speeds(result.states[1:]) <= LIMIT + 1e-6)


@pytest.mark.parametrize(("change", "match"), [
    ({"max_speed": 0.0}, "max_speed"), ({"max_speed": -1.0}, "max_speed"),
    ({"max_speed": np.nan}, "max_speed"), ({"speed_sides": 2}, "speed_sides"),
    ({"speed_sides": 8.5}, "speed_sides"),
])
def test_bad_speed_limits_name_the_value(change, match):
    with pytest.raises((InvalidParameterError, TypeError), match=match):
        MPCSafetyFilter(A, B, C, **{**KWARGS, **change})


def test_a_speed_limit_needs_a_position_velocity_state():
    with pytest.raises(InvalidParameterError, match="position; velocity"):
        MPCProblem(np.eye(3), np.ones((3, 1)), np.eye(3)[:1], 5, np.eye(1), np.eye(3),
                   np.eye(3), max_speed=1.0)
    problem = MPCProblem(A, B, C, T, np.eye(2), np.eye(4), np.eye(4))
    assert problem.speed_rows[0].shape == (0, 4)  # inf: no rows


def test_the_wrapper_passes_the_env_speed_limit_and_keeps_it():
    env = SafetyFilterWrapper(gym.make("SafeNav/MultiObstacle-v0", max_speed=2.0))
    env.reset(seed=1)
    assert env._mpc.problem.max_speed == 2.0
    assert env._mpc._recovery.problem.max_speed == 2.0
    for _ in range(20):
        _, _, terminated, truncated, info = env.step(np.array([10.0, 0.0]))
        applied = info["filter"].applied_action
        # the filter's plan keeps the polygon (to the QP's feasibility tolerance, 1e-6 m/s):
        # the env does not have to change its action beyond that
        np.testing.assert_allclose(info["acceleration"], applied, atol=1e-5)
        assert np.hypot(*env.unwrapped.ego_state[2:]) <= 2.0 + 1e-6
        if terminated or truncated:
            break
    free = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0", max_speed=None))
    assert free._mpc.problem.max_speed == np.inf


def _dense_crossing() -> Scenario:
    """Eight obstacles crossing the ego's path at once, from both sides (a crowd)."""
    obstacles = []
    for k in range(8):
        side = 1.0 if k % 2 else -1.0
        x = -1.5 + 0.5 * k
        obstacles.append(ObstacleSpec(start=(x, -2.2 * side), velocity=(0.0, 1.1 * side)))
    return Scenario(name="DenseCrossing", ego_start=(-4.5, 0.0, 1.5, 0.0), goal=(4.5, 0.0),
                    obstacles=tuple(obstacles), duration=6.0)


def _recorded_infeasible_steps(count: int) -> tuple[SafetyFilterWrapper, list]:
    """The wrapper on the dense crossing with a planner pushing at the input bound, and
    up to ``count`` recorded steps where the hard QP was infeasible and the first recovery
    QP answered: ``(step data, result)``; every realised speed is under the limit."""
    env = SafetyFilterWrapper(gym.make("SafeNav/Custom-v0", scenario=_dense_crossing(),
                                       max_obstacles=8), fallback="brake")
    recorded = []
    for seed in range(3):
        env.reset(seed=seed)
        for _ in range(30):
            mpc = env._mpc
            _, _, terminated, truncated, info = env.step(np.array([10.0, 0.0]))
            assert np.hypot(*env.unwrapped.ego_state[2:]) <= env.unwrapped.max_speed + 1e-9
            if mpc.last_qp_solves == 2 and len(recorded) < count:
                step = mpc._step
                recorded.append((step, mpc.solve(step.x0, np.vstack([step.x0, step.ref_states]),
                                                 (step.normals, step.offsets),
                                                 reference_inputs=step.ref_inputs)))
            if terminated or truncated:
                break
    return env, recorded


def test_the_recovery_takes_the_least_violation_then_the_lowest_speed():
    """On recorded infeasible steps of a dense crossing, the recovery's plan has the least
    total violation (an LP in CVXPY, 1e-5 m) and, among the plans with that violation, the
    lowest speed cost (a QP in CVXPY): it brakes rather than speeding up, unless speeding
    up lowers the violation. The arena, the terminal set and the speed limit hold."""
    import cvxpy as cp

    env, recorded = _recorded_infeasible_steps(6)
    assert len(recorded) >= 4
    problem = env._mpc.problem
    (u_low, u_high), (y_low, y_high) = problem.input_bounds, problem.position_bounds
    G, g = problem.terminal_set
    S, s_max = problem.speed_rows
    for step, result in recorded:
        assert result.status in (FilterStatus.SOFT, FilterStatus.OPTIMAL)
        assert result.bound_slack == 0.0
        u, x = cp.Variable((T, 2)), cp.Variable((T + 1, 4))
        slack = cp.Variable(step.offsets.shape, nonneg=True)
        rows = [x[0] == step.x0, u >= np.tile(u_low, (T, 1)), u <= np.tile(u_high, (T, 1)),
                x[1:, :2] >= np.tile(y_low, (T, 1)), x[1:, :2] <= np.tile(y_high, (T, 1)),
                G @ x[T] <= g, x[1:] @ S.T <= np.tile(s_max, (T, 1))]
        rows += [x[t + 1] == A @ x[t] + B @ u[t] for t in range(T)]
        rows += [cp.sum(cp.multiply(step.normals[i], x[1:, :2]), axis=1)
                 <= step.offsets[i] + slack[i] for i in range(step.offsets.shape[0])]
        least = cp.Problem(cp.Minimize(cp.sum(slack)), rows)
        least.solve(solver=cp.CLARABEL, tol_gap_abs=1e-10, tol_gap_rel=1e-10)
        speed_cost = cp.sum_squares(x[1:, 2:]) + 1e-2 * cp.sum_squares(u)
        slowest = cp.Problem(cp.Minimize(speed_cost), rows + [cp.sum(slack) <= least.value + 1e-7])
        slowest.solve(solver=cp.CLARABEL)
        violation = float(result.slack.sum())
        assert violation == pytest.approx(least.value, abs=1e-5)
        ours = float(np.sum(result.states[1:, 2:] ** 2) + 1e-2 * np.sum(result.inputs ** 2))
        assert ours <= slowest.value + 1e-3 * (1.0 + slowest.value)
        assert np.all(_speeds(result.states[1:]) <= problem.max_speed + 1e-6)


def test_the_references_are_rolled_out_under_the_env_speed_limit():
    """The held-action and policy roll-out references apply the environment's own input
    (``applied_input``): the held action's reference is the ego's motion when the env is
    stepped with that action."""
    from filters.references import PolicyRolloutReference, hold_action_reference

    env = gym.make("SafeNav/HeadOn-v0", max_speed=2.0)
    env.reset(seed=0)
    base = env.unwrapped
    action = np.array([10.0, 4.0])
    states, inputs = hold_action_reference(base, action, 6)
    for k in range(6):
        np.testing.assert_allclose(base.ego_state, states[k], rtol=0, atol=1e-12)
        *_, info = env.step(action)
        np.testing.assert_allclose(info["acceleration"], inputs[k], rtol=0, atol=1e-12)
    assert np.max(_speeds(states)) <= 2.0 + 1e-12

    class Push:
        def predict(self, observation, deterministic=True):
            return np.array([10.0, -10.0]), None

    states, _ = PolicyRolloutReference(Push())(base, action, 10)
    assert np.max(_speeds(states)) <= 2.0 + 1e-12


def test_the_held_reference_meets_the_speed_limit_late_in_the_horizon():
    """Held roll-out below the limit, the env's applied input from the step that reaches
    it: stepping the environment with the action gives the same states and inputs."""
    from filters.references import hold_action_reference

    env = gym.make("SafeNav/HeadOn-v0", max_speed=3.0)
    env.reset(seed=0)
    base = env.unwrapped
    action = np.array([2.0, 0.5])  # from 1.5 m/s along x: over 3 m/s after a few steps
    states, inputs = hold_action_reference(base, action, 10)
    assert np.all(inputs[0] == action) and not np.allclose(inputs[-1], action)
    for k in range(10):
        np.testing.assert_allclose(base.ego_state, states[k], rtol=0, atol=1e-12)
        *_, info = env.step(action)
        np.testing.assert_allclose(info["acceleration"], inputs[k], rtol=0, atol=1e-12)
    np.testing.assert_allclose(base.ego_state, states[10], rtol=0, atol=1e-12)

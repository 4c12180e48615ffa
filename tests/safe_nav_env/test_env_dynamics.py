"""Ego dynamics, the safety-filter protocol on ``env.unwrapped``, and the observation."""

from __future__ import annotations

import re

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401  (registers the ids)
from safe_nav_env import InvalidActionError, double_integrator, single_integrator
from safe_nav_env.dynamics import applied_acceleration
from safe_nav_env.errors import ConfigError, ScenarioError

PROTOCOL = {
    "dt": (),
    "ego_state": (4,),
    "obstacle_radii": (3,),
    "obstacle_positions": (3, 2),
    "obstacle_velocities": (3, 2),
    "predictions": (3, 100, 10, 2),
    "goal": (2,),
}


def test_double_integrator_matches_the_paper():
    A, B, C = double_integrator(0.2)
    eye = np.eye(2)
    np.testing.assert_array_equal(A, np.block([[eye, 0.2 * eye], [0 * eye, eye]]))
    np.testing.assert_allclose(B, np.vstack([0.02 * eye, 0.2 * eye]))
    np.testing.assert_array_equal(C, np.hstack([eye, 0 * eye]))
    A1, B1, C1 = single_integrator(0.2)
    np.testing.assert_array_equal(A1, eye)
    np.testing.assert_allclose(B1, 0.2 * eye)
    with pytest.raises(ValueError, match="dt"):
        double_integrator(0.0)


def test_unwrapped_offers_the_filter_protocol():
    env = gym.make("SafeNav/MultiObstacle-v0")
    env.reset(seed=0)
    u = env.unwrapped
    for name, shape in PROTOCOL.items():
        assert np.shape(getattr(u, name)) == shape, name
    A, B, C = u.dynamics
    assert (A.shape, B.shape, C.shape) == ((4, 4), (4, 2), (2, 4))
    assert u.dt == 0.2 and u.ego_radius == 0.3
    low, high = u.input_bounds
    np.testing.assert_array_equal(high, [10.0, 10.0])
    np.testing.assert_array_equal(low, -high)
    low, high = u.position_bounds
    np.testing.assert_array_equal(low, [-5.0, -5.0])
    np.testing.assert_array_equal(high, [5.0, 5.0])
    assert u.render_hooks == []
    import filters.protocol as protocol
    assert isinstance(u, protocol.FilterableEnv)


def test_step_is_the_double_integrator_with_clipped_input():
    env = gym.make("SafeNav/HeadOn-v0", max_speed=np.inf)
    env.reset(seed=0)
    A, B, _ = env.unwrapped.dynamics
    for action in ([1.0, -2.0], [25.0, -40.0]):
        x = env.unwrapped.ego_state.copy()
        *_, info = env.step(np.array(action, dtype=np.float32))
        u = np.clip(action, -10.0, 10.0)
        np.testing.assert_array_equal(info["acceleration"], u)
        np.testing.assert_allclose(env.unwrapped.ego_state, A @ x + B @ u, rtol=0, atol=1e-12)


def _projection_reference(v, action, dt, a_max, v_max):
    """The closest input to the clipped action in {|u_i| <= a_max, ||v + dt u|| <= v_max},
    written as read in CVXPY (the readable reference of applied_acceleration)."""
    import cvxpy as cp

    u = cp.Variable(2)
    target = np.clip(action, -a_max, a_max)
    problem = cp.Problem(cp.Minimize(cp.sum_squares(u - target)),
                         [cp.abs(u) <= a_max, cp.norm(u + v / dt) <= v_max / dt])
    problem.solve(solver=cp.CLARABEL, tol_feas=1e-12, tol_gap_abs=1e-12, tol_gap_rel=1e-12)
    return np.array(u.value)


def test_the_speed_limit_is_the_projection_onto_the_disc_within_the_box():
    """At speeds up to the limit, the applied input is the CVXPY projection (by distance),
    stays in the box, and the next velocity in the disc; under the limit nothing changes."""
    rng = np.random.default_rng(11)
    dt, a_max, v_max = 0.2, 10.0, 3.0
    limited = 0
    for _ in range(300):
        speed, heading = v_max * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
        v = speed * np.array([np.cos(heading), np.sin(heading)])
        action = rng.uniform(-15.0, 15.0, 2)
        u = np.array(applied_acceleration(tuple(v), tuple(action), dt, a_max, v_max))
        assert np.all(np.abs(u) <= a_max) and np.hypot(*(v + dt * u)) <= v_max * (1 + 1e-12)
        if np.hypot(*(v + dt * np.clip(action, -a_max, a_max))) <= v_max:
            np.testing.assert_array_equal(u, np.clip(action, -a_max, a_max))
            continue
        limited += 1
        reference = _projection_reference(v, action, dt, a_max, v_max)
        # Feasible (above) and no farther from the action than the conic solver's answer:
        # the projection. The solver's distance is accurate to ~1e-9, its point only to
        # ~1e-4 m/s² along the circle (the distance is flat there to first order).
        target = np.clip(action, -a_max, a_max)
        assert np.hypot(*(u - target)) <= np.hypot(*(reference - target)) + 1e-9
        np.testing.assert_allclose(u, reference, rtol=0, atol=5e-4)
    assert limited > 100


def test_above_the_limit_the_ego_brakes_as_hard_as_the_box_allows():
    u = applied_acceleration((5.0, -4.0), (10.0, 10.0), 0.2, 10.0, 3.0)
    assert u == (-10.0, 10.0)  # clip(-v / dt): back under the limit as fast as it can


def test_the_env_keeps_the_speed_limit_and_its_observation_bounds():
    env = gym.make("SafeNav/MultiObstacle-v0", max_speed=2.0)
    obs, _ = env.reset(seed=0)
    A, B, _ = env.unwrapped.dynamics
    np.testing.assert_array_equal(env.observation_space.high[2:4], [2.0, 2.0])
    np.testing.assert_array_equal(env.observation_space.low[2:4], [-2.0, -2.0])
    rng = np.random.default_rng(0)
    for _ in range(30):
        x = env.unwrapped.ego_state.copy()
        obs, *_, info = env.step(rng.uniform(-10, 10, 2))
        assert env.observation_space.contains(obs)
        assert np.hypot(*env.unwrapped.ego_state[2:]) <= 2.0 * (1 + 1e-12)
        np.testing.assert_allclose(env.unwrapped.ego_state, A @ x + B @ info["acceleration"],
                                   rtol=0, atol=1e-12)


@pytest.mark.parametrize("value", [0.0, -1.0, np.nan, -np.inf, "3", True])
def test_a_bad_max_speed_names_the_value(value):
    with pytest.raises(ConfigError, match="max_speed .*inf.*" + re.escape(repr(value))):
        gym.make("SafeNav/HeadOn-v0", max_speed=value)


def test_a_start_above_the_limit_is_refused_and_inf_switches_the_limit_off():
    with pytest.raises(ScenarioError, match="1.5 m/s.*max_speed=1"):
        gym.make("SafeNav/HeadOn-v0", max_speed=1.0).reset(seed=0)
    env = gym.make("SafeNav/HeadOn-v0", max_speed=np.inf)
    env.reset(seed=0)
    assert env.unwrapped.max_speed == np.inf
    assert env.observation_space.high[2] == np.finfo(np.float32).max
    for _ in range(5):
        env.step(np.array([10.0, 10.0]))
    assert np.hypot(*env.unwrapped.ego_state[2:]) > 5.0


def test_random_starts_are_drawn_under_the_limit():
    env = gym.make("SafeNav/RandomCrossing-v0", max_speed=2.0,
                   random_start={"probability": 1.0, "rest": 0.0, "max_speed": 6.0})
    speeds = [np.hypot(*env.reset(seed=seed)[0][2:4]) for seed in range(20)]
    assert max(speeds) <= 2.0 + 1e-6 and max(speeds) > 1.9


@pytest.mark.parametrize("action", [[np.nan, 0.0], [1.0, 2.0, 3.0], [np.inf, 0.0]])
def test_bad_actions_raise(action):
    env = gym.make("SafeNav/HeadOn-v0")
    env.reset(seed=0)
    with pytest.raises(InvalidActionError):
        env.unwrapped.step(np.array(action))


@pytest.mark.parametrize(("action", "given"), [(5.0, "shape ()"), (np.zeros(3), "shape (3,)")])
def test_a_bad_action_shape_names_the_expected_one(action, given):
    env = gym.make("SafeNav/HeadOn-v0")
    env.reset(seed=0)
    with pytest.raises(InvalidActionError, match=re.escape("shape (2,)") + ".*" + re.escape(given)):
        env.unwrapped.step(action)


def test_observation_layout_and_observe():
    env = gym.make("SafeNav/MultiObstacle-v0")
    obs, _ = env.reset(seed=0)
    for _ in range(3):
        obs, *_ = env.step(np.array([1.0, 0.5], np.float32))
    u = env.unwrapped
    np.testing.assert_array_equal(
        obs, u.observe(u.ego_state, u.obstacle_positions, u.obstacle_velocities)
    )
    x = u.ego_state
    np.testing.assert_allclose(obs[0:4], x, rtol=1e-6)
    np.testing.assert_allclose(obs[4:6], u.goal - x[:2], rtol=1e-6)
    slots = obs[6:].reshape(4, 5)
    relative = u.obstacle_positions - x[:2]
    order = np.argsort(np.linalg.norm(relative, axis=1))
    np.testing.assert_allclose(slots[:3, 0:2], relative[order], rtol=1e-6)
    np.testing.assert_allclose(slots[:3, 2:4], u.obstacle_velocities[order] - x[2:], rtol=1e-6)
    np.testing.assert_array_equal(slots[:, 4], [1, 1, 1, 0])
    np.testing.assert_array_equal(slots[3], 0.0)


def test_observe_hypothetical_and_keeps_the_nearest():
    env = gym.make("SafeNav/HeadOn-v0", max_obstacles=2)
    env.reset(seed=0)
    state_before = env.unwrapped.ego_state.copy()
    positions = np.array([[3.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    velocities = np.array([[-1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
    obs = env.unwrapped.observe(np.zeros(4), positions, velocities)
    assert obs.dtype == np.float32 and obs.shape == (16,)
    np.testing.assert_array_equal(obs[6:].reshape(2, 5),
                                  [[1, 0, 0, 0, 1], [2, 0, 0, 1, 1]])
    np.testing.assert_array_equal(env.unwrapped.ego_state, state_before)
    empty = env.unwrapped.observe(np.zeros(4), np.zeros((0, 2)), np.zeros((0, 2)))
    np.testing.assert_array_equal(empty[6:], 0.0)
    with pytest.raises(ValueError, match="shape"):
        env.unwrapped.observe(np.zeros(3), positions, velocities)

"""Ego dynamics, the safety-filter protocol on ``env.unwrapped``, and the observation."""

from __future__ import annotations

import re

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401  (registers the ids)
from safe_nav_env import InvalidActionError, double_integrator, single_integrator

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
    env = gym.make("SafeNav/HeadOn-v0")
    env.reset(seed=0)
    A, B, _ = env.unwrapped.dynamics
    for action in ([1.0, -2.0], [25.0, -40.0]):
        x = env.unwrapped.ego_state.copy()
        env.step(np.array(action, dtype=np.float32))
        u = np.clip(action, -10.0, 10.0)
        np.testing.assert_allclose(env.unwrapped.ego_state, A @ x + B @ u, rtol=0, atol=1e-12)


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

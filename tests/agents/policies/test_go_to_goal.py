"""The obstacle-blind go-to-goal controller: its law, the goal it reaches, its checks."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401  (registers the ids)
from agents.policies.go_to_goal import GoToGoalPolicy
from filters.errors import InvalidParameterError


def test_law_caps_the_speed_and_clips_at_the_input_bound():
    policy = GoToGoalPolicy(gain=1.0, damping=2.0, cruise_speed=3.0, max_acceleration=10.0)
    # Far away: desired velocity capped at 3 m/s towards the goal; at rest -> 2 * 3 = 6 m/s².
    np.testing.assert_allclose(policy.action(np.zeros(2), np.array([9.0, 0.0])), [6.0, 0.0])
    # Close: v_d = k_p (g - p) = (0.5, 0); moving at (1, 0) -> k_d (0.5 - 1) = -1.
    np.testing.assert_allclose(policy.action(np.array([1.0, 0.0]), np.array([0.5, 0.0])),
                               [-1.0, 0.0])
    # Large velocity error: clipped per axis.
    np.testing.assert_allclose(policy.action(np.array([-20.0, 20.0]), np.array([1.0, 0.0])),
                               [10.0, -10.0])


def test_predict_reads_the_observation_and_batches():
    env = gym.make("SafeNav/HeadOn-v0")
    obs, _ = env.reset(seed=0)
    policy = GoToGoalPolicy.from_env(env)
    action, state = policy.predict(obs, deterministic=True)
    assert state is None and action.dtype == np.float32 and action.shape == (2,)
    np.testing.assert_allclose(action, policy.action(obs[2:4], obs[4:6]), rtol=1e-6)
    batch, _ = policy.predict(np.stack([obs, obs]))
    np.testing.assert_allclose(batch, np.stack([action, action]))


def test_reaches_the_goal_when_alone():
    env = gym.make("SafeNav/Custom-v0", scenario={"name": "empty", "ego_start": (-4.7, 0.0),
                                                  "goal": (4.7, 1.0), "duration": 10.0})
    obs, _ = env.reset(seed=0)
    policy = GoToGoalPolicy.from_env(env)
    for _ in range(50):
        obs, _, terminated, truncated, info = env.step(policy.predict(obs)[0])
        if terminated or truncated:
            break
    assert info["is_success"] and info["time"] < 6.0
    assert np.hypot(*info["ego_state"][2:]) <= 3.0 + 1e-9


@pytest.mark.parametrize("name", ["gain", "damping", "cruise_speed", "max_acceleration"])
@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), "1", True])
def test_parameters_are_validated(name, bad):
    with pytest.raises(InvalidParameterError, match=name):
        GoToGoalPolicy(**{name: bad})

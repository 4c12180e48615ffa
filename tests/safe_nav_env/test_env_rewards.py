"""Collisions (exactly at distance 0), rewards, termination and truncation."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401  (registers the ids)
from safe_nav_env import Gaussian, NoiseModel, ObstacleSpec, Scenario, distance_to_collision

STILL = NoiseModel(prediction=Gaussian(0.0), reality=Gaussian(0.0), n_samples=3)
"""Zero-covariance noise: obstacles follow their nominal motion exactly."""


def still_scenario(obstacle_x: float, *, goal=(4.0, 0.0)) -> Scenario:
    """Ego at rest at the origin (radius 0.25); a parked obstacle (radius 0.25) at (x, 0)."""
    return Scenario(
        name="touch", ego_start=(0.0, 0.0), goal=goal, ego_radius=0.25, noise=STILL,
        obstacles=[ObstacleSpec(start=(obstacle_x, 0.0), velocity=(0.0, 0.0), radius=0.25)],
    )


def test_distance_to_collision_formula():
    d = distance_to_collision(np.array([0.0, 0.0]), np.array([[3.0, 4.0], [0.5, 0.0]]), 0.3,
                              np.array([0.2, 0.25]))
    np.testing.assert_allclose(d, [5.0 - 0.5, 0.5 - 0.55])


def test_collision_exactly_at_distance_zero():
    env = gym.make("SafeNav/Custom-v0", scenario=still_scenario(0.5))
    _, info = env.reset(seed=0)
    assert info["distance_to_collision"][0] == 0.0  # 0.5 - 0.25 - 0.25, exact in binary
    assert info["collision"] is True and info["cost"] == 1.0
    _, reward, terminated, _, info = env.step(np.zeros(2, np.float32))
    assert info["distance_to_collision"][0] == 0.0
    assert info["collision"] is True and info["cost"] == 1.0
    assert reward == pytest.approx(-1.0)  # the default collision penalty, nothing else
    assert terminated is False  # collisions do not end the episode by default


def test_no_collision_slightly_above_zero():
    env = gym.make("SafeNav/Custom-v0", scenario=still_scenario(np.nextafter(0.5, 1.0)))
    _, info = env.reset(seed=0)
    assert 0.0 < info["distance_to_collision"][0] < 1e-15
    assert info["collision"] is False and info["cost"] == 0.0
    _, reward, _, _, info = env.step(np.zeros(2, np.float32))
    assert info["collision"] is False and reward == 0.0


def test_terminate_on_collision_and_penalty_option():
    env = gym.make("SafeNav/Custom-v0", scenario=still_scenario(0.4), collision_penalty=5.0,
                   terminate_on_collision=True)
    env.reset(seed=0)
    _, reward, terminated, _, info = env.step(np.zeros(2, np.float32))
    assert info["distance_to_collision"][0] == pytest.approx(-0.1)
    assert terminated is True and reward == pytest.approx(-5.0)


def test_reward_terms_and_weights():
    env = gym.make("SafeNav/Custom-v0", scenario=still_scenario(-3.0), progress_weight=2.0,
                   control_cost_weight=0.01, time_penalty=0.05)
    env.reset(seed=0)
    _, reward, *_ = env.step(np.array([1.0, 0.0], np.float32))
    progress = 0.5 * 0.2**2 * 1.0  # the ego moves T_s²/2 u toward the goal
    assert reward == pytest.approx(2.0 * progress - 0.01 * 1.0 - 0.05)


def test_arrival_terminates_with_success_and_bonus():
    scenario = still_scenario(-3.0, goal=(0.4, 0.0))
    env = gym.make("SafeNav/Custom-v0", scenario=scenario, goal_tolerance=0.3, arrival_bonus=7.0)
    _, info = env.reset(seed=0)
    assert info["is_success"] is False
    _, reward, terminated, truncated, info = env.step(np.array([10.0, 0.0], np.float32))
    assert info["distance_to_goal"] == pytest.approx(0.2)  # moved T_s²/2 * 10 = 0.2 m
    assert terminated is True and truncated is False and info["is_success"] is True
    assert reward == pytest.approx(0.2 + 7.0 - 1e-3 * 100.0)


def test_out_of_bounds_is_recorded_not_enforced():
    scenario = Scenario(name="edge", ego_start=(4.9, 0.0, 2.0, 0.0), goal=(0.0, 0.0),
                        noise=STILL)
    env = gym.make("SafeNav/Custom-v0", scenario=scenario)
    _, info = env.reset(seed=0)
    assert info["out_of_bounds"] is False
    _, _, _, _, info = env.step(np.zeros(2, np.float32))
    assert info["out_of_bounds"] is True
    assert env.unwrapped.ego_state[0] == pytest.approx(5.3)
    assert info["min_distance_to_collision"] == np.inf  # no obstacles


def test_unfiltered_goal_seeking_collides_in_head_on():
    """A straight-to-the-goal controller hits the head-on obstacle: the task needs a filter."""
    env = gym.make("SafeNav/HeadOn-v0")
    _, info = env.reset(seed=0)
    collided = False
    for _ in range(40):
        x = env.unwrapped.ego_state
        action = 2.0 * (env.unwrapped.goal - x[:2]) - 3.0 * x[2:]
        _, _, terminated, truncated, info = env.step(action.astype(np.float32))
        collided |= info["collision"]
        if terminated or truncated:
            break
    assert collided

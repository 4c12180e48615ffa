"""Randomised ego starts (training only): validation, the draws, and that off means off."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env

import safe_nav_env  # noqa: F401
from safe_nav_env import ConfigError, RandomStart
from safe_nav_env.starts import resolve_random_start

pytestmark = pytest.mark.filterwarnings("ignore:.*normalized:UserWarning")


@pytest.mark.parametrize(("value", "field"), [
    ({"probability": 1.5}, "probability"), ({"probability": math.nan}, "probability"),
    ({"near_goal": -0.1}, "near_goal"), ({"rest": 2}, "rest"),
    ({"random_goal": 1.01}, "random_goal"), ({"max_speed": -1.0}, "max_speed"),
    ({"clearance": math.inf}, "clearance"), ({"wall_margin": -0.1}, "wall_margin"),
    ({"goal_distance": (0.0, 1.0)}, r"goal_distance\[0\]"),
    ({"goal_distance": (2.0, 1.0)}, r"goal_distance\[1\]"),
    ({"goal_distance": 1.0}, "goal_distance"), ({"probability": "half"}, "probability"),
    ({"probability": True}, "probability"), ({"speed": 1.0}, "unknown field"),
    (-0.5, "probability"), (2.0, "probability"), ("yes", "random_start"),
    ([0.5], "random_start"),
])
def test_bad_random_starts_raise_naming_the_field(value, field):
    with pytest.raises(ConfigError, match=field):
        gym.make("SafeNav/RandomCrossing-v0", random_start=value)


@pytest.mark.parametrize("off", [None, 0, 0.0, {"probability": 0.0}, RandomStart(probability=0)])
def test_off_means_no_draw(off):
    assert resolve_random_start(off) is None
    env = gym.make("SafeNav/RandomCrossing-v0", random_start=off)
    assert env.unwrapped.random_start is None


def _episode(env: gym.Env, seed: int, steps: int = 12) -> list[np.ndarray]:
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for k in range(steps):
        obs, reward, _, _, _ = env.step(np.array([np.sin(k), np.cos(k)], dtype=np.float32))
        out += [obs, np.array([reward])]
    return out


@pytest.mark.parametrize("env_id", ["SafeNav/RandomCrossing-v0", "SafeNav/HeadOn-v0"])
def test_the_default_leaves_episodes_bit_for_bit_unchanged(env_id):
    plain, off = gym.make(env_id), gym.make(env_id, random_start=0.0)
    for seed in (0, 7):
        for a, b in zip(_episode(plain, seed), _episode(off, seed), strict=True):
            assert np.array_equal(a, b)


def test_random_starts_follow_their_law():
    start = RandomStart(probability=1.0, near_goal=0.5, goal_distance=(0.5, 1.5),
                        max_speed=2.0, rest=0.25, clearance=0.5, wall_margin=0.3)
    env = gym.make("SafeNav/RandomCrossing-v0", random_start=start)
    base = env.unwrapped
    near = rest = 0
    n = 200
    for seed in range(n):
        _, info = env.reset(seed=seed)
        x = base.ego_state
        assert np.all(x[:2] >= -4.7 - 1e-12) and np.all(x[:2] <= 4.7 + 1e-12)
        clearance = info["distance_to_collision"]
        assert np.all(clearance >= 0.5 - 1e-12)
        speed = math.hypot(x[2], x[3])
        assert speed <= 2.0
        rest += speed == 0.0
        distance = math.hypot(*(x[:2] - base.goal))
        assert info["distance_to_goal"] == pytest.approx(distance)
        assert distance > base.goal_tolerance
        near += 0.5 <= distance <= 1.5
    # About half the starts are drawn near the goal (plus a few uniform ones that land
    # there), about a quarter at rest: 6-sigma binomial bands.
    assert 0.5 * n - 6 * math.sqrt(n / 4) <= near <= 0.5 * n + 6 * math.sqrt(n / 4) + 0.1 * n
    assert abs(rest - 0.25 * n) <= 6 * math.sqrt(n * 0.25 * 0.75)


def test_near_goal_starts_at_rest_and_random_goals():
    env = gym.make("SafeNav/Intersection-v0", random_start={
        "probability": 1.0, "near_goal": 1.0, "rest": 1.0, "goal_distance": (0.4, 1.2),
        "random_goal": 1.0})
    base = env.unwrapped
    goals = set()
    for seed in range(30):
        env.reset(seed=seed)
        assert np.all(base.ego_state[2:] == 0.0)
        assert 0.4 <= math.hypot(*(base.ego_state[:2] - base.goal)) <= 1.2
        assert np.all(np.abs(base.goal) <= 4.7)
        goals.add(tuple(base.goal))
    assert len(goals) == 30  # a new goal each episode, not the scenario's (1, -3)


def test_same_seed_same_start_and_the_reward_counts_progress_from_it():
    env = gym.make("SafeNav/RandomCrossing-v0", random_start=1.0)
    base = env.unwrapped
    obs_a, info_a = env.reset(seed=3)
    start_a = base.ego_state.copy()
    obs_b, info_b = env.reset(seed=3)
    assert np.array_equal(obs_a, obs_b) and np.array_equal(start_a, base.ego_state)
    np.testing.assert_allclose(obs_a[4:6], base.goal - start_a[:2], rtol=1e-6)
    before = info_b["distance_to_goal"]
    _, reward, _, _, info = env.step(np.zeros(2, dtype=np.float32))
    assert reward == pytest.approx(before - info["distance_to_goal"], abs=1e-9)


def test_a_start_that_cannot_be_placed_keeps_the_scenario_start():
    # Margin larger than half the arena: no position qualifies.
    env = gym.make("SafeNav/HeadOn-v0", random_start={"probability": 1.0, "wall_margin": 6.0})
    env.reset(seed=0)
    np.testing.assert_array_equal(env.unwrapped.ego_state, [-4.7, 0.0, 1.5, 0.0])


def test_env_checker_passes_with_random_starts():
    gym_check_env(gym.make("SafeNav/RandomCrossing-v0", random_start=0.5).unwrapped)

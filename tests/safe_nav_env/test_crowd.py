"""SafeNav/Crowd-v0: CrowdNav's circle crossing with ORCA and social-force humans."""

from __future__ import annotations

import logging
import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import safe_nav_env  # noqa: F401  (registers the ids)
from filters import SafetyFilterWrapper
from safe_nav_env.crowd.env import CIRCLE_RADIUS, DISCOMFORT_DISTANCE, HUMAN_RADIUS
from safe_nav_env.crowd.humans import make_humans
from safe_nav_env.errors import ConfigError


@pytest.mark.parametrize("policy", ["orca", "social_force"])
def test_the_crowd_environment_passes_gymnasiums_checker(policy):
    check_env(gym.make("SafeNav/Crowd-v0", human_policy=policy).unwrapped,
              skip_render_check=True)


def test_starts_follow_crowdnavs_circle_crossing_rule():
    env = gym.make("SafeNav/Crowd-v0")
    for seed in range(20):
        env.reset(seed=seed)
        base = env.unwrapped
        starts = np.array(base.obstacle_positions)
        assert starts.shape == (5, 2)
        radius = np.hypot(starts[:, 0], starts[:, 1])
        assert np.all(np.abs(radius - CIRCLE_RADIUS) <= 0.5 * math.sqrt(2) + 1e-12)
        np.testing.assert_array_equal(base.goal, [0.0, CIRCLE_RADIUS])
        np.testing.assert_array_equal(base.ego_state, [0.0, -CIRCLE_RADIUS, 0.0, 0.0])
        agents = [(np.array([0.0, -CIRCLE_RADIUS]), np.array([0.0, CIRCLE_RADIUS]), 0.3)]
        for start in starts:  # each human clear of the agents placed before it
            for other, goal, r in agents:
                gap = HUMAN_RADIUS + r + DISCOMFORT_DISTANCE
                assert np.hypot(*(start - other)) >= gap and np.hypot(*(start - goal)) >= gap
            agents.append((start, -start, HUMAN_RADIUS))


def _run(env, seed, steps=40):
    obs, _ = env.reset(seed=seed)
    rows = [obs]
    for _ in range(steps):
        obs, *_ = env.step(np.array([0.5, 1.0]))
        rows.append(obs)
    return np.array(rows)


@pytest.mark.parametrize("policy", ["orca", "social_force"])
def test_an_episode_is_determined_by_its_seed(policy):
    env = gym.make("SafeNav/Crowd-v0", human_policy=policy, robot_visible=True)
    first, again, other = _run(env, 3), _run(env, 3), _run(env, 4)
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first, other)


@pytest.mark.parametrize(("policy", "least_gap"), [
    ("orca", 2 * HUMAN_RADIUS - 0.05),  # collision free up to ORCA's step discretisation
    ("social_force", HUMAN_RADIUS),  # soft repulsion: close passes, no walking through
])
def test_humans_cross_to_the_antipode_without_running_into_each_other(policy, least_gap):
    env = gym.make("SafeNav/Crowd-v0", human_policy=policy)
    env.reset(seed=1)
    base = env.unwrapped
    goals = -np.array(base.obstacle_positions)
    closest = math.inf
    for _ in range(base.max_episode_steps):
        _, _, terminated, truncated, _ = env.step(np.zeros(2))
        p = np.array(base.obstacle_positions)
        gaps = np.hypot(*(p[:, None] - p[None]).transpose(2, 0, 1)) + np.eye(len(p)) * 1e9
        closest = min(closest, float(gaps.min()))
        if terminated or truncated:
            break
    assert np.all(np.hypot(*(p - goals).T) < 0.6), np.hypot(*(p - goals).T)
    assert closest > least_gap


@pytest.mark.parametrize(("policy", "visible_gap"), [
    ("orca", 0.55),  # ORCA keeps the two discs (0.3 m + 0.01 m each) apart
    ("social_force", 0.25),  # a soft push: deflected, but the discs may overlap
])
def test_visible_robot_is_avoided_invisible_robot_is_walked_into(policy, visible_gap):
    """One human walks from (-2, 0) to (2, 0) past a robot standing at the origin."""
    def closest(visible: bool) -> float:
        humans = make_humans(policy, dt=0.2, radius=0.3, preferred_speed=1.0,
                             robot_radius=0.3, robot_visible=visible)
        humans.reset(np.array([[-2.0, 0.02]]), np.array([[2.0, 0.02]]))
        gaps = [np.hypot(*humans.step(np.zeros(2), np.zeros(2))[0]) for _ in range(40)]
        return min(gaps)

    assert closest(False) < 0.1  # straight through the robot's disc
    assert closest(True) > visible_gap


def test_social_force_leaves_no_log_file_and_the_root_logger_as_it_was(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    root = logging.getLogger()
    level, handlers = root.level, list(root.handlers)
    env = gym.make("SafeNav/Crowd-v0", human_policy="social_force")
    env.reset(seed=0)
    env.step(np.zeros(2))
    assert list(tmp_path.iterdir()) == []
    assert root.level == level and root.handlers == handlers


def test_the_safety_filter_wraps_the_crowd():
    env = SafetyFilterWrapper(gym.make("SafeNav/Crowd-v0"), risk="dr_cvar")
    env.reset(seed=0)
    for _ in range(5):
        _, _, _, _, info = env.step(np.array([0.0, 3.0]))
        assert info["filter"]["status"] in ("optimal", "soft", "recovery")
        assert info["predictions"].shape == (5, 100, 10, 2)
        assert isinstance(info["discomfort"], bool)


def test_discomfort_flags_a_close_pass():
    env = gym.make("SafeNav/Crowd-v0")
    env.reset(seed=0)
    base = env.unwrapped
    info = base._info(np.array([0.5, 0.15]), np.array([0.5, 0.15]), 1.0)
    assert info["discomfort"] is True
    info = base._info(np.array([0.5, 0.25]), np.array([0.5, 0.25]), 1.0)
    assert info["discomfort"] is False


@pytest.mark.parametrize(("option", "value", "words"), [
    ("human_policy", "boids", "human_policy"),
    ("n_humans", 0, "n_humans"),
    ("circle_radius", -1.0, "circle_radius"),
])
def test_bad_options_name_the_value(option, value, words):
    with pytest.raises(ConfigError, match=words):
        gym.make("SafeNav/Crowd-v0", **{option: value})


@pytest.mark.parametrize("env_id", ["SafeNav/Crowd-v0", "SafeNav/Pedestrians-v0"])
def test_a_scene_of_its_own_refuses_another_scenario_at_reset(env_id):
    env = gym.make(env_id)
    env.reset(seed=0)
    with pytest.raises(ConfigError, match=rf"options\['scenario'\] does not apply to {env_id}"):
        env.reset(seed=1, options={"scenario": "HeadOn"})

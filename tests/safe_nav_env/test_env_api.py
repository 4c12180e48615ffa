"""Gymnasium / Stable-Baselines3 conformance of every registered id, seeding, options."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env

import safe_nav_env
from safe_nav_env import HEAD_ON, MULTI_OBSTACLE, ObstacleSpec, SafeNavEnv, Scenario

# The action box is ±max_acceleration in m/s² (not [-1, 1]) by design; both checkers
# recommend a normalised box, which is advice, not a failure.
pytestmark = pytest.mark.filterwarnings("ignore:.*normalized:UserWarning")

ALL_IDS = list(safe_nav_env.ENV_IDS)
SCENARIO_KWARGS = {"SafeNav/Custom-v0": {"scenario": MULTI_OBSTACLE}}


def make(env_id: str, **kwargs) -> gym.Env:
    return gym.make(env_id, **{**SCENARIO_KWARGS.get(env_id, {}), **kwargs})


def test_ids_are_registered_on_import():
    for env_id in [
        "SafeNav/HeadOn-v0",
        "SafeNav/Overtaking-v0",
        "SafeNav/Intersection-v0",
        "SafeNav/MultiObstacle-v0",
        "SafeNav/RandomCrossing-v0",
        "SafeNav/Custom-v0",
    ]:
        assert env_id in gym.registry


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_gymnasium_check_env(env_id):
    gym_check_env(make(env_id, render_mode="rgb_array").unwrapped)


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_sb3_check_env(env_id):
    import stable_baselines3.common.env_checker as sb3_checker
    sb3_checker.check_env(make(env_id))


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_make_vec_steps(env_id):
    envs = gym.make_vec(env_id, num_envs=4, vectorization_mode="sync",
                        **SCENARIO_KWARGS.get(env_id, {}))
    obs, info = envs.reset(seed=0)
    assert obs.shape == (4, 26) and obs.dtype == np.float32
    envs.action_space.seed(0)
    for _ in range(45):  # past the 40-step time limit of the single-obstacle presets
        obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
    assert obs.shape == (4, 26) and reward.shape == (4,)
    assert info["predictions"].shape[0] == 4
    envs.close()


def rollout(env: gym.Env, seed: int, n_steps: int = 30) -> list:
    obs, info = env.reset(seed=seed)
    actions = np.random.default_rng(123).uniform(-3, 3, size=(n_steps, 2)).astype(np.float32)
    record = [obs, info["predictions"], info["obstacle_positions"]]
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(action)
        record += [obs, reward, terminated, truncated, info["predictions"],
                   info["obstacle_positions"], info["ego_state"]]
        if terminated or truncated:
            break
    return record


def same(a: list, b: list) -> bool:
    return len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


@pytest.mark.parametrize("env_id", ["SafeNav/MultiObstacle-v0", "SafeNav/RandomCrossing-v0"])
def test_same_seed_same_episode_different_seed_different(env_id):
    first = rollout(gym.make(env_id), seed=7)
    assert same(first, rollout(gym.make(env_id), seed=7))  # bitwise, in a fresh env
    env = gym.make(env_id)
    rollout(env, seed=3)
    assert same(first, rollout(env, seed=7))  # and after other episodes
    assert not same(first, rollout(env, seed=8))


def test_random_crossing_changes_with_the_seed():
    env = gym.make("SafeNav/RandomCrossing-v0")
    starts = set()
    for seed in range(6):
        env.reset(seed=seed)
        starts.add((tuple(env.unwrapped.ego_state), env.unwrapped.n_obstacles))
    assert len(starts) == 6


def test_custom_accepts_a_scenario_a_mapping_and_a_family():
    mine = Scenario(name="mine", ego_start=(-4.0, 1.0, 0.5, 0.0), goal=(4.0, 1.0),
                    obstacles=[ObstacleSpec(start=(0.0, 1.0), velocity=(-0.5, 0.0))])
    env = gym.make("SafeNav/Custom-v0", scenario=mine)
    env.reset(seed=0)
    assert env.unwrapped.scenario is mine
    np.testing.assert_array_equal(env.unwrapped.goal, (4.0, 1.0))

    as_data = {"name": "data", "ego_start": [0, 0], "goal": [3, 0],
               "obstacles": [{"start": [1.5, 0.0], "velocity": [0, 0], "radius": 0.2}]}
    env = gym.make("SafeNav/Custom-v0", scenario=as_data)
    _, info = env.reset(seed=0)
    assert info["obstacle_positions"].shape == (1, 2)
    np.testing.assert_array_equal(env.unwrapped.obstacle_radii, [0.2])

    env = gym.make("SafeNav/Custom-v0", scenario=lambda rng: HEAD_ON)
    env.reset(seed=0)
    assert env.unwrapped.scenario is HEAD_ON


def test_custom_without_scenario_explains_what_to_pass():
    with pytest.raises(ValueError, match="scenario is required"):
        gym.make("SafeNav/Custom-v0")


def test_reset_option_replaces_the_scenario():
    env = gym.make("SafeNav/HeadOn-v0")
    env.reset(seed=0, options={"scenario": "multi_obstacle"})
    assert env.unwrapped.n_obstacles == 3


def test_make_kwargs_take_effect():
    env = gym.make("SafeNav/MultiObstacle-v0", n_samples=7, horizon=3, episode_length=1.0,
                   max_obstacles=2, max_acceleration=2.5)
    obs, info = env.reset(seed=0)
    assert info["predictions"].shape == (3, 7, 3, 2)
    assert obs.shape == (6 + 5 * 2,) and env.observation_space.shape == obs.shape
    np.testing.assert_array_equal(env.action_space.high, [2.5, 2.5])
    steps, truncated = 0, False
    while not truncated:
        _, _, _, truncated, _ = env.step(np.zeros(2, np.float32))
        steps += 1
    assert steps == 5  # 1.0 s / 0.2 s

    env = gym.make("SafeNav/HeadOn-v0", noise="authors_code")
    _, info = env.reset(seed=0)
    assert info["predictions"].shape == (1, 20, 10, 2)
    assert env.unwrapped.noise == safe_nav_env.NOISE_PRESETS["authors_code"]


def test_default_episode_lengths():
    for env_id, steps in [("SafeNav/HeadOn-v0", 40), ("SafeNav/MultiObstacle-v0", 50)]:
        env = gym.make(env_id)
        env.reset(seed=0)
        assert env.unwrapped.max_episode_steps == steps
    env = gym.make("SafeNav/HeadOn-v0", episode_length=HEAD_ON.duration)
    env.reset(seed=0)
    assert env.unwrapped.max_episode_steps == 15  # the paper's 3 s


@pytest.mark.filterwarnings("ignore:.*render_mode='ascii'")
@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"n_samples": 0}, "n_samples"),
        ({"horizon": 0}, "horizon"),
        ({"horizon": 2.5}, "horizon"),
        ({"episode_length": -1.0}, "episode_length"),
        ({"collision_penalty": -1.0}, "collision_penalty"),
        ({"max_acceleration": float("nan")}, "max_acceleration"),
        ({"noise": "cauchy"}, "noise"),
        ({"render_mode": "ascii"}, "render_mode"),
        ({"scenario": "nowhere"}, "scenario"),
    ],
)
def test_bad_options_raise_value_error_naming_them(kwargs, field):
    with pytest.raises(ValueError, match=field):
        gym.make("SafeNav/HeadOn-v0", **kwargs)


def test_info_contents():
    env = gym.make("SafeNav/MultiObstacle-v0")
    _, info = env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(2, np.float32))
    assert info["predictions"].shape == (3, 100, 10, 2)
    assert info["obstacle_positions"].shape == info["obstacle_velocities"].shape == (3, 2)
    assert info["distance_to_collision"].shape == (3,)
    assert info["min_distance_to_collision"] == info["distance_to_collision"].min()
    assert isinstance(info["collision"], bool) and isinstance(info["is_success"], bool)
    assert info["cost"] in (0.0, 1.0)
    assert info["ego_state"].shape == (4,)
    assert info["time"] == pytest.approx(0.2)
    with pytest.raises(ValueError, match="read-only"):
        info["predictions"][0, 0, 0, 0] = 1.0


def test_padded_info_for_families():
    env = gym.make("SafeNav/RandomCrossing-v0")
    for seed in range(5):
        _, info = env.reset(seed=seed)
        n = env.unwrapped.n_obstacles
        assert info["predictions"].shape == (4, 100, 10, 2)
        assert info["obstacle_present"].tolist() == [True] * n + [False] * (4 - n)
        assert np.all(np.isinf(info["distance_to_collision"][n:]))
        np.testing.assert_array_equal(info["predictions"][:n], env.unwrapped.predictions)


def test_import_is_light():
    code = (
        "import sys, safe_nav_env; "
        "bad = [m for m in ('matplotlib', 'torch', 'stable_baselines3', 'filters') "
        "if m in sys.modules]; print(bad); sys.exit(bool(bad))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            cwd=Path(__file__).resolve().parents[2])
    assert result.returncode == 0, result.stdout + result.stderr


def test_direct_construction_and_placeholders_before_reset():
    env = SafeNavEnv("random_crossing")
    assert env.predictions.shape == (0, 100, 10, 2)  # defined, empty, until reset()
    obs, _ = env.reset(seed=1)
    assert env.observation_space.contains(obs)

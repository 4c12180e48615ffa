"""The PPO reference planner (shipped, trained, loaded) and the MPC reference planner."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401
from agents import MPCReferencePlanner, load_ppo, train_ppo
from agents.evaluation.records import EpisodeSpec
from agents.evaluation.runner import run_episode
from agents.training.ppo import pretrained_policy_path
from filters import InvalidParameterError


@pytest.fixture(scope="module")
def shipped_policy():
    return load_ppo()


def test_the_shipped_policy_loads_and_acts(shipped_policy):
    assert pretrained_policy_path().stat().st_size < 1_000_000
    env = gym.make("SafeNav/HeadOn-v0")
    obs, _ = env.reset(seed=0)
    action, _ = shipped_policy.predict(obs, deterministic=True)
    assert action.shape == env.action_space.shape
    assert env.action_space.contains(np.clip(action, -10, 10).astype(np.float32))


def test_dr_cvar_filtered_ppo_collides_less_on_multi_obstacle(shipped_policy):
    collisions, goals = {}, {}
    for risk in ("none", "dr_cvar"):
        records = [run_episode(EpisodeSpec("SafeNav/MultiObstacle-v0", risk, seed),
                               policy=shipped_policy)[0] for seed in range(8)]
        assert all(r.error == "" for r in records)
        collisions[risk] = sum(r.collision for r in records)
        goals[risk] = sum(r.goal_reached for r in records)
    assert collisions["none"] >= 5  # the learned planner is goal-driven, not safe
    assert collisions["dr_cvar"] < collisions["none"]
    assert goals["dr_cvar"] >= 6


def test_train_save_and_load_round_trip_with_the_filter_in_the_loop(tmp_path):
    path = tmp_path / "tiny.zip"
    model, report = train_ppo("SafeNav/HeadOn-v0", total_timesteps=512, seed=1, n_envs=2,
                              filter_kwargs={"risk": "cvar"}, intervention_penalty=0.5,
                              progress_bar=False, save_path=path,
                              ppo_kwargs={"n_steps": 128, "batch_size": 64, "n_epochs": 1})
    assert report.total_timesteps >= 512 and report.save_path == path
    loaded = load_ppo(path)
    obs = np.zeros(model.observation_space.shape, dtype=np.float32)
    np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0],
                               model.predict(obs, deterministic=True)[0], atol=1e-6)


def test_training_arguments_are_checked(tmp_path):
    with pytest.raises(InvalidParameterError, match="total_timesteps"):
        train_ppo(total_timesteps=0)
    with pytest.raises(InvalidParameterError, match="intervention_penalty"):
        train_ppo(total_timesteps=10, intervention_penalty=1.0)
    with pytest.raises(FileNotFoundError, match="no PPO policy"):
        load_ppo(tmp_path / "missing.zip")


def test_mpc_planner_reaches_the_goal_when_nothing_is_in_the_way():
    env = gym.make("SafeNav/HeadOn-v0", episode_length=8.0)
    planner = MPCReferencePlanner.from_env(env)
    obs, _ = env.reset(seed=0)
    done, info = False, {}
    while not done:
        action, _ = planner.predict(obs)
        obs, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
    assert info["is_success"]


def test_mpc_planner_plan_is_dynamically_consistent_and_batched():
    env = gym.make("SafeNav/Intersection-v0")
    obs, _ = env.reset(seed=0)
    planner = MPCReferencePlanner.from_env(env)
    states, inputs = planner.plan(env.unwrapped.ego_state, env.unwrapped.goal)
    A, B, _ = env.unwrapped.dynamics
    np.testing.assert_allclose(states[1:], states[:-1] @ A.T + inputs @ B.T, atol=1e-9)
    single, _ = planner.predict(obs)
    batch, _ = planner.predict(np.stack([obs, obs]))
    np.testing.assert_allclose(batch, np.stack([single, single]), atol=1e-6)
    np.testing.assert_allclose(single, inputs[0], atol=1e-6)
    with pytest.raises(InvalidParameterError, match="horizon"):
        planner(env.unwrapped, single, 5)

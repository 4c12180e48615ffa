"""The lean control loop gives the episodes of the straightforward one, to rounding.

The optimised path (the numpy actor, the environment reused across seeds, the
observation built on floats, the inter-sample rows without a second check pass) is
compared with a reference path run in the same process: Stable-Baselines3's own
``predict`` on a freshly built environment, and the array formulas the fast code
replaced. No hard-coded numbers: the two paths agree within stated tolerances (the
same seed on the same path gives the same record exactly: that is determinism).
"""

from __future__ import annotations

import dataclasses
import math

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401
from agents import load_ppo
from agents.evaluation.records import TIMING_FIELDS, EpisodeSpec
from agents.evaluation.runner import _ENV_CACHE, clear_env_cache, run_episode

TIMING = {*TIMING_FIELDS, "policy"}


def _same_records(a, b, *, skip: tuple[str, ...] = ()) -> None:
    a, b = dataclasses.asdict(a), dataclasses.asdict(b)
    for key in a:
        if key in TIMING or key in skip:
            continue
        x, y = a[key], b[key]
        both_nan = isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y)
        assert x == y or both_nan, (key, x, y)


@pytest.fixture(scope="module")
def model():
    return load_ppo()


def test_runner_episodes_follow_the_sb3_path_to_rounding(model):
    """The default runner (the numpy actor, a reused environment) against SB3's predict on
    a fresh environment: the same statuses and outcomes, positions to 1e-6 m."""
    clear_env_cache()
    for spec in (EpisodeSpec("MultiObstacle", "dr_cvar", 3), EpisodeSpec("HeadOn", "cvar", 1),
                 EpisodeSpec("RandomCrossing", "dr_cvar", 2)):
        fast, fast_path = run_episode(spec, record_trajectory=True)
        slow, slow_path = run_episode(spec, policy=model, record_trajectory=True,
                                      reuse_env=False)
        assert not fast.error and not slow.error and fast.steps > 5
        assert (fast.steps, fast.collision, fast.goal_reached) == (
            slow.steps, slow.collision, slow.goal_reached)
        assert fast_path.statuses == slow_path.statuses
        np.testing.assert_allclose(fast_path.ego, slow_path.ego, rtol=0, atol=1e-6)
        assert fast.min_distance == pytest.approx(slow.min_distance, abs=1e-6)
    clear_env_cache()


def test_a_reused_environment_gives_the_same_records_as_a_fresh_one():
    clear_env_cache()
    for scenario, risk in (("RandomCrossing", "dr_cvar"), ("Overtaking", "none")):
        seeds = [4, 0, 4, 2]  # a seed again after others: nothing carries over
        reused = [run_episode(EpisodeSpec(scenario, risk, s))[0] for s in seeds]
        fresh = [run_episode(EpisodeSpec(scenario, risk, s), reuse_env=False)[0] for s in seeds]
        for a, b in zip(reused, fresh, strict=True):
            assert not a.error
            _same_records(a, b)
        _same_records(reused[0], reused[2])
        assert reused[0].min_distance != reused[1].min_distance  # the seeds differ
    clear_env_cache()


def test_a_failed_episode_drops_its_environment(monkeypatch):
    clear_env_cache()
    spec = EpisodeSpec("HeadOn", "mean", 0)
    run_episode(spec)
    (env, _), = _ENV_CACHE.values()

    def broken(*args, **kwargs):
        raise RuntimeError("boom")

    monkeypatch.setattr(env, "step", broken)
    record, _ = run_episode(spec)
    assert "boom" in record.error
    assert not _ENV_CACHE  # not reused after a half-run episode
    again, _ = run_episode(spec)
    assert not again.error and again.steps > 0
    clear_env_cache()


def _observe_reference(env, x, positions, velocities):
    """The observation with array operations, as the environment built it before."""
    x = np.asarray(x, dtype=np.float64)
    delta = np.asarray(positions, dtype=np.float64) - x[:2]
    obs = np.zeros(env._obs_size, dtype=np.float32)
    obs[0:4] = x
    obs[4:6] = env.goal - x[:2]
    n = delta.shape[0]
    if n and env.max_obstacles:
        slots = np.empty((n, 5))
        slots[:, 0:2] = delta
        slots[:, 2:4] = np.asarray(velocities, dtype=np.float64) - x[2:]
        slots[:, 4] = 1.0
        if n > 1:
            centre = np.hypot(delta[:, 0], delta[:, 1])
            slots = slots[centre.argsort(kind="stable")[: env.max_obstacles]]
        obs[6 : 6 + slots.size] = slots.ravel()
    return obs


def test_observation_equals_the_array_formulas():
    rng = np.random.default_rng(5)
    for max_obstacles in (1, 2, 4):
        env = gym.make("SafeNav/MultiObstacle-v0", max_obstacles=max_obstacles)
        base = env.unwrapped
        obs, _ = env.reset(seed=1)
        close = {"rtol": 1e-6, "atol": 1e-6}  # float32 entries of the same double values
        np.testing.assert_allclose(obs, _observe_reference(
            base, base.ego_state, base.obstacle_positions, base.obstacle_velocities), **close)
        for _ in range(20):
            obs, *_ = env.step(rng.uniform(-3.0, 3.0, 2).astype(np.float32))
            np.testing.assert_allclose(obs, _observe_reference(
                base, base.ego_state, base.obstacle_positions, base.obstacle_velocities), **close)
            for n in (0, 1, 3, 6):
                x = 4.0 * rng.standard_normal(4)
                p, v = 4.0 * rng.standard_normal((n, 2)), rng.standard_normal((n, 2))
                p[1:2] = p[:1]  # a tie in the distance: the stable order decides
                np.testing.assert_allclose(base.observe(x, p, v),
                                           _observe_reference(base, x, p, v), **close)
        env.close()


def test_a_filter_with_a_persistent_calibration_is_never_reused():
    """Persistent conformal margins carry over between episodes: each gets a fresh filter."""
    clear_env_cache()
    seeds = [1, 0, 1]
    options = {"calibration_memory": "persistent"}
    reused = [run_episode(EpisodeSpec("HeadOn", "conformal", s, filter_options=options))[0]
              for s in seeds]
    assert not _ENV_CACHE
    fresh = [run_episode(EpisodeSpec("HeadOn", "conformal", s, filter_options=options),
                         reuse_env=False)[0] for s in seeds]
    for a, b in zip(reused, fresh, strict=True):
        assert not a.error
        _same_records(a, b)
    _same_records(reused[0], reused[2])


def test_a_filter_with_a_per_episode_calibration_is_reused_with_the_same_records():
    """calibration_memory="episode" (the default): reset restores the calibrated state."""
    clear_env_cache()
    seeds = [1, 0, 1]
    reused = [run_episode(EpisodeSpec("HeadOn", "conformal", s))[0] for s in seeds]
    assert len(_ENV_CACHE) == 1
    fresh = [run_episode(EpisodeSpec("HeadOn", "conformal", s), reuse_env=False)[0]
             for s in seeds]
    for a, b in zip(reused, fresh, strict=True):
        assert not a.error
        _same_records(a, b)
    _same_records(reused[0], reused[2])
    clear_env_cache()

"""The lean control loop gives the same episodes, bit for bit, as the straightforward one.

The optimised path (the actor's one-row torch kernels, the environment reused across
seeds, the observation built on floats, the inter-sample rows without a second check
pass) is compared with a reference path run in the same process: Stable-Baselines3's
own ``predict`` on a freshly built environment, and the array formulas the fast code
replaced. No hard-coded numbers: the two paths must agree exactly.
"""

from __future__ import annotations

import dataclasses
import math

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401
from agents import load_ppo
from agents.evaluation.records import EpisodeSpec
from agents.evaluation.runner import _ENV_CACHE, clear_env_cache, run_episode
from agents.policies.numpy_policy import TorchActorPolicy
from filters import Disc, InvalidArrayError, safe_halfspaces
from filters.halfspaces import offsets_along
from filters.intersample import intersample_rows

TIMING = {"wall_time", "filter_time_median", "filter_time_max", "policy"}


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


def test_filtered_episodes_equal_the_sb3_reference_path_bit_for_bit(model):
    """Fast actor + reused environment vs SB3 predict on a fresh one: same trajectory
    (the roll-out calling the actor at each look-ahead step, ``compiled_rollout=False``)."""
    clear_env_cache()
    loop = '{"compiled_rollout": false}'
    specs = [EpisodeSpec("MultiObstacle", "dr_cvar", 3, filter_options=loop),
             EpisodeSpec("HeadOn", "cvar", 1, filter_options=loop)]
    for spec in specs:
        run_episode(dataclasses.replace(spec, seed=spec.seed + 100))  # warms the cache
        fast, fast_path = run_episode(spec, record_trajectory=True)
        slow, slow_path = run_episode(spec, policy=model, record_trajectory=True,
                                      reuse_env=False)
        assert not fast.error and not slow.error
        assert fast.steps > 5
        _same_records(fast, slow, skip=("policy_sha256",))  # "" for a given policy object
        assert np.array_equal(fast_path.ego, slow_path.ego)
        assert np.array_equal(fast_path.obstacles, slow_path.obstacles)
        assert fast_path.statuses == slow_path.statuses
        assert len(fast_path.halfspaces) == len(slow_path.halfspaces) == fast.steps
        for (n1, b1), (n2, b2) in zip(fast_path.halfspaces, slow_path.halfspaces, strict=True):
            assert np.array_equal(n1, n2) and np.array_equal(b1, b2)
    assert len(_ENV_CACHE) == 2  # the fast runs reused one environment per setting
    clear_env_cache()
    assert not _ENV_CACHE


def test_compiled_rollout_episodes_follow_the_sb3_path_to_rounding(model):
    """The default runner (compiled roll-out kernel, float64 actor) against SB3's predict
    at every look-ahead step: the same statuses and outcomes, positions to 1e-6 m."""
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


def test_fast_actor_is_bit_identical_to_sb3_on_thousands_of_observations(model):
    actor = TorchActorPolicy.from_sb3(model)
    assert actor._kernels is not None  # the one-row kernels, not the modules
    rng = np.random.default_rng(12)
    observations = (rng.standard_normal((3000, 26)) * rng.choice([0.1, 1.0, 10.0], (3000, 1)))
    observations = observations.astype(np.float32)
    expected, _ = model.predict(observations, deterministic=True)  # SB3, batched
    for obs in observations:
        got, _ = actor.predict(obs)
        assert got.dtype == np.float32
        assert np.array_equal(got, model.predict(obs, deterministic=True)[0])
    # the batch path (the modules) agrees with SB3's batch too
    assert np.array_equal(actor.predict_batch(observations), expected)


@pytest.mark.parametrize("activation", ["Tanh", "ReLU", "Sigmoid"])
@pytest.mark.parametrize("use_sde", [False, True])
def test_fast_actor_variants_and_training_updates(activation, use_sde):
    import torch
    from stable_baselines3 import PPO

    model = PPO("MlpPolicy", gym.make("SafeNav/HeadOn-v0"), seed=0, device="cpu", n_steps=64,
                batch_size=64, use_sde=use_sde,
                policy_kwargs={"net_arch": [24, 8], "activation_fn": getattr(torch.nn, activation)})
    actor = TorchActorPolicy.from_sb3(model)
    assert (actor._kernels is None) == (activation == "Sigmoid")  # other layers: the modules
    observations = (3.0 * np.random.default_rng(1).standard_normal((200, 26))).astype(np.float32)
    for obs in observations:
        assert np.array_equal(actor.predict(obs)[0], model.predict(obs, deterministic=True)[0])
    with torch.no_grad():  # training changes the shared parameters; the actor follows
        model.policy.action_net.bias.add_(0.5)
    for obs in observations[:20]:
        assert np.array_equal(actor.predict(obs)[0], model.predict(obs, deterministic=True)[0])


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
        assert np.array_equal(obs, _observe_reference(
            base, base.ego_state, base.obstacle_positions, base.obstacle_velocities))
        for _ in range(20):
            obs, *_ = env.step(rng.uniform(-3.0, 3.0, 2).astype(np.float32))
            assert np.array_equal(obs, _observe_reference(
                base, base.ego_state, base.obstacle_positions, base.obstacle_velocities))
            for n in (0, 1, 3, 6):
                x = 4.0 * rng.standard_normal(4)
                p, v = 4.0 * rng.standard_normal((n, 2)), rng.standard_normal((n, 2))
                p[1:2] = p[:1]  # a tie in the distance: the stable order decides
                assert np.array_equal(base.observe(x, p, v), _observe_reference(base, x, p, v))
        env.close()


@pytest.mark.parametrize("risk", ["mean", "cvar", "dr_cvar", "gaussian_cc", "moment_dr",
                                  "conformal"])
def test_offsets_along_equals_safe_halfspaces_with_given_normals(risk):
    rng = np.random.default_rng(7)
    for n, n_samples, horizon in ((1, 20, 1), (3, 100, 9), (4, 57, 20)):
        samples = rng.uniform(-4, 4, (n, 1, horizon + 1, 2)) + 0.1 * rng.standard_normal(
            (n, n_samples, horizon + 1, 2))
        normals = rng.standard_normal((n, horizon, 2))
        shapes = dict(ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.2 + 0.1 * i) for i in range(n)])
        options = dict(risk=risk, alpha=0.2, delta=0.05, epsilon=np.linspace(0.0, 0.1, horizon))
        if risk == "conformal":
            options["conformal_margins"] = rng.uniform(0.0, 0.3, horizon)
        fast = offsets_along(normals, samples, **shapes, **options)
        slow = safe_halfspaces(np.zeros((horizon, 2)), samples[:, :, :horizon], **shapes,
                               normals=normals, **options)
        assert np.array_equal(fast, slow.offsets)
    with pytest.raises(InvalidArrayError, match="non-zero"):
        offsets_along(np.zeros((1, 2, 2)), samples[:1], **dict(shapes, obstacle_shapes=[Disc(1)]))
    bad = samples.copy()
    bad[0, 3, 1, 0] = np.nan
    with pytest.raises(InvalidArrayError, match="samples"):
        offsets_along(normals, bad, **shapes)


def test_intersample_rows_unchanged_by_the_fast_start_rows(monkeypatch):
    """The start rows through offsets_along equal those of a full safe_halfspaces call."""
    import filters.intersample as intersample

    rng = np.random.default_rng(9)
    samples = rng.uniform(-3, 3, (3, 1, 10, 2)) + 0.1 * rng.standard_normal((3, 100, 10, 2))
    shapes = dict(ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.3)] * 3)
    hs = safe_halfspaces(rng.uniform(-3, 3, (10, 2)), samples, **shapes)
    kwargs = dict(input_bounds=(-10 * np.ones(2), 10 * np.ones(2)), dt=0.2, **shapes)
    fast = intersample_rows(hs, samples, **kwargs)

    def full(normals, samples, **options):
        horizon = normals.shape[1]
        return safe_halfspaces(np.zeros((horizon, 2)), samples[:, :, :horizon],
                               normals=normals, **options).offsets

    monkeypatch.setattr(intersample, "offsets_along", full)
    slow = intersample_rows(hs, samples, **kwargs)
    assert np.array_equal(fast.offsets, slow.offsets)
    assert np.array_equal(fast.normals, slow.normals)


def test_offsets_along_refuses_bad_input_with_the_package_errors():
    from filters import InvalidParameterError

    rng = np.random.default_rng(3)
    samples = rng.standard_normal((2, 10, 4, 2))
    normals = rng.standard_normal((2, 3, 2))
    shapes = dict(ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.3)] * 2)
    with pytest.raises(InvalidArrayError, match="samples"):
        offsets_along(normals, samples[:, :, :2], **shapes)  # fewer steps than normals
    with pytest.raises(InvalidArrayError):
        offsets_along(normals[0], samples, **shapes)  # not (n, T, d)
    with pytest.raises(InvalidArrayError):
        offsets_along(normals, samples.tolist()[:1], **shapes)  # one obstacle, two normals
    with pytest.raises(InvalidParameterError, match="risk"):
        offsets_along(normals, samples, risk="worst", **shapes)
    with pytest.raises(InvalidParameterError, match="obstacle_shapes"):
        offsets_along(normals, samples, ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.3)])
    assert offsets_along(normals, samples, **shapes).shape == (2, 3)


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

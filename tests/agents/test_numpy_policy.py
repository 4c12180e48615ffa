"""The numpy export of the PPO actor equals torch's deterministic predict (to 1e-6)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401
from agents import load_ppo
from agents.policies.numpy_policy import (
    NumpyPolicy,
    TorchActorPolicy,
    UnsupportedPolicyError,
    load_numpy_policy,
)
from filters import InvalidArrayError, InvalidParameterError


def assert_matches_torch(
    numpy_actions: np.ndarray, torch_actions: np.ndarray, *, unit: float = 1.0
) -> None:
    """|a_numpy - a_torch| <= 1e-6 unit max(1, |a_torch| / unit): float32 rounding of torch.

    ``unit`` is the half-width of the box for a squashed policy (its output tanh(mu) in
    [-1, 1] is stretched to the box, and so are torch's rounding errors).
    """
    assert numpy_actions.dtype == torch_actions.dtype == np.float32
    assert numpy_actions.shape == torch_actions.shape
    bound = 1e-6 * unit * np.maximum(1.0, np.abs(torch_actions) / unit)
    excess = np.abs(numpy_actions.astype(np.float64) - torch_actions) - bound
    assert np.all(excess <= 0.0), f"worst excess over the 1e-6 bound: {excess.max():.3e}"


@pytest.fixture(scope="module")
def shipped():
    model = load_ppo()
    return model, NumpyPolicy.from_sb3(model)


def test_shipped_policy_equals_torch_on_random_observations(shipped):
    model, policy = shipped
    rng = np.random.default_rng(0)
    for scale in (0.3, 1.0, 5.0):
        observations = (scale * rng.standard_normal((400, 26))).astype(np.float32)
        torch_batch, _ = model.predict(observations, deterministic=True)
        assert_matches_torch(policy.predict(observations, deterministic=True)[0], torch_batch)
        assert_matches_torch(policy.predict_batch(observations), torch_batch)
        for obs in observations[:50]:
            torch_action, _ = model.predict(obs, deterministic=True)
            numpy_action, state = policy.predict(obs, deterministic=True)
            assert state is None
            assert_matches_torch(numpy_action, torch_action)
    # the outputs vary: the comparison is not of constants
    assert np.ptp(torch_batch, axis=0).min() > 1.0


def test_shipped_policy_equals_torch_on_environment_observations(shipped):
    model, policy = shipped
    for env_id in ("SafeNav/HeadOn-v0", "SafeNav/MultiObstacle-v0", "SafeNav/RandomCrossing-v0"):
        env = gym.make(env_id)
        obs, _ = env.reset(seed=3)
        observations = []
        for _ in range(30):
            action, _ = model.predict(obs, deterministic=True)
            assert_matches_torch(policy.predict(obs)[0], action)
            observations.append(obs)
            obs, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                break
        batch = np.stack(observations)
        torch_batch, _ = model.predict(batch, deterministic=True)
        assert_matches_torch(policy.predict_batch(batch), torch_batch)
        env.close()


def test_load_numpy_policy_loads_the_shipped_policy(shipped):
    model, policy = shipped
    loaded = load_numpy_policy()
    for (w1, b1, f1), (w2, b2, f2) in zip(loaded.layers, policy.layers, strict=True):
        np.testing.assert_array_equal(w1, w2)
        np.testing.assert_array_equal(b1, b2)
        assert (f1 is None) == (f2 is None)
    assert not loaded.layers[0][0].flags.writeable
    with pytest.raises(FileNotFoundError, match="no PPO policy"):
        load_numpy_policy("/nonexistent/policy.zip")


def _model(**policy_kwargs):
    from stable_baselines3 import PPO

    use_sde = policy_kwargs.pop("use_sde", False)
    return PPO("MlpPolicy", gym.make("SafeNav/HeadOn-v0"), seed=0, device="cpu", n_steps=64,
               batch_size=64, use_sde=use_sde, policy_kwargs=policy_kwargs)


@pytest.mark.parametrize(
    "policy_kwargs",
    [
        {"net_arch": [32, 16]},  # Tanh, the SB3 default
        {"net_arch": [48], "activation_fn": "ReLU"},
        {"net_arch": {"pi": [24, 24], "vf": [8]}, "activation_fn": "LeakyReLU",
         "share_features_extractor": False},
        {"net_arch": [16, 16, 16], "activation_fn": "ELU"},
        {"net_arch": []},  # the action net straight on the observation
        {"net_arch": [32], "use_sde": True, "squash_output": True},
    ],
    ids=["tanh", "relu", "leaky-relu-separate-extractor", "elu", "linear", "gsde-squashed"],
)
def test_any_mlp_policy_equals_torch_and_clips_as_sb3(policy_kwargs):
    import torch

    if isinstance(policy_kwargs.get("activation_fn"), str):
        policy_kwargs = {**policy_kwargs,
                         "activation_fn": getattr(torch.nn, policy_kwargs["activation_fn"])}
    model = _model(**policy_kwargs)
    action_net = model.policy.action_net
    rng = np.random.default_rng(2)
    weight = rng.normal(0.0, 0.5, tuple(action_net.weight.shape))
    edge = 3.0 if model.policy.squash_output else 10.0  # tanh(+-4.2) rounds to the bounds
    bias = rng.choice([-edge, edge], action_net.bias.shape[0])
    with torch.no_grad():  # outputs around the bounds, so that clipping (or squashing) matters
        action_net.weight.copy_(torch.as_tensor(weight, dtype=torch.float32))
        action_net.bias.copy_(torch.as_tensor(bias, dtype=torch.float32))
    policy = NumpyPolicy.from_sb3(model)
    observations = np.random.default_rng(1).standard_normal((300, 26)).astype(np.float32)
    torch_actions, _ = model.predict(observations, deterministic=True)
    unit = 10.0 if model.policy.squash_output else 1.0  # the box is [-10, 10]^2
    assert_matches_torch(policy.predict_batch(observations), torch_actions, unit=unit)
    for obs in observations[:20]:
        torch_action, _ = model.predict(obs, deterministic=True)
        assert_matches_torch(policy.predict(obs)[0], torch_action, unit=unit)
    exact = TorchActorPolicy.from_sb3(model)
    assert np.array_equal(exact.predict_batch(observations), torch_actions)
    for obs in observations[:20]:
        assert np.array_equal(exact.predict(obs)[0], model.predict(obs, deterministic=True)[0])
    at_bounds = np.mean(np.abs(torch_actions) >= 10.0 - 1e-3)
    assert 0.05 < at_bounds < 0.95  # some actions were clipped (or squashed to the box edge)
    assert np.all(np.abs(policy.predict_batch(observations)) <= 10.0)


def test_bad_calls_raise_clear_errors(shipped):
    _, policy = shipped
    obs = np.zeros(26, dtype=np.float32)
    with pytest.raises(InvalidParameterError, match="deterministic=False"):
        policy.predict(obs, deterministic=False)
    with pytest.raises(InvalidArrayError, match=r"shape \(26,\) or \(batch, 26\), got \(25,\)"):
        policy.predict(np.zeros(25))
    with pytest.raises(InvalidArrayError, match="single observation"):
        policy.predict_batch(obs)
    bad = obs.copy()
    bad[4] = np.nan
    with pytest.raises(InvalidArrayError, match=r"finite, got nan at index \(4,\)"):
        policy.predict(bad)
    with pytest.raises(InvalidArrayError, match="numeric"):
        policy.predict("not an observation")


def test_unsupported_policies_are_refused():
    import torch
    from stable_baselines3 import PPO

    with pytest.raises(UnsupportedPolicyError, match="Sigmoid"):
        NumpyPolicy.from_sb3(_model(net_arch=[8], activation_fn=torch.nn.Sigmoid))
    discrete = PPO("MlpPolicy", gym.make("CartPole-v1"), device="cpu", n_steps=64, batch_size=64)
    with pytest.raises(UnsupportedPolicyError, match="Box action spaces are supported"):
        NumpyPolicy.from_sb3(discrete)
    with pytest.raises(UnsupportedPolicyError, match="ActorCriticPolicy"):
        NumpyPolicy.from_sb3(object())


def test_numpy_policy_drops_into_the_rollout_reference(shipped):
    from filters.references import PolicyRolloutReference

    model, policy = shipped
    env = gym.make("SafeNav/MultiObstacle-v0")
    obs, _ = env.reset(seed=5)
    for _ in range(5):
        action, _ = model.predict(obs, deterministic=True)
        torch_states, torch_inputs = PolicyRolloutReference(model)(env.unwrapped, action, 10)
        numpy_states, numpy_inputs = PolicyRolloutReference(policy)(env.unwrapped, action, 10)
        assert torch_states.shape == (11, 4)
        np.testing.assert_allclose(numpy_inputs, torch_inputs, rtol=0, atol=1e-5)
        np.testing.assert_allclose(numpy_states, torch_states, rtol=0, atol=1e-5)
        obs, *_ = env.step(action)
    env.close()


def test_benchmark_numpy_policy_reports_medians_and_agreement():
    from agents.policies.numpy_policy import benchmark_numpy_policy

    timing = benchmark_numpy_policy(calls=40, batch=8, seed=1)
    assert timing.calls == 40 and timing.batch == 8
    assert timing.sb3_us > 0 and timing.numpy_us > 0
    assert np.isclose(timing.ratio, timing.sb3_us / timing.numpy_us)
    assert timing.max_difference < 1e-5
    assert "NumpyPolicy" in timing.format()


def test_torch_actor_is_bit_identical_to_sb3_predict(shipped):
    model, _ = shipped
    actor = TorchActorPolicy.from_sb3(model)
    rng = np.random.default_rng(4)
    observations = (2.0 * rng.standard_normal((300, 26))).astype(np.float32)
    torch_batch, _ = model.predict(observations, deterministic=True)
    assert np.array_equal(actor.predict(observations)[0], torch_batch)
    for obs in observations[:100]:
        assert np.array_equal(actor.predict(obs)[0], model.predict(obs, deterministic=True)[0])
        as_float64 = obs.astype(np.float64)  # SB3 casts to float32 first; so does the actor
        assert np.array_equal(actor.predict(as_float64)[0],
                              model.predict(as_float64, deterministic=True)[0])
    with pytest.raises(InvalidParameterError, match="TorchActorPolicy"):
        actor.predict(observations[0], deterministic=False)
    # any policy_net is called as it is
    import torch

    sigmoid = _model(net_arch=[8], activation_fn=torch.nn.Sigmoid)
    obs = observations[:10]
    assert np.array_equal(TorchActorPolicy.from_sb3(sigmoid).predict_batch(obs),
                          sigmoid.predict(obs, deterministic=True)[0])


def test_torch_actor_keeps_evaluation_records_identical(shipped):
    """Same records as the SB3 model (apart from wall times), unlike the numpy export,
    when the roll-out calls the actor at every step (``compiled_rollout=False``); the
    compiled roll-out (the default) gives the same outcomes, distances to rounding."""
    import dataclasses

    from agents.evaluation.evaluate import EpisodeSpec, run_episode

    model, _ = shipped
    actor = TorchActorPolicy.from_sb3(model)
    timing = {"wall_time", "filter_time_median", "filter_time_max", "policy"}  # + its name
    loop = '{"compiled_rollout": false}'
    for spec in (EpisodeSpec("MultiObstacle", "dr_cvar", 0, filter_options=loop),
                 EpisodeSpec("HeadOn", "none", 1)):
        records = [dataclasses.asdict(run_episode(spec, policy=p)[0]) for p in (model, actor)]
        assert records[0]["steps"] > 5
        for key in records[0]:
            if key not in timing:
                a, b = records[0][key], records[1][key]
                assert a == b or (a != a and b != b), key  # NaN (no goal) in both
    spec = EpisodeSpec("MultiObstacle", "dr_cvar", 0)
    exact, compiled = (dataclasses.asdict(run_episode(spec, policy=p)[0]) for p in (model, actor))
    assert compiled["steps"] > 5
    for key in exact:
        a, b = exact[key], compiled[key]
        if key in timing or key == "filter_options":
            continue
        if isinstance(a, float) and not isinstance(a, bool):
            assert a == pytest.approx(b, rel=1e-6, abs=1e-6, nan_ok=True), key
        else:
            assert a == b, key


def test_rollout_reference_timing_covers_every_path():
    from benchmarks.suite import benchmark_rollout_reference, format_rollout_reference

    medians = benchmark_rollout_reference(horizon=5, steps=4)
    assert set(medians) == {"sb3", "numpy", "torch_actor", "compiled", "hold"}
    assert all(value > 0 for value in medians.values())
    assert "compiled kernel" in format_rollout_reference(medians, 5)

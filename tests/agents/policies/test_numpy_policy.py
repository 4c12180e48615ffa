"""The numpy export of the PPO actor equals torch's deterministic predict (to 1e-6)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401
from agents import load_ppo
from agents.policies.numpy_policy import (
    NumpyPolicy,
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


def test_benchmark_numpy_policy_reports_medians_and_agreement():
    from benchmarks.policy import benchmark_numpy_policy

    timing = benchmark_numpy_policy(calls=40, batch=8, seed=1)
    assert timing.calls == 40 and timing.batch == 8
    assert timing.sb3_us > 0 and timing.numpy_us > 0
    assert np.isclose(timing.ratio, timing.sb3_us / timing.numpy_us)
    assert timing.max_difference < 1e-5
    assert "NumpyPolicy" in timing.format()


def test_rollout_reference_timing_covers_every_path():
    from benchmarks.policy import benchmark_rollout_reference, format_rollout_reference

    medians = benchmark_rollout_reference(horizon=5, steps=4)
    assert set(medians) == {"sb3", "numpy", "hold"}
    assert all(value > 0 for value in medians.values())
    assert "NumpyPolicy.predict" in format_rollout_reference(medians, 5)


def test_torch_actor_policy_is_a_deprecated_alias_of_numpy_policy(shipped):
    import agents
    from agents.policies import numpy_policy

    with pytest.warns(DeprecationWarning, match="alias of NumpyPolicy"):
        alias = agents.TorchActorPolicy
    assert alias is NumpyPolicy
    with pytest.warns(DeprecationWarning, match="alias of NumpyPolicy"):
        assert numpy_policy.TorchActorPolicy is NumpyPolicy
    assert isinstance(alias.from_sb3(shipped[0]), NumpyPolicy)
    with pytest.raises(AttributeError, match="no attribute 'NoSuchPolicy'"):
        numpy_policy.NoSuchPolicy  # noqa: B018


def _plain_rollout(model, base, action, horizon):
    """The readable reference roll-out: SB3's ``predict`` at each look-ahead step, the
    environment's dynamics (with the input it applies, its speed limit included) and its
    ``observe`` on the predicted mean obstacle positions."""
    A, B, _ = base.dynamics
    low, high = base.input_bounds
    means = base.predictions.mean(axis=1)  # (n_obstacles, T, 2)
    x, u = np.array(base.ego_state, dtype=float), np.clip(action, low, high)
    states, inputs = [x], []
    for k in range(horizon):
        if k > 0:
            obs = base.observe(x, means[:, k - 1], base.obstacle_velocities)
            u = np.clip(model.predict(obs, deterministic=True)[0], low, high)
        u = base.applied_input(x, u)
        x = A @ x + B @ u
        states.append(x)
        inputs.append(u)
    return np.array(states), np.array(inputs)


def _situations(seed: int):
    """Environment states along episodes driven by seeded random actions (all scenarios)."""
    rng = np.random.default_rng(seed)
    for env_id in ("SafeNav/HeadOn-v0", "SafeNav/MultiObstacle-v0", "SafeNav/Intersection-v0",
                   "SafeNav/RandomCrossing-v0"):
        env = gym.make(env_id)
        env.reset(seed=int(rng.integers(1000)))
        for _ in range(12):
            action = rng.uniform(-8.0, 8.0, 2).astype(np.float32)
            yield env.unwrapped, action
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                break
        env.close()


def test_numpy_rollout_is_within_1e_6_m_of_the_plain_sb3_rollout(shipped):
    """PolicyRolloutReference with the numpy actor against the readable reference (SB3's
    predict + dynamics + observe): positions within 1e-6 m, actions within 1e-5 m/s²."""
    from filters.references import PolicyRolloutReference

    model, policy = shipped
    fast, sb3 = PolicyRolloutReference(policy), PolicyRolloutReference(model)
    count = 0
    for base, action in _situations(11):
        expected_states, expected_inputs = _plain_rollout(model, base, action, 10)
        states, inputs = fast(base, action, 10)
        assert states.shape == (11, 4) and inputs.shape == (10, 2)
        np.testing.assert_allclose(states[:, :2], expected_states[:, :2], rtol=0, atol=1e-6)
        np.testing.assert_allclose(states[:, 2:], expected_states[:, 2:], rtol=0, atol=1e-5)
        np.testing.assert_allclose(inputs, expected_inputs, rtol=0, atol=1e-5)
        # with SB3's model the roll-out is the plain loop itself (to rounding)
        sb3_states, _ = sb3(base, action, 10)
        np.testing.assert_allclose(sb3_states, expected_states, rtol=0, atol=1e-12)
        count += 1
    assert count > 30


@pytest.mark.parametrize(
    "policy_kwargs",
    [
        {"net_arch": [16, 8]},
        {"net_arch": [12], "activation_fn": "LeakyReLU"},
        {"net_arch": [12], "activation_fn": "ELU"},
        {"net_arch": [8], "use_sde": True, "squash_output": True},
    ],
    ids=["tanh", "leaky-relu", "elu", "gsde-squashed"],
)
def test_a_saved_policy_loads_with_the_same_actions_and_spaces(tmp_path, policy_kwargs):
    import torch

    if "activation_fn" in policy_kwargs:
        policy_kwargs = {**policy_kwargs,
                         "activation_fn": getattr(torch.nn, policy_kwargs["activation_fn"])}
    policy = NumpyPolicy.from_sb3(_model(**policy_kwargs))
    policy.save(tmp_path / "policy.npz")
    loaded = NumpyPolicy.load(tmp_path / "policy.npz")
    assert loaded.observation_space == policy.observation_space
    assert loaded.action_space == policy.action_space
    assert loaded.squash_output == policy.squash_output
    assert [a for _, _, a in loaded.layers] == [a for _, _, a in policy.layers]
    observations = np.random.default_rng(3).standard_normal((200, 26)).astype(np.float32)
    expected = policy.predict_batch(observations)
    np.testing.assert_allclose(loaded.predict_batch(observations), expected, rtol=0,
                               atol=1e-6 * max(1.0, float(np.max(np.abs(expected)))))


def test_a_file_that_is_no_saved_policy_is_refused(tmp_path, shipped):
    _, policy = shipped
    (tmp_path / "junk.npz").write_bytes(b"not an npz file")
    with pytest.raises(UnsupportedPolicyError, match="not a NumpyPolicy file"):
        NumpyPolicy.load(tmp_path / "junk.npz")
    policy.save(tmp_path / "policy.npz")
    with np.load(tmp_path / "policy.npz") as data:
        arrays = {key: data[key] for key in data.files}
    np.savez(tmp_path / "future.npz", **{**arrays, "format": np.array(99)})
    with pytest.raises(UnsupportedPolicyError, match="export format 99"):
        NumpyPolicy.load(tmp_path / "future.npz")

"""The compiled roll-out reference against the Python roll-out it replaces.

The slow, obviously correct path is :class:`filters.references.PolicyRolloutReference`
with ``compiled=False``: the policy's own ``predict`` at every look-ahead step, the
environment's own ``observe``, numpy's ``A @ x + B @ u``. With the float64 numpy actor
the compiled kernel must give the same numbers (to 1e-12: the same arithmetic); against
SB3's float32 torch actor, the same to the float32 rounding of torch (1e-6 relative).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401
from agents import load_ppo
from agents.policies.compiled_rollout import (
    CompiledRollout,
    _observe,
    compile_rollout,
    supports_env,
)
from agents.policies.numpy_policy import NumpyPolicy, TorchActorPolicy
from agents.training.wrappers import PhysicalUnitsPolicy
from filters import (
    InvalidArrayError,
    InvalidParameterError,
    InvalidTypeError,
    SafetyFilterWrapper,
)
from filters.references import PolicyRolloutReference
from safe_nav_env.env import SafeNavEnv


@pytest.fixture(scope="module")
def model():
    return load_ppo()


def _states(env_id: str, seeds: range, *, steps: int = 12, **make):
    """Environments at varied states: along episodes of random actions, then the ego
    placed at random states (fast, slow, near obstacles), so clipping matters too."""
    env = gym.make(env_id, **make)
    base = env.unwrapped
    rng = np.random.default_rng(len(env_id))
    for seed in seeds:
        env.reset(seed=seed)
        for _ in range(steps):
            env.step(rng.uniform(-10.0, 10.0, 2).astype(np.float32))
            yield base, rng.uniform(-10.0, 10.0, 2)
            saved = base.ego_state
            base.ego_state = np.concatenate([rng.uniform(-5.0, 5.0, 2),
                                             rng.uniform(-6.0, 6.0, 2)])
            yield base, rng.uniform(-12.0, 12.0, 2)  # outside the box: clipped
            base.ego_state = saved
    env.close()


def _compare(fast, slow, env_id, *, atol, rtol=0.0, horizons=(10,), **make):
    count = 0
    for base, action in _states(env_id, range(3), **make):
        for horizon in horizons:
            s1, u1 = fast(base, action, horizon)
            s2, u2 = slow(base, action, horizon)
            assert s1.shape == s2.shape == (horizon + 1, 4)
            assert u1.shape == u2.shape == (horizon, 2)
            np.testing.assert_allclose(u1, u2, atol=atol, rtol=rtol)
            np.testing.assert_allclose(s1, s2, atol=atol, rtol=rtol)
            count += 1
    return count


@pytest.mark.parametrize("env_id, make", [
    ("SafeNav/HeadOn-v0", {}),
    ("SafeNav/MultiObstacle-v0", {}),
    ("SafeNav/MultiObstacle-v0", {"max_obstacles": 2}),  # the farthest is left out
    ("SafeNav/RandomCrossing-v0", {"n_samples": 37, "horizon": 12}),
])
def test_compiled_equals_the_numpy_policy_loop(model, env_id, make):
    if "max_obstacles" in make:  # another observation size: a network of its own
        from stable_baselines3 import PPO

        model = PPO("MlpPolicy", gym.make(env_id, **make), seed=3, device="cpu", n_steps=64)
    policy = NumpyPolicy.from_sb3(model)
    fast = PolicyRolloutReference(policy)
    slow = PolicyRolloutReference(policy, compiled=False)
    assert fast._fast is not None and slow._fast is None
    count = _compare(fast, slow, env_id, atol=1e-12, horizons=(1, 2, 10), **make)
    assert count >= 200


def test_compiled_equals_sb3_predict_to_float32_rounding(model):
    """Torch's float32 actor against the float64 one: every action of the compiled
    roll-out is SB3's action at the roll-out's own state to 1e-6 (relative, m/s²); the
    whole roll-out follows SB3's to the accumulated rounding (a few 1e-6)."""
    fast = PolicyRolloutReference(TorchActorPolicy.from_sb3(model))
    slow = PolicyRolloutReference(model)  # SB3's predict: no compiled path
    assert slow._fast is None
    differences = []
    for base, action in _states("SafeNav/MultiObstacle-v0", range(3)):
        s1, u1 = fast(base, action, 10)
        means = np.asarray(base.predictions).mean(axis=1)
        for k in range(1, 10):
            obs = base.observe(s1[k], means[:, k - 1], base.obstacle_velocities)
            expected = np.clip(model.predict(obs, deterministic=True)[0], -10.0, 10.0)
            assert np.all(np.abs(u1[k] - expected) <= 1e-6 * np.maximum(1.0, np.abs(expected)))
        s2, u2 = slow(base, action, 10)
        np.testing.assert_allclose(u1, u2, atol=5e-5, rtol=0)
        np.testing.assert_allclose(s1, s2, atol=5e-5, rtol=0)
        differences.append(np.abs(u1 - u2).max())
    assert max(differences) > 0.0  # the float32 and float64 networks do differ somewhere


def _sb3(**policy_kwargs):
    import torch
    from stable_baselines3 import PPO

    if isinstance(policy_kwargs.get("activation_fn"), str):
        policy_kwargs["activation_fn"] = getattr(torch.nn, policy_kwargs["activation_fn"])
    use_sde = policy_kwargs.pop("use_sde", False)
    return PPO("MlpPolicy", gym.make("SafeNav/HeadOn-v0"), seed=0, device="cpu", n_steps=64,
               batch_size=64, use_sde=use_sde, policy_kwargs=policy_kwargs)


@pytest.mark.parametrize("policy_kwargs", [
    {"net_arch": [48], "activation_fn": "ReLU"},
    {"net_arch": [24, 24], "activation_fn": "LeakyReLU"},
    {"net_arch": [16, 16], "activation_fn": "ELU"},
    {"net_arch": []},
    {"net_arch": [32], "use_sde": True, "squash_output": True},
], ids=["relu", "leaky-relu", "elu", "linear", "gsde-squashed"])
def test_every_exportable_network_compiles_to_the_same_rollout(policy_kwargs):
    import torch

    model = _sb3(**dict(policy_kwargs))
    with torch.no_grad():  # large outputs, so that the box clip (or the squash) matters
        model.policy.action_net.bias.copy_(torch.tensor([8.0, -6.0]))
        model.policy.action_net.weight.mul_(20.0)
    policy = NumpyPolicy.from_sb3(model)
    _compare(PolicyRolloutReference(policy), PolicyRolloutReference(policy, compiled=False),
             "SafeNav/HeadOn-v0", atol=1e-12)
    if "activation_fn" not in policy_kwargs or policy_kwargs["activation_fn"] == "ReLU":
        # the live torch export (Tanh / ReLU nets) against SB3 itself
        live = PolicyRolloutReference(TorchActorPolicy.from_sb3(model))
        assert live._fast is not None
        _compare(live, PolicyRolloutReference(model), "SafeNav/HeadOn-v0", atol=2e-5,
                 rtol=2e-6)


def test_a_normalised_policy_rolls_out_in_physical_units():
    """PhysicalUnitsPolicy's map c + w a is folded into the kernel."""
    from agents.training.wrappers import NormalisedActions

    env = NormalisedActions(gym.make("SafeNav/HeadOn-v0"))
    from stable_baselines3 import PPO

    model = PPO("MlpPolicy", env, seed=1, device="cpu", n_steps=64, batch_size=64)
    physical = PhysicalUnitsPolicy(model, env.unwrapped.action_space)
    compiled = compile_rollout(physical)
    assert compiled is not None
    np.testing.assert_array_equal(compiled.half_width, [10.0, 10.0])
    _compare(PolicyRolloutReference(physical), PolicyRolloutReference(physical, compiled=False),
             "SafeNav/HeadOn-v0", atol=2e-4, rtol=2e-6)  # 10 x the float32 rounding


def test_the_live_export_follows_training(model):
    """TorchActorPolicy and SB3 models share the torch parameters: in-place updates (the
    optimiser's) and replaced tensors are picked up by the compiled roll-out."""
    import copy

    import torch

    own = copy.deepcopy(model)
    actor = TorchActorPolicy.from_sb3(own)
    env = gym.make("SafeNav/MultiObstacle-v0")
    env.reset(seed=0)
    base, action = env.unwrapped, np.array([1.0, -2.0])
    before = actor.rollout_reference(base, action, 10)
    with torch.no_grad():
        own.policy.action_net.bias.add_(0.75)
    after = actor.rollout_reference(base, action, 10)
    assert not np.array_equal(before[1][1:], after[1][1:])
    expected = PolicyRolloutReference(own)(base, action, 10)
    np.testing.assert_allclose(after[1], expected[1], atol=1e-5)
    own.policy.action_net.weight.data = own.policy.action_net.weight.data * 0.5  # replaced
    expected = PolicyRolloutReference(own)(base, action, 10)
    np.testing.assert_allclose(actor.rollout_reference(base, action, 10)[1], expected[1],
                               atol=1e-5)
    env.close()


def test_the_training_policy_uses_the_compiled_rollout_of_its_model():
    from agents.training.ppo import TrainingPolicy
    from agents.training.wrappers import NormalisedActions

    env = NormalisedActions(gym.make("SafeNav/HeadOn-v0"))
    from stable_baselines3 import PPO

    model = PPO("MlpPolicy", env, seed=2, device="cpu", n_steps=64, batch_size=64)
    policy = TrainingPolicy()
    base = env.unwrapped
    base.reset(seed=0)
    assert policy.rollout_reference(base, np.zeros(2), 10) is None  # not bound yet
    policy.bind(model, base.action_space)
    made = policy.rollout_reference(base, np.zeros(2), 10)
    expected = PolicyRolloutReference(policy, compiled=False)(base, np.zeros(2), 10)
    np.testing.assert_allclose(made[0], expected[0], atol=1e-4)
    model.learn(64)  # one PPO update changes the weights in place
    made = policy.rollout_reference(base, np.zeros(2), 10)
    expected = PolicyRolloutReference(policy, compiled=False)(base, np.zeros(2), 10)
    np.testing.assert_allclose(made[1], expected[1], atol=2e-4, rtol=2e-6)


def test_the_kernel_observation_is_the_environment_observation_bit_for_bit():
    rng = np.random.default_rng(8)
    for max_obstacles in (0, 1, 2, 4):
        env = gym.make("SafeNav/MultiObstacle-v0", max_obstacles=max_obstacles)
        base = env.unwrapped
        env.reset(seed=1)
        size = base.observation_space.shape[0]
        for _ in range(300):
            n = int(rng.integers(0, 7))
            x = 4.0 * rng.standard_normal(4)
            p, v = 4.0 * rng.standard_normal((n, 2)), rng.standard_normal((n, 2))
            if n > 2:
                p[2] = p[0]  # a tie in the distance: the stable order decides
            obs = np.full(size, 7.0, dtype=np.float32)  # the kernel zeroes it
            _observe(x, p, v, base.goal, base.max_obstacles, obs, np.empty(n, np.int64),
                     np.empty(n))
            assert np.array_equal(obs, base.observe(x, p, v))
        env.close()


def test_same_inputs_give_the_same_bits_whatever_ran_before(model):
    policy = NumpyPolicy.from_sb3(model)
    envs = [gym.make(i) for i in ("SafeNav/HeadOn-v0", "SafeNav/RandomCrossing-v0")]
    for seed, env in enumerate(envs):
        env.reset(seed=seed)
    first = [policy.rollout_reference(env.unwrapped, np.ones(2), 10) for env in envs]
    for env in reversed(envs):  # another order, other calls in between
        policy.rollout_reference(env.unwrapped, -np.ones(2), 7)
    again = [policy.rollout_reference(env.unwrapped, np.ones(2), 10) for env in envs]
    for (s1, u1), (s2, u2) in zip(first, again, strict=True):
        assert np.array_equal(s1, s2) and np.array_equal(u1, u2)
        assert s1 is not s2  # fresh arrays each call: a kept reference never changes


def test_bad_data_raises_the_package_errors(model):
    policy = NumpyPolicy.from_sb3(model)
    env = gym.make("SafeNav/HeadOn-v0")
    env.reset(seed=0)
    base = env.unwrapped
    with pytest.raises(InvalidArrayError, match="action must have 2 entries"):
        policy.rollout_reference(base, np.zeros(3), 10)
    with pytest.raises(InvalidParameterError, match="horizon"):
        policy.rollout_reference(base, np.zeros(2), 12)  # predictions for 10 steps
    predictions = np.array(base.predictions)
    predictions[0, 3, 4, 1] = np.nan
    base.predictions = predictions
    with pytest.raises(InvalidArrayError, match="look-ahead step 5 is not finite"):
        policy.rollout_reference(base, np.zeros(2), 10)
    policy.rollout_reference(base, np.zeros(2), 5)  # steps 1..4 only: finite
    with pytest.raises(InvalidTypeError, match="compiled must be a bool"):
        PolicyRolloutReference(policy, compiled="yes")
    env.close()


def test_nan_predictions_in_the_wrapper_are_an_error_status(model):
    env = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"),
                              policy=NumpyPolicy.from_sb3(model))
    env.reset(seed=0)
    base = env.unwrapped
    predictions = np.array(base.predictions)
    predictions[0, 0, 2, 0] = np.nan
    base.predictions = predictions
    _, _, _, _, info = env.step(np.zeros(2, dtype=np.float32))
    assert info["filter"].status == "error" and "not finite" in info["filter"].error
    assert np.all(np.isfinite(info["filter"].applied_action))


class _OwnObservation(SafeNavEnv):
    def observe(self, ego_state, obstacle_positions, obstacle_velocities):
        return 0.5 * super().observe(ego_state, obstacle_positions, obstacle_velocities)


def test_unknown_environments_and_networks_fall_back_to_predict(model):
    import torch

    own = _OwnObservation("HeadOn")
    own.reset(seed=0)
    assert not supports_env(own) and supports_env(gym.make("SafeNav/HeadOn-v0").unwrapped)
    policy = NumpyPolicy.from_sb3(model)
    assert policy.rollout_reference(own, np.zeros(2), 10) is None
    states, _ = PolicyRolloutReference(policy)(own, np.zeros(2), 10)  # the loop: own observe
    expected, _ = PolicyRolloutReference(policy, compiled=False)(own, np.zeros(2), 10)
    assert np.array_equal(states, expected)
    sigmoid = _sb3(net_arch=[8], activation_fn=torch.nn.Sigmoid)
    assert compile_rollout(TorchActorPolicy.from_sb3(sigmoid)) is None
    assert compile_rollout(object()) is None
    from agents.planners import MPCReferencePlanner

    env = gym.make("SafeNav/HeadOn-v0")
    assert compile_rollout(MPCReferencePlanner.from_env(env)) is None


def test_the_wrapper_switch_and_its_validation(model):
    actor = TorchActorPolicy.from_sb3(model)
    on = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), policy=actor)
    off = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), policy=actor,
                              compiled_rollout=False)
    assert on.reference._fast is not None and off.reference._fast is None
    with pytest.raises(InvalidTypeError, match="compiled_rollout must be a bool"):
        SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), policy=actor, compiled_rollout=1)
    assert isinstance(compile_rollout(actor), CompiledRollout)


def test_shapes_are_checked_before_the_kernel_runs(model):
    """The kernel does not check indices: every shape is checked before it runs."""
    from agents.policies.compiled_rollout import ActorNetwork

    box = dict(squash=False, action_low=[-1.0, -1.0], action_high=[1.0, 1.0])
    with pytest.raises(InvalidArrayError, match="layer 1"):
        ActorNetwork.from_layers([(np.zeros((26, 8)), np.zeros(8), "tanh", 0.0),
                                  (np.zeros((9, 2)), np.zeros(2), "identity", 0.0)], **box)
    with pytest.raises(InvalidArrayError, match="layer 0"):
        ActorNetwork.from_layers([(np.zeros((26, 2)), np.zeros(3), "identity", 0.0)], **box)
    with pytest.raises(InvalidArrayError, match="action box"):
        ActorNetwork.from_layers([(np.zeros((26, 3)), np.zeros(3), "identity", 0.0)], **box)
    with pytest.raises(InvalidParameterError, match="activation"):
        ActorNetwork.from_layers([(np.zeros((26, 2)), np.zeros(2), "swish", 0.0)], **box)
    with pytest.raises(InvalidParameterError, match="at least one layer"):
        ActorNetwork.from_layers([], **box)
    compiled = compile_rollout(NumpyPolicy.from_sb3(model))
    small = gym.make("SafeNav/HeadOn-v0", max_obstacles=2)  # 16 observation entries
    small.reset(seed=0)
    assert not compiled.supports(small.unwrapped)
    with pytest.raises(InvalidArrayError, match="takes 26 inputs"):
        compiled(small.unwrapped, np.zeros(2), 10)  # called directly, without supports()


def test_the_kernel_checks_every_shape_and_type_it_is_given(model):
    """The shapes are checked inside the kernel (a status, then the package's errors):
    each misfit raises, none reads out of bounds; other dimensions or dtypes too."""
    from agents.policies.compiled_rollout import ActorNetwork

    compiled = compile_rollout(NumpyPolicy.from_sb3(model))
    env = gym.make("SafeNav/MultiObstacle-v0")
    env.reset(seed=3)
    base = env.unwrapped
    states, inputs = compiled(base, np.ones(2), 10)
    again = compiled(base, np.ones(2, dtype=np.float32), np.int64(10))  # as given: same bits
    assert np.array_equal(states, again[0]) and np.array_equal(inputs, again[1])
    with pytest.raises(InvalidParameterError, match="horizon"):
        compiled(base, np.ones(2), 0)
    misfits = {"obstacle_velocities": np.zeros((2, 2)),  # 3 obstacles predicted
               "goal": np.zeros(3), "ego_state": np.zeros(5),
               "predictions": np.zeros((3, 100, 10, 3))}
    for name, value in misfits.items():
        saved = getattr(base, name)
        setattr(base, name, value)
        with pytest.raises(InvalidArrayError, match="do not fit|the network takes"):
            compiled(base, np.ones(2), 10)
        setattr(base, name, saved)
    saved = base.goal
    base.goal = np.zeros((2, 1))  # another dimension: numba cannot take it
    with pytest.raises(InvalidArrayError, match="do not fit"):
        compiled(base, np.ones(2), 10)
    base.goal = saved
    assert np.array_equal(compiled(base, np.ones(2), 10)[0], states)
    weights = (np.zeros((26, 8)), np.zeros((9, 2)))  # 8 outputs, then 9 inputs
    with pytest.raises(InvalidArrayError, match="layer 1"):
        ActorNetwork(weights, (np.zeros(8), np.zeros(2)), np.zeros(2, np.int64), np.zeros(2),
                     False, np.zeros(2, np.float32), np.ones(2, np.float32))
    env.close()

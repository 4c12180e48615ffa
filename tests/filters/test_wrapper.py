"""SafetyFilterWrapper: Gymnasium compliance, the safety guarantee, graceful failure."""

from __future__ import annotations

import re
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import safe_nav_env  # noqa: F401
from agents.planners import MPCReferencePlanner
from filters import (
    InvalidArrayError,
    InvalidParameterError,
    InvalidTypeError,
    SafetyFilterWrapper,
)
from filters.references import PolicyRolloutReference, hold_action_reference
from filters.wrapper import RISKS
from safe_nav_env import ObstacleSpec, Scenario

RISKY = [r for r in RISKS if r != "none"]


def _run(env: SafetyFilterWrapper, planner: MPCReferencePlanner, seed: int):
    obs, _ = env.reset(seed=seed)
    infos = []
    done = False
    while not done:
        action, _ = planner.predict(obs)
        obs, _, terminated, truncated, info = env.step(action)
        infos.append(info)
        done = terminated or truncated
    return infos


@pytest.mark.parametrize("risk", RISKS)
def test_gymnasium_env_checker_passes(risk):
    env = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), risk=risk)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*action space.*")
        warnings.filterwarnings("ignore", message=".*different from the unwrapped.*")
        check_env(env, skip_render_check=True)


def test_sb3_env_checker_passes():
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = SafetyFilterWrapper(gym.make("SafeNav/MultiObstacle-v0"), risk="dr_cvar")
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*action space.*")
        sb3_check_env(env, warn=False)


@pytest.mark.parametrize("risk", RISKY)
def test_optimal_plans_stay_inside_every_halfspace(risk):
    env = SafetyFilterWrapper(gym.make("SafeNav/MultiObstacle-v0"), risk=risk)
    planner = MPCReferencePlanner.from_env(env)
    C = env.unwrapped.dynamics[2]
    checked = 0
    for seed in range(3):
        for info in _run(env, planner, seed):
            report = info["filter"]
            if report["status"] != "optimal":
                continue
            positions = report["planned_states"][1:] @ C.T  # (T, 2)
            lhs = np.einsum("itd,td->it", report["normals"], positions)
            assert np.all(lhs <= report["offsets"] + 1e-6)
            # The applied input is the first input of that plan.
            np.testing.assert_allclose(
                report["planned_states"][1],
                env.unwrapped.dynamics[0] @ report["planned_states"][0]
                + env.unwrapped.dynamics[1] @ report["applied_action"], atol=1e-9)
            checked += 1
    assert checked > 20


def test_reports_compare_equal_whatever_the_timings():
    runs = []
    for _ in range(2):
        env = SafetyFilterWrapper(gym.make("SafeNav/MultiObstacle-v0"), risk="dr_cvar")
        env.reset(seed=5)
        runs.append([env.step(np.array([2.0, 0.5], dtype=np.float32))[4]["filter"]
                     for _ in range(5)])
    first, second = runs
    assert first == second
    assert first[0]["status"] == first[0].status
    assert any(a.filter_time != b.filter_time for a, b in zip(first, second, strict=True))
    assert first[0] != first[1]


def test_passthrough_applies_the_proposal_unchanged():
    env = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), risk="none")
    env.reset(seed=0)
    action = np.array([1.5, -0.25], dtype=np.float32)
    before = env.unwrapped.ego_state.copy()
    _, _, _, _, info = env.step(action)
    report = info["filter"]
    assert report["status"] == "passthrough"
    assert report["intervention"] == 0.0
    np.testing.assert_array_equal(report["applied_action"], action.astype(float))
    A, B, _ = env.unwrapped.dynamics
    np.testing.assert_allclose(env.unwrapped.ego_state, A @ before + B @ action, atol=1e-6)


def test_dr_cvar_collides_less_than_unfiltered_with_mpc_planner():
    outcomes = {}
    for risk in ("none", "dr_cvar"):
        env = SafetyFilterWrapper(gym.make("SafeNav/MultiObstacle-v0"), risk=risk)
        planner = MPCReferencePlanner.from_env(env)
        outcomes[risk] = sum(any(i["collision"] for i in _run(env, planner, seed))
                             for seed in range(6))
    assert outcomes["none"] >= 4
    assert outcomes["dr_cvar"] < outcomes["none"]


def _trap_scenario() -> Scenario:
    # An obstacle sits right in front of a fast ego: no input in the box avoids it.
    return Scenario(
        name="trap", ego_start=(-1.0, 0.0, 4.0, 0.0), goal=(4.0, 0.0),
        obstacles=(ObstacleSpec(start=(-0.3, 0.0), velocity=(-1.0, 0.0)),),
        duration=2.0,
    )


def test_infeasible_steps_fall_back_without_raising():
    env = SafetyFilterWrapper(
        gym.make("SafeNav/Custom-v0", scenario=_trap_scenario(), max_acceleration=1.0,
                 max_speed=5.0),
        risk="dr_cvar", fallback="paper", terminal=False)
    env.reset(seed=0)
    statuses = []
    for _ in range(6):
        _, _, terminated, truncated, info = env.step(np.zeros(2, dtype=np.float32))
        statuses.append(info["filter"]["status"])
        low, high = env.unwrapped.input_bounds
        assert np.all(info["filter"]["applied_action"] >= low - 1e-9)
        assert np.all(info["filter"]["applied_action"] <= high + 1e-9)
        if terminated or truncated:
            break
    assert statuses[0] == "brake"  # no plan stored yet: the last resort
    assert set(statuses) <= {"brake", "shifted", "optimal"}


def test_infeasible_steps_recover_with_the_default_fallback():
    env = SafetyFilterWrapper(
        gym.make("SafeNav/Custom-v0", scenario=_trap_scenario(), max_acceleration=1.0,
                 max_speed=5.0),
        risk="dr_cvar")
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(2, dtype=np.float32))
    report = info["filter"]
    assert report.status in ("soft", "recovery")  # the exact-penalty QP, not braking
    assert report.slack is not None and np.max(report.slack) > 0.0
    low, high = env.unwrapped.input_bounds
    assert np.all(report.applied_action >= low - 1e-9)
    assert np.all(report.applied_action <= high + 1e-9)


def test_soft_mode_reports_slack_instead_of_falling_back():
    env = SafetyFilterWrapper(
        gym.make("SafeNav/Custom-v0", scenario=_trap_scenario(), max_acceleration=1.0,
                 max_speed=5.0),
        risk="dr_cvar", soft=True, terminal=False)  # only the halfspaces are at stake
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(2, dtype=np.float32))
    assert info["filter"]["status"] == "soft"
    assert np.max(info["filter"]["slack"]) > 0.0


def test_non_finite_action_brakes_and_says_why():
    env = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), risk="dr_cvar")
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([np.nan, 0.0], dtype=np.float32))
    report = info["filter"]
    assert report["status"] == "error"
    assert report["error"]
    assert np.all(np.isfinite(report["applied_action"]))


def test_policy_rollout_reference_follows_the_dynamics():
    env = gym.make("SafeNav/MultiObstacle-v0")
    env.reset(seed=1)
    planner = MPCReferencePlanner.from_env(env)
    base = env.unwrapped
    proposal = np.array([0.5, 0.2])
    states, inputs = PolicyRolloutReference(planner)(base, proposal, 10)
    A, B, _ = base.dynamics
    np.testing.assert_allclose(inputs[0], proposal)
    np.testing.assert_allclose(states[0], base.ego_state)
    np.testing.assert_allclose(states[1:], states[:-1] @ A.T + inputs @ B.T, atol=1e-12)
    held_states, held_inputs = hold_action_reference(base, proposal, 10)
    np.testing.assert_allclose(held_inputs, np.tile(proposal, (10, 1)))
    assert not np.allclose(states, held_states)  # the planner re-plans along the way


def test_the_compiled_rollout_switches_are_deprecated_and_ignored():
    env = gym.make("SafeNav/HeadOn-v0")
    env.reset(seed=0)
    planner = MPCReferencePlanner.from_env(env)
    with pytest.warns(DeprecationWarning, match="compiled=.*deprecated and ignored"):
        maker = PolicyRolloutReference(planner, compiled=False)
    expected = PolicyRolloutReference(planner)(env.unwrapped, np.ones(2), 10)
    np.testing.assert_allclose(maker(env.unwrapped, np.ones(2), 10)[0], expected[0], atol=1e-12)
    with pytest.warns(DeprecationWarning, match="compiled_rollout=.*deprecated and ignored"):
        wrapped = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), policy=planner,
                                      compiled_rollout=False)
    assert isinstance(wrapped.reference, PolicyRolloutReference)
    with pytest.warns(DeprecationWarning, match="fast_path=.*deprecated and ignored"):
        lean = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), fast_path=False)
    plain = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"))
    for env in (lean, plain):
        env.reset(seed=3)
    for _ in range(10):  # the same steps with or without the ignored switch
        a, b = (env.step(np.array([2.0, 1.0]))[4]["filter"] for env in (lean, plain))
        assert a.status == b.status
        np.testing.assert_array_equal(a.applied_action, b.applied_action)


def test_intervention_penalty_lowers_the_reward_by_its_square():
    rewards = {}
    for penalty in (0.0, 2.0):
        env = SafetyFilterWrapper(gym.make("SafeNav/MultiObstacle-v0"), risk="dr_cvar",
                                  intervention_penalty=penalty)
        planner = MPCReferencePlanner.from_env(env)
        obs, _ = env.reset(seed=3)
        rewards[penalty] = []
        for _ in range(12):
            action, _ = planner.predict(obs)
            obs, reward, _, _, info = env.step(action)
            rewards[penalty].append((reward, info["filter"]["intervention"]))
    for (r0, i0), (r2, i2) in zip(rewards[0.0], rewards[2.0], strict=True):
        assert i0 == pytest.approx(i2)
        assert r2 == pytest.approx(r0 - 2.0 * i0**2)
    assert any(i > 0 for _, i in rewards[0.0])


def test_bad_arguments_are_named():
    env = gym.make("SafeNav/HeadOn-v0")
    with pytest.raises(InvalidParameterError, match="risk"):
        SafetyFilterWrapper(env, risk="worst")
    with pytest.raises(InvalidParameterError, match="horizon"):
        SafetyFilterWrapper(env, horizon=11)
    with pytest.raises(InvalidParameterError, match="intervention_penalty"):
        SafetyFilterWrapper(env, intervention_penalty=-1.0)
    with pytest.raises(InvalidTypeError, match="FilterableEnv"):
        SafetyFilterWrapper(gym.make("CartPole-v1"))
    with pytest.raises(InvalidTypeError, match="predict"):
        SafetyFilterWrapper(env, policy=object())


def test_render_hook_is_installed_once_and_frames_render():
    env = SafetyFilterWrapper(gym.make("SafeNav/MultiObstacle-v0", render_mode="rgb_array"),
                              risk="dr_cvar")
    planner = MPCReferencePlanner.from_env(env)
    for seed in (0, 1):
        obs, _ = env.reset(seed=seed)
    assert len(env.unwrapped.render_hooks) == 1
    action, _ = planner.predict(obs)
    env.step(action)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3


@pytest.mark.video  # the video extra: pytest -m video
def test_record_video_writes_a_file(tmp_path):
    import moviepy  # noqa: F401
    env = gym.make("SafeNav/HeadOn-v0", render_mode="rgb_array")
    folder = tmp_path / "videos"
    env = gym.wrappers.RecordVideo(SafetyFilterWrapper(env, risk="dr_cvar"), str(folder),
                                   episode_trigger=lambda e: True, disable_logger=True)
    planner = MPCReferencePlanner.from_env(env)
    obs, _ = env.reset(seed=0)
    done = False
    while not done:
        action, _ = planner.predict(obs)
        obs, _, terminated, truncated, _ = env.step(action)
        done = terminated or truncated
    env.close()
    assert list(folder.glob("*.mp4"))


def test_sb3_learns_on_the_filtered_env():
    from stable_baselines3 import PPO

    env = SafetyFilterWrapper(gym.make("SafeNav/RandomCrossing-v0"), risk="dr_cvar",
                              intervention_penalty=0.1)
    model = PPO("MlpPolicy", env, n_steps=256, batch_size=64, n_epochs=1, seed=0,
                device="cpu")
    model.learn(total_timesteps=2048)
    assert model.num_timesteps >= 2048


@pytest.mark.parametrize("risk", ["none", "dr_cvar"])
@pytest.mark.parametrize(("action", "given"), [
    (5.0, "shape ()"),  # was broadcast to both axes
    (np.zeros(3), "shape (3,)"),  # was a raw numpy broadcasting error
    ([1.0], "shape (1,)"),
])
def test_an_action_of_another_shape_is_a_clear_error(risk, action, given):
    env = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), risk=risk)
    env.reset(seed=0)
    before = env.unwrapped.ego_state.copy()
    with pytest.raises(InvalidArrayError, match=re.escape("shape (2,)") + ".*" + re.escape(given)):
        env.step(action)
    assert np.array_equal(env.unwrapped.ego_state, before)  # no step was taken
    with pytest.raises(InvalidArrayError, match="numeric"):
        env.step("fast")

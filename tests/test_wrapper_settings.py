"""SafetyFilterWrapper: settings checked at construction, wrappers in between, defaults."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import ClipAction, RescaleAction

import safe_nav_env  # noqa: F401
from filters import InvalidParameterError, InvalidTypeError, SafetyFilterWrapper
from safe_nav_env import ObstacleSpec, Scenario


@pytest.mark.parametrize(("name", "value"), [
    ("alpha", 2.0), ("alpha", 0.0), ("alpha", -0.1), ("alpha", math.nan),
    ("epsilon", -1.0), ("epsilon", math.nan), ("epsilon", math.inf),
    ("delta", math.nan), ("delta", math.inf),
    ("objective", "tracking"), ("normals", "sideways"), ("fallback", "pray"),
    ("later_input_weight", 0.0), ("stop_time", 0.05), ("intervention_penalty", -1.0),
    ("risk", "worst"), ("horizon", 11), ("horizon", 0), ("horizon", 2.5),
])
def test_bad_settings_raise_at_construction(name, value):
    env = gym.make("SafeNav/HeadOn-v0")
    with pytest.raises(InvalidParameterError, match=name):
        SafetyFilterWrapper(env, **{name: value})


@pytest.mark.parametrize("name", ["intersample", "terminal", "soft"])
def test_flags_must_be_bools(name):
    with pytest.raises(InvalidTypeError, match=name):
        SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), **{name: "yes"})


def test_an_action_wrapper_in_between_is_refused():
    with pytest.raises(InvalidTypeError, match="RescaleAction"):
        SafetyFilterWrapper(RescaleAction(gym.make("SafeNav/HeadOn-v0"), -1.0, 1.0))
    with pytest.raises(InvalidTypeError, match="ClipAction"):
        SafetyFilterWrapper(ClipAction(gym.make("SafeNav/HeadOn-v0")))


def test_rescale_action_outside_maps_to_physical_units():
    env = RescaleAction(SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), risk="none"),
                        -1.0, 1.0)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([0.5, -0.25], dtype=np.float32))
    np.testing.assert_allclose(info["filter"].applied_action, [5.0, -2.5], atol=1e-6)


def _free_path() -> Scenario:
    return Scenario(name="free", ego_start=(-4.0, 0.0, 0.0, 0.0), goal=(4.0, 0.0),
                    obstacles=(ObstacleSpec(start=(0.0, 4.0), velocity=(0.0, 0.0)),),
                    duration=8.0)


def _goal_seeking(obs: np.ndarray) -> np.ndarray:
    """A PD controller to the goal at full acceleration: a fast, unsafe planner."""
    return np.clip(4.0 * obs[4:6] - 2.0 * obs[2:4], -10.0, 10.0)


def test_default_wrapper_reaches_the_goal_on_a_free_path():
    """No deadlock: the default filter (no planner given) lets a free path through."""
    env = SafetyFilterWrapper(gym.make("SafeNav/Custom-v0", scenario=_free_path()))
    obs, info = env.reset(seed=0)
    for _ in range(int(8.0 / 0.2)):
        obs, _, terminated, truncated, info = env.step(_goal_seeking(obs))
        if terminated or truncated:
            break
    assert info["is_success"]
    assert info["filter"].status in ("optimal", "soft", "recovery")


def test_default_wrapper_passes_a_safe_action_unchanged():
    env = SafetyFilterWrapper(gym.make("SafeNav/Custom-v0", scenario=_free_path()))
    env.reset(seed=0)
    action = np.array([1.0, 0.0], dtype=np.float32)
    _, _, _, _, info = env.step(action)
    assert info["filter"].status == "optimal"
    assert info["filter"].intervention <= 1e-6


@pytest.mark.parametrize("bad", [np.array([np.nan, 0.0]), np.array([np.inf, 1.0])])
def test_a_non_finite_action_is_an_error_status_with_braking(bad):
    env = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"))
    env.reset(seed=0)
    _, _, _, _, info = env.step(bad.astype(np.float32))
    report = info["filter"]
    assert report.status == "error" and "finite" in report.error
    assert np.all(np.isfinite(report.applied_action))


def test_nan_predictions_are_an_error_status():
    env = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"))
    env.reset(seed=0)
    base = env.unwrapped
    predictions = np.array(base.predictions)
    predictions[0, 0, 0, 0] = np.nan
    base.predictions = predictions
    _, _, _, _, info = env.step(np.zeros(2, dtype=np.float32))
    assert info["filter"].status == "error"
    assert "samples" in info["filter"].error or "NaN" in info["filter"].error


@pytest.mark.parametrize("normals", ["paper", "ego", "previous_plan"])
def test_every_normal_source_keeps_optimal_plans_inside_the_rows(normals):
    env = SafetyFilterWrapper(gym.make("SafeNav/MultiObstacle-v0"), normals=normals)
    obs, _ = env.reset(seed=2)
    for _ in range(15):
        obs, _, terminated, truncated, info = env.step(_goal_seeking(obs))
        report = info["filter"]
        if report.status == "optimal":
            positions = np.asarray(report.planned_states)[1:, :2]
            violation = np.einsum("itd,td->it", report.normals, positions) - report.offsets
            assert violation.max() <= 1e-5
        if terminated or truncated:
            break

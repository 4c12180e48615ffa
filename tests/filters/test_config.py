"""FilterConfig: its checks, its JSON form, and the wrapper built from it or from keywords."""

from __future__ import annotations

import dataclasses
import json
import math

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401
from filters import (
    FilterConfig,
    InvalidArrayError,
    InvalidParameterError,
    InvalidTypeError,
    SafetyFilterWrapper,
)
from filters.config import FIELDS


@pytest.mark.parametrize(("name", "value", "error"), [
    ("risk", "worst", InvalidParameterError), ("risk", 3, InvalidTypeError),
    ("alpha", 0.0, InvalidParameterError), ("alpha", 1.5, InvalidParameterError),
    ("alpha", math.nan, InvalidParameterError), ("alpha", "big", InvalidParameterError),
    ("delta", -0.1, InvalidParameterError), ("delta", math.nan, InvalidParameterError),
    ("delta", math.inf, InvalidParameterError),
    ("epsilon", -1.0, InvalidParameterError), ("epsilon", math.inf, InvalidParameterError),
    ("epsilon", "automatic", InvalidParameterError),
    ("horizon", 0, InvalidParameterError), ("horizon", 2.5, InvalidParameterError),
    ("horizon", True, InvalidParameterError),
    ("objective", "tracking", InvalidParameterError),
    ("normals", "sideways", InvalidParameterError),
    ("fallback", "pray", InvalidParameterError), ("fallback", None, InvalidTypeError),
    ("later_input_weight", 0.0, InvalidParameterError),
    ("stop_time", 0.0, InvalidParameterError), ("stop_time", math.inf, InvalidParameterError),
    ("intervention_penalty", -1.0, InvalidParameterError),
    ("intersample", "yes", InvalidTypeError), ("terminal", 1, InvalidTypeError),
    ("soft", None, InvalidTypeError), ("draw_halfspaces", "no", InvalidTypeError),
    ("adaptive_epsilon", 0, InvalidTypeError),
    ("Q", [[1.0, math.nan], [0.0, 1.0]], InvalidArrayError), ("R", [1.0, 1.0], InvalidArrayError),
    ("Q_terminal", "diag", InvalidArrayError),
    ("support", (np.eye(2),), InvalidTypeError),
    ("support", (np.eye(2), [1.0, math.inf]), InvalidArrayError),
    ("calibration_episodes", -1, InvalidParameterError),
    ("calibration_seed", 1.5, InvalidParameterError),
    ("calibration_memory", "forever", InvalidParameterError),
])
def test_each_bad_setting_raises_the_project_error_naming_it(name, value, error):
    with pytest.raises(error) as caught:
        FilterConfig(**{name: value})
    message = str(caught.value)
    assert name.split("_")[0] in message
    if isinstance(value, str | float | int):
        assert repr(value) in message or str(value) in message


def test_a_violation_probability_of_one_is_refused_for_the_chance_risks():
    for risk in ("gaussian_cc", "moment_dr", "conformal"):
        with pytest.raises(InvalidParameterError, match=f"alpha .*risk='{risk}'.*got 1.0"):
            FilterConfig(risk=risk, alpha=1.0)
    assert FilterConfig(risk="cvar", alpha=1.0).alpha == 1.0


def test_the_wrapper_refuses_the_same_bad_settings_as_keywords():
    env = gym.make("SafeNav/HeadOn-v0")
    with pytest.raises(InvalidParameterError, match="delta .*got -0.1"):
        SafetyFilterWrapper(env, delta=-0.1)
    with pytest.raises(InvalidTypeError, match=r"unknown filter setting\(s\) \['bogus'\]"):
        SafetyFilterWrapper(env, bogus=1)
    with pytest.raises(InvalidTypeError, match="config must be a FilterConfig"):
        SafetyFilterWrapper(env, 0.2)
    with pytest.warns(DeprecationWarning, match="risk"):  # the old positional risk still works
        assert SafetyFilterWrapper(env, "cvar").risk == "cvar"


def test_the_checks_that_need_the_environment_stay_in_the_wrapper():
    config = FilterConfig(horizon=11, stop_time=0.05)  # fine without an environment
    env = gym.make("SafeNav/HeadOn-v0")  # prediction horizon 10, dt 0.2 s
    with pytest.raises(InvalidParameterError, match=r"horizon .*\[1, 10\].*got 11"):
        SafetyFilterWrapper(env, dataclasses.replace(config, stop_time=0.5))
    with pytest.raises(InvalidParameterError, match=r"stop_time .*\[0.1, inf\).*got 0.05"):
        SafetyFilterWrapper(env, dataclasses.replace(config, horizon=None))


def _odd_config() -> FilterConfig:
    return FilterConfig(risk="cvar", alpha=0.3, delta=0.05, epsilon=0.0, horizon=8,
                        objective="trajectory", later_input_weight=0.02, normals="nearside",
                        fallback="brake", stop_time=0.6, Q=2.0 * np.eye(4),
                        Q_terminal=np.diag([9.0, 9.0, 1.0, 1.0]), R=np.eye(2), soft=True,
                        intervention_penalty=0.01, support=(np.vstack([np.eye(2), -np.eye(2)]),
                                                            np.full(4, 5.0)),
                        calibration_episodes=2, calibration_seed=7,
                        calibration_memory="persistent")


def test_to_dict_is_json_and_from_dict_gives_the_config_back():
    for config in (FilterConfig(), _odd_config(), FilterConfig(risk="conformal", epsilon="auto")):
        data = json.loads(json.dumps(config.to_dict()))
        assert set(data) == set(FIELDS)
        again = FilterConfig.from_dict(data)
        assert again == config and hash(again) == hash(config)
        for name in ("Q", "Q_terminal", "R"):
            value = getattr(again, name)
            assert value is None or (isinstance(value, np.ndarray) and not value.flags.writeable)
    odd = _odd_config()
    assert odd.to_dict()["support"] == [odd.support[0].tolist(), [5.0] * 4]
    assert odd != dataclasses.replace(odd, Q=3.0 * np.eye(4))
    assert FilterConfig.from_dict({"alpha": 0.1}, base=odd) == dataclasses.replace(odd, alpha=0.1)
    with pytest.raises(InvalidTypeError, match="no_such"):
        FilterConfig.from_dict({"no_such": 1})


def _steps(env: gym.Env, n: int) -> list[np.ndarray]:
    """``n`` steps of a PD controller to the goal at full acceleration (fast and unsafe)."""
    obs, _ = env.reset(seed=3)
    applied, intervened = [], False
    for _ in range(n):
        action = np.clip(4.0 * obs[4:6] - 2.0 * obs[2:4], -10.0, 10.0)
        obs, _, terminated, truncated, info = env.step(action)
        applied.append(np.asarray(info["filter"].applied_action))
        intervened = intervened or info["filter"].intervention > 0.1
        if terminated or truncated:
            break
    assert intervened  # the filter changed some action: the comparison means something
    return applied


@pytest.mark.parametrize("settings", [
    {"risk": "dr_cvar"},
    {"risk": "cvar", "alpha": 0.3, "delta": 0.05, "horizon": 8, "fallback": "brake",
     "normals": "nearside", "soft": True, "Q": 2.0 * np.eye(4)},
])
def test_keywords_and_config_give_the_same_wrapper_and_actions(settings):
    by_keywords = SafetyFilterWrapper(gym.make("SafeNav/MultiObstacle-v0"), **settings)
    by_config = SafetyFilterWrapper(gym.make("SafeNav/MultiObstacle-v0"), FilterConfig(**settings))
    assert by_keywords.config == by_config.config == FilterConfig(**settings)
    for name in FIELDS:
        a, b = getattr(by_keywords, name), getattr(by_config, name)
        assert np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b, name
    actions = _steps(by_keywords, 8), _steps(by_config, 8)
    assert len(actions[0]) == 8
    for a, b in zip(*actions, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-9, rtol=0.0)


def test_keywords_override_the_config_and_none_settings_are_resolved():
    base = FilterConfig(risk="cvar", alpha=0.3)
    env = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), base, risk="mean", soft=True)
    assert env.config == dataclasses.replace(base, risk="mean", soft=True)
    assert (env.risk, env.alpha, env.soft) == ("mean", 0.3, True)
    # None in the config: the wrapper's choice, on the wrapper's attributes only
    assert env.config.horizon is None and env.horizon == 10
    assert env.config.objective is None and env.objective == "first_input"
    assert env.config.normals is None and env.normals == "clearest"


def test_the_recorded_constructor_arguments_make_the_wrapper_again():
    config = _odd_config()
    env = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), config)
    recorded = env.spec.additional_wrappers[-1]
    assert recorded.kwargs["config"] == config
    again = gym.make(env.spec)
    assert isinstance(again, SafetyFilterWrapper) and again.config == config

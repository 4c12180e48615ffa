"""One name per scenario across gym ids, SCENARIOS, the CLI and the records."""

from __future__ import annotations

import warnings

import gymnasium as gym
import pytest

import safe_nav_env
from safe_nav_env import (
    ENV_IDS,
    HEAD_ON,
    SCENARIO_NAMES,
    SCENARIOS,
    SCENES,
    SafeNavEnv,
    Scenario,
    ScenarioError,
    ScenarioNameWarning,
    env_id,
    scenario_name,
)


def test_the_canonical_name_is_the_gym_ids():
    assert SCENARIO_NAMES == ("HeadOn", "Overtaking", "Intersection", "MultiObstacle",
                              "RandomCrossing", *SCENES, "Custom")
    assert list(SCENARIOS) == list(SCENARIO_NAMES[:5])
    for name in SCENARIO_NAMES:
        assert env_id(name) in gym.registry
        if name in SCENES:  # an environment of its own
            assert gym.registry[env_id(name)].entry_point == SCENES[name]
            assert env_id(name) not in ENV_IDS
        else:
            assert ENV_IDS[env_id(name)] == (None if name == "Custom" else name)
    for name, scenario in SCENARIOS.items():
        if isinstance(scenario, Scenario):
            assert scenario.name == name
    assert safe_nav_env.random_crossing(__import__("numpy").random.default_rng(0)).name == \
        "RandomCrossing"


@pytest.mark.parametrize("spelling", ["head_on", "SafeNav/HeadOn-v0"])
def test_other_spellings_are_accepted_with_a_warning_naming_the_canonical_one(spelling):
    with pytest.warns(ScenarioNameWarning, match="use 'HeadOn'"):
        assert scenario_name(spelling) == "HeadOn"
    with pytest.warns(ScenarioNameWarning, match="'HeadOn'"):
        assert SCENARIOS[spelling] is HEAD_ON
    assert spelling in SCENARIOS
    with pytest.warns(ScenarioNameWarning):
        env = SafeNavEnv(spelling)
    assert env.scenario is HEAD_ON
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert scenario_name(spelling, warn=False) == "HeadOn"
        assert env_id(spelling) == "SafeNav/HeadOn-v0"
        assert SCENARIOS["HeadOn"] is HEAD_ON
        SafeNavEnv("MultiObstacle")


def test_unknown_names_list_the_canonical_ones():
    with pytest.raises(ScenarioError, match="'Roundabout'.*'HeadOn'"):
        scenario_name("Roundabout")
    assert "Roundabout" not in SCENARIOS and SCENARIOS.get("Roundabout") is None
    with pytest.raises(KeyError):
        SCENARIOS["Roundabout"]
    with pytest.raises(ScenarioError, match="unknown scenario"):
        SafeNavEnv("roundabout")


def test_a_custom_scenario_without_a_length_lasts_ten_seconds():
    scenario = Scenario(name="mine", ego_start=(-4.0, 0.0), goal=(4.0, 0.0),
                        obstacles=[{"start": (0.0, 2.0), "velocity": (0.0, -1.0)}])
    assert scenario.duration == scenario.time_limit == safe_nav_env.scenarios.DEFAULT_DURATION
    assert scenario.time_limit == 10.0
    env = gym.make("SafeNav/Custom-v0", scenario=scenario)
    env.reset(seed=0)
    steps, done = 0, False
    while not done:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample() * 0)
        steps, done = steps + 1, terminated or truncated
    assert steps == 50  # 10 s at 0.2 s, not the 15 steps (3 s) it used to be
    # Given lengths are kept: duration alone is the time limit; episode_length wins.
    assert Scenario(name="x", ego_start=(0, 0), goal=(1, 1), duration=4.0).time_limit == 4.0
    both = Scenario(name="x", ego_start=(0, 0), goal=(1, 1), duration=3.0, episode_length=8.0)
    assert (both.duration, both.time_limit) == (3.0, 8.0)
    only_length = Scenario(name="x", ego_start=(0, 0), goal=(1, 1), episode_length=7.0)
    assert only_length.duration == 7.0

"""Scenario data: the paper's presets, the random family, and validation errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from safe_nav_env import (
    HEAD_ON,
    INTERSECTION,
    MULTI_OBSTACLE,
    OVERTAKING,
    SCENARIOS,
    Gaussian,
    Laplace,
    NoiseModel,
    ObstacleSpec,
    Scenario,
    ScenarioError,
    random_crossing,
    resolve_noise,
)


def test_presets_follow_the_design_table():
    table = {
        "HeadOn": ((-4.7, 0.0), (4.7, 0.0), [((2.0, -0.01), (-1.0, 0.0))], 3.0),
        "Overtaking": ((-4.7, 0.0), (4.7, 0.0), [((-2.0, -0.05), (1.0, 0.0))], 3.0),
        "Intersection": ((-3.5, 1.0), (1.0, -3.0), [((-2.5, -1.0), (1.5, 0.0))], 3.0),
        "MultiObstacle": ((-4.7, -1.0), (4.7, 0.0),
                           [((-1.1, 1.01), (0.7, 0.0)), ((-2.0, -1.01), (1.0, 0.0)),
                            ((-1.0, -2.01), (0.7, 0.0))], 5.0),
    }
    for scenario in (HEAD_ON, OVERTAKING, INTERSECTION, MULTI_OBSTACLE):
        start, goal, obstacles, duration = table[scenario.name]
        assert SCENARIOS[scenario.name] is scenario
        assert scenario.ego_start == (*start, 1.5, 0.0)  # 1.5 m/s along +x
        assert scenario.goal == goal and scenario.duration == duration
        assert [(o.start, o.velocity) for o in scenario.obstacles] == obstacles
        assert scenario.ego_radius == 0.3 and all(o.radius == 0.3 for o in scenario.obstacles)
        assert scenario.noise == NoiseModel(Gaussian(0.01), Laplace(0.01), 100)
        # Long enough to reach the goal at the start speed, unlike the paper's encounter.
        distance = math.dist(start, goal)
        assert scenario.time_limit > distance / 1.5


def test_random_crossing_is_seeded_and_crosses_the_path():
    a, b = random_crossing(np.random.default_rng(5)), random_crossing(np.random.default_rng(5))
    assert a == b
    counts = set()
    for seed in range(40):
        s = random_crossing(np.random.default_rng(seed))
        counts.add(s.n_obstacles)
        start, goal = np.array(s.ego_start[:2]), np.array(s.goal)
        assert s.ego_start[0] == -4.5 and s.goal[0] == 4.5 and 0 <= s.ego_start[2] <= 1.5
        direction = (goal - start) / np.linalg.norm(goal - start)
        for o in s.obstacles:
            assert 0.5 <= o.speed <= 1.5
            v = np.array(o.velocity) / o.speed
            cross = abs(direction[0] * v[1] - direction[1] * v[0])
            assert cross >= math.sin(math.pi / 6) - 1e-9  # crossing angle in [30°, 150°]
            assert np.linalg.norm(np.array(o.start) - start) >= 1.0
    assert counts == {1, 2, 3, 4}


def base(**changes) -> dict:
    data = {"name": "t", "ego_start": (0.0, 0.0), "goal": (1.0, 1.0),
            "obstacles": [{"start": (2.0, 2.0), "velocity": (0.0, 1.0)}]}
    data.update(changes)
    return data


OK = {"start": (2.0, 2.0), "velocity": (0.0, 1.0)}


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"obstacles": [OK, {**OK, "radius": -0.3}]}, r"obstacles\[1\]\.radius must be > 0"),
        ({"obstacles": [{**OK, "start": (math.nan, 0.0)}]},
         r"obstacles\[0\]\.start must be finite"),
        ({"obstacles": [{**OK, "velocity": (1.0, 2.0, 3.0)}]}, r"obstacles\[0\]\.velocity"),
        ({"obstacles": [{**OK, "turn_probability": 1.5}]}, r"obstacles\[0\]\.turn_probability"),
        ({"obstacles": [{**OK, "colour": "red"}]}, r"obstacles\[0\]: unknown field"),
        ({"obstacles": [{"start": (0, 0)}]}, r"obstacles\[0\]: missing field"),
        ({"ego_start": (math.nan, 0.0)}, "ego_start must be finite"),
        ({"ego_start": (0.0, 0.0, 1.0)}, r"ego_start must have shape \(2,\) or \(4,\)"),
        ({"ego_start": (7.0, 0.0)}, "ego_start position .* outside the arena"),
        ({"goal": (6.0, 0.0)}, "goal position .* outside the arena"),
        ({"goal": "home"}, "goal must be a numeric vector"),
        ({"noise": "cauchy"}, "noise: unknown noise preset 'cauchy'"),
        ({"noise": {"reality": {"law": "cauchy"}}}, "noise.reality.law must be one of"),
        ({"noise": {"reality": {"law": "laplace", "covariance": -0.01}}},
         "noise.reality.covariance must be >= 0"),
        ({"noise": {"prediction": {"law": "student_t", "dof": 2.0}}}, "noise.prediction.dof"),
        ({"noise": {"n_samples": 0}}, "noise.n_samples must be >= 1"),
        ({"duration": 0.0}, "duration must be > 0"),
        ({"episode_length": -1.0}, "episode_length must be > 0"),
        ({"ego_radius": -0.3}, "ego_radius must be > 0"),
        ({"arena": ((5, 5), (-5, -5))}, "arena must have x_min < x_max"),
        ({"name": ""}, "name must be a non-empty string"),
    ],
)
def test_bad_scenario_data_names_the_field(changes, message):
    with pytest.raises(ScenarioError, match=message) as excinfo:
        Scenario(**base(**changes))
    assert isinstance(excinfo.value, ValueError)


def test_bad_obstacle_spec_and_laws_directly():
    with pytest.raises(ValueError, match="ObstacleSpec.radius must be > 0"):
        ObstacleSpec(start=(0, 0), velocity=(1, 0), radius=-0.3)
    with pytest.raises(ValueError, match="Gaussian.covariance must be positive semidefinite"):
        Gaussian(((1.0, 2.0), (2.0, 1.0)))
    with pytest.raises(ValueError, match="Laplace.covariance must be symmetric"):
        Laplace(((1.0, 0.5), (0.0, 1.0)))
    with pytest.raises(ValueError, match="noise.reality is for 3 axes"):
        NoiseModel(reality=Gaussian((0.01, 0.01, 0.01)))


def test_scenarios_are_plain_frozen_data():
    scenario = Scenario(**base(noise="authors_code"))
    assert isinstance(scenario.obstacles[0], ObstacleSpec)
    assert scenario.ego_start == (0.0, 0.0, 0.0, 0.0)
    assert scenario.noise.n_samples == 20
    with pytest.raises(AttributeError):
        scenario.goal = (0.0, 0.0)  # type: ignore[misc]
    assert hash(scenario) == hash(Scenario(**base(noise="authors_code")))
    assert resolve_noise({"reality": "gaussian"}).reality == Gaussian(0.01)

"""The goal-reaching check of a planner: counts on a planner that cannot miss, and on one
that never moves; bad settings raise."""

from __future__ import annotations

import numpy as np
import pytest

from agents.experiments.goal_reaching import GOALS, goal_reaching
from filters import InvalidParameterError


class _GoalSeeker:
    """A PD controller to the goal, in m/s² (reaches it from rest in a few steps)."""

    def predict(self, obs, deterministic=True):
        return np.clip(4.0 * obs[4:6] - 3.0 * obs[2:4], -10.0, 10.0).astype(np.float32), None


class _Still:
    def predict(self, obs, deterministic=True):
        return np.zeros(2, dtype=np.float32), None


def test_a_goal_seeker_reaches_every_goal_and_a_still_policy_none():
    good = goal_reaching(_GoalSeeker(), starts=12, max_speed=1.0)
    assert (good.reached, good.starts, good.misses) == (12, 12, ())
    assert 1 <= good.mean_steps <= 40
    still = goal_reaching(_Still(), starts=12)
    assert still.reached == 0 and np.isnan(still.mean_steps)
    assert [goal for goal, _ in still.misses] == [GOALS[i % len(GOALS)] for i in range(12)]
    for goal, start in still.misses:  # at rest, 0.4-1.2 m from the goal
        assert start[2:] == (0.0, 0.0)
        assert 0.4 <= np.hypot(start[0] - goal[0], start[1] - goal[1]) <= 1.2


def test_the_same_seed_gives_the_same_starts():
    a, b = goal_reaching(_Still(), starts=6, seed=3), goal_reaching(_Still(), starts=6, seed=3)
    assert a.misses == b.misses


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"starts": 0}, "starts"), ({"starts": 2.5}, "starts"),
    ({"distance": (0.0, 1.0)}, "goal_distance"), ({"distance": (1.0, 0.5)}, "goal_distance"),
    ({"goals": ((9.0, 0.0),)}, "goal"), ({"max_speed": -1.0}, "max_speed"),
])
def test_bad_settings_raise(kwargs, match):
    with pytest.raises(InvalidParameterError, match=match):
        goal_reaching(_Still(), **kwargs)


class _Broken:
    def predict(self, obs, deterministic=True):
        return np.full(2, np.nan, dtype=np.float32), None


def test_a_failing_policy_raises_with_the_episode_error():
    with pytest.raises(InvalidParameterError, match="_Broken failed from start 0 .*finite"):
        goal_reaching(_Broken(), starts=3)

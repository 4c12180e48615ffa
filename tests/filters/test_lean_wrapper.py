"""The lean filter step: immutable reports, the held-action reference, the cheap norms.

Each piece is checked against the straightforward numpy formula, within tolerances, and
the reports against the property users rely on: a report kept from step k is not
changed by step k + 1 (SB3's DummyVecEnv keeps them; so do loggers).
"""

from __future__ import annotations

import copy

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401
from agents import load_numpy_policy
from agents.planners import MPCReferencePlanner
from filters import InvalidArrayError, SafetyFilterWrapper
from filters.references import hold_action_reference
from filters.wrapper import FilterReport, _distance

ARRAYS = ("proposed_action", "applied_action", "slack", "normals", "offsets",
          "planned_states")


def _snapshot(report: FilterReport) -> dict:
    return {key: np.array(value) if isinstance(value, np.ndarray) else value
            for key, value in report.as_dict().items()}


def _unchanged(report: FilterReport, snapshot: dict) -> None:
    for key, value in snapshot.items():
        now = report[key]
        if isinstance(value, np.ndarray):
            assert np.array_equal(now, value, equal_nan=True), key
        else:
            assert now == value or (now != now and value != value), key  # NaN: itself


@pytest.mark.parametrize("kwargs", [
    {},  # held action, first-input objective
    {"soft": True},  # slack rows reported
    {"policy": "numpy"},  # the numpy actor rolled out, trajectory objective
    {"risk": "none"},  # pass-through
    {"fallback": "paper", "intersample": False},
], ids=["hold", "soft", "rollout", "passthrough", "paper"])
def test_a_report_is_not_changed_by_later_steps(kwargs):
    if kwargs.get("policy") == "numpy":
        kwargs = {**kwargs, "policy": load_numpy_policy()}
    env = SafetyFilterWrapper(gym.make("SafeNav/MultiObstacle-v0"), **kwargs)
    planner = MPCReferencePlanner.from_env(env)
    obs, _ = env.reset(seed=4)
    kept: list[tuple[FilterReport, dict]] = []
    statuses = set()
    for step in range(25):
        action, _ = planner.predict(obs)
        if step == 7 and env.risk != "none":
            action = np.array([np.nan, 0.0])  # an error step among them
        obs, _, terminated, truncated, info = env.step(action)
        report = info["filter"]
        statuses.add(report.status)
        for key in ARRAYS:
            value = report[key]
            if value is not None:
                assert not value.flags.writeable, key
                with pytest.raises(ValueError):
                    value[...] = 0.0
        kept.append((report, _snapshot(report)))
        assert copy.deepcopy(report) is report and copy.copy(report) is report
        assert copy.deepcopy(info)["filter"] == report
        for old, snapshot in kept:
            _unchanged(old, snapshot)
        if terminated or truncated:
            obs, _ = env.reset(seed=5)
    if env.risk != "none":
        assert "error" in statuses and len(statuses) >= 2


def test_report_arrays_are_not_the_filter_s_own():
    """Changing what the halfspaces or the plan hold cannot reach a report, and back."""
    env = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"))
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(2, dtype=np.float32))
    report = info["filter"]
    assert not np.shares_memory(report.normals, env._last_halfspaces.normals)
    assert not np.shares_memory(report.offsets, env._last_halfspaces.offsets)
    assert not np.shares_memory(report.planned_states, env._last_plan)
    assert report.normals.dtype == report.offsets.dtype == np.float64


def _hold_numpy(env, action, horizon):
    """The held-action reference written out with numpy (the readable reference)."""
    A, B, _ = env.dynamics
    low, high = env.input_bounds
    u = np.clip(np.asarray(action, dtype=float), low, high)
    inputs = np.tile(u, (horizon, 1))
    states = np.empty((horizon + 1, A.shape[0]))
    states[0] = env.ego_state
    Bu = B @ inputs[0]
    for k in range(horizon):
        states[k + 1] = A @ states[k] + Bu
    return states, inputs


class _System:
    """A FilterableEnv stand-in with other dynamics (hold_action_reference reads four
    attributes)."""

    def __init__(self, rng, n, m):
        self.dynamics = (rng.standard_normal((n, n)), rng.standard_normal((n, m)), None)
        self.input_bounds = (-np.ones(m), 2.0 * np.ones(m))
        self.ego_state = rng.standard_normal(n)


def test_the_held_action_reference_follows_the_numpy_recursion():
    env = gym.make("SafeNav/RandomCrossing-v0", max_speed=None)  # the plain recursion
    base = env.unwrapped
    rng = np.random.default_rng(3)
    env.reset(seed=0)
    for _ in range(500):  # the double integrator
        base.ego_state = rng.uniform(-8.0, 8.0, 4)
        action = rng.uniform(-15.0, 15.0, 2)
        for horizon in (1, 10, 23):
            fast, slow = hold_action_reference(base, action, horizon), _hold_numpy(
                base, action, horizon)
            np.testing.assert_allclose(fast[0], slow[0], rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(fast[1], slow[1], rtol=0, atol=0)  # the clipped action
    for n, m in ((4, 2), (6, 3), (3, 1)):  # any linear system: to rounding
        system = _System(rng, n, m)
        for _ in range(20):
            action = rng.uniform(-3.0, 3.0, m)
            fast, slow = hold_action_reference(system, action, 8), _hold_numpy(system, action, 8)
            np.testing.assert_allclose(fast[0], slow[0], rtol=1e-12, atol=1e-12)
            assert np.array_equal(fast[1], slow[1])
    states, inputs = hold_action_reference(base, np.ones(2), 0)
    assert np.array_equal(states, base.ego_state[None]) and inputs.shape == (0, 2)
    nan = hold_action_reference(base, np.array([np.nan, 20.0]), 3)
    assert np.all(np.isnan(nan[1][:, 0])) and np.all(nan[1][:, 1] == 10.0)  # as np.clip
    with pytest.raises(InvalidArrayError, match="2 entries"):
        hold_action_reference(base, np.zeros(3), 5)
    with pytest.raises(InvalidArrayError, match="horizon"):
        hold_action_reference(base, np.zeros(2), -1)


def test_the_intervention_norm_equals_numpy_s():
    rng = np.random.default_rng(9)
    for size in (1, 2, 2, 2, 3, 5):
        for _ in range(2000):
            scale = 10.0 ** rng.integers(-8, 4)
            a, b = scale * rng.standard_normal(size), rng.standard_normal(size)
            expected = float(np.linalg.norm(a - b))
            # numpy's norm is sqrt(dot): a BLAS that fuses the multiply-adds of the dot
            # product (numpy 2.4's OpenBLAS does) rounds once less, so the last bit may
            # differ from the plain sum of squares; size 1 has no sum
            if size == 1:
                assert _distance(a, b) == expected
            else:
                assert abs(_distance(a, b) - expected) <= 2 * np.spacing(expected)
    assert np.isnan(_distance(np.array([np.nan, 0.0]), np.zeros(2)))


def test_a_report_built_by_hand_is_immutable_too():
    proposed, applied = np.array([1.0, 2.0]), np.array([0.5, 2.0])
    report = FilterReport("optimal", proposed, applied, intervention=0.5,
                          normals=np.zeros((1, 3, 2)), offsets=np.ones((1, 3)))
    proposed[0] = 9.0  # the caller's arrays stay the caller's
    assert report.proposed_action[0] == 1.0
    assert not report.normals.flags.writeable and not report.applied_action.flags.writeable
    assert copy.deepcopy(report) is report
    assert report == FilterReport("optimal", [1.0, 2.0], [0.5, 2.0], intervention=0.5,
                                  normals=np.zeros((1, 3, 2)), offsets=np.ones((1, 3)))


def test_the_held_action_reference_refuses_shapes_that_do_not_fit():
    system = _System(np.random.default_rng(0), 4, 2)
    system.ego_state = np.zeros(3)
    with pytest.raises(InvalidArrayError, match="do not fit together"):
        hold_action_reference(system, np.zeros(2), 5)
    system = _System(np.random.default_rng(0), 4, 2)
    system.input_bounds = (-np.ones(3), np.ones(3))
    with pytest.raises(InvalidArrayError, match="do not fit together"):
        hold_action_reference(system, np.zeros(2), 5)

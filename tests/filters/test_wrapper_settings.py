"""SafetyFilterWrapper: settings checked at construction, wrappers in between, defaults."""

from __future__ import annotations

import math
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import ClipAction, RescaleAction

import safe_nav_env  # noqa: F401
from filters import InvalidParameterError, InvalidTypeError, SafetyFilterWrapper
from filters.normals import nearside_normals as _nearside_normals
from filters.references import hold_action_reference
from filters.wrapper import clearest_normals
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


@pytest.mark.parametrize(("inner", "order"), [
    (lambda env: RescaleAction(env, -1.0, 1.0),
     "RescaleAction(SafetyFilterWrapper(env), -1.0, 1.0)"),
    (ClipAction, "ClipAction(SafetyFilterWrapper(env))"),
])
def test_the_composition_error_says_which_order_works_and_why(inner, order):
    with pytest.raises(InvalidTypeError) as caught:
        SafetyFilterWrapper(inner(gym.make("SafeNav/HeadOn-v0")), risk="dr_cvar")
    message = str(caught.value)
    assert "put it outside the filter instead, " + order in message
    assert "Why:" in message and "physical units" in message


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


@pytest.mark.parametrize("normals", ["paper", "ego", "nearside", "previous_plan", "clearest"])
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


@pytest.mark.parametrize(("risk", "epsilon"), [("conformal", 0.05), ("dr_cvar", "auto"),
                                               ("gaussian_cc", 0.05), ("moment_dr", 0.05)])
def test_calibrated_and_chance_risks_run_in_the_loop(risk, epsilon):
    env = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), risk=risk, epsilon=epsilon)
    obs, _ = env.reset(seed=0)
    statuses = set()
    for _ in range(12):
        obs, _, terminated, truncated, info = env.step(_goal_seeking(obs))
        statuses.add(info["filter"].status)
        assert np.all(np.isfinite(info["filter"].offsets))
        if terminated or truncated:
            break
    assert "error" not in statuses


def test_conformal_needs_a_probability():
    with pytest.raises(InvalidParameterError, match="alpha"):
        SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), risk="conformal", alpha=1.0)


# ------------------------------------------------------------------ normals="clearest"
def test_default_normals_are_clearest_for_the_held_action_and_paper_for_a_planner():
    assert SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0")).normals == "clearest"

    class Still:
        def predict(self, obs, deterministic=True):
            return np.zeros(2, dtype=np.float32), None

    planned = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), policy=Still())
    assert planned.normals == "paper"


def _instance(rng: np.random.Generator, k: int = 3, T: int = 10):
    means = rng.uniform(-3.0, 3.0, size=(k, T, 2))
    samples = means[:, None] + 0.1 * rng.standard_normal((k, 50, T, 2))
    reference = rng.uniform(-3.0, 3.0, size=(T, 2))
    plan = rng.uniform(-3.0, 3.0, size=(T, 2))
    return samples, reference, rng.uniform(-3.0, 3.0, size=2), plan


def test_clearest_normals_start_at_the_ego_then_at_the_clearer_origin():
    rng = np.random.default_rng(0)
    for _ in range(50):
        samples, reference, ego, plan = _instance(rng)
        normals = clearest_normals(samples, reference, ego, plan)
        means = samples.mean(axis=1)
        np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-12)
        first = means[:, 0] - ego
        np.testing.assert_allclose(normals[:, 0], first / np.linalg.norm(first, axis=-1,
                                                                         keepdims=True))
        d_reference = np.linalg.norm(means - reference, axis=-1)
        d_plan = np.linalg.norm(means - plan, axis=-1)
        origin = np.where((d_reference >= d_plan)[..., None], reference, plan)
        # h . (p - o) = |p - o| = max(d_ref, d_plan): the normal starts at the clearer point
        reach = np.einsum("ktd,ktd->kt", normals, means - origin)
        np.testing.assert_allclose(reach[:, 1:], np.maximum(d_reference, d_plan)[:, 1:],
                                   rtol=1e-12)


def test_clearest_normals_without_a_plan_are_the_nearside_ones_after_the_first_step():
    rng = np.random.default_rng(1)
    samples, reference, ego, _ = _instance(rng)
    np.testing.assert_allclose(clearest_normals(samples, reference, ego)[:, 1:],
                               _nearside_normals(samples, reference, ego)[:, 1:])


def test_clearest_normals_never_degenerate():
    samples = np.zeros((1, 5, 4, 2))  # every sample at the origin
    at_mean = np.zeros((4, 2))
    normals = clearest_normals(samples, at_mean, np.array([0.0, -1.0]), at_mean)
    np.testing.assert_allclose(normals[0], np.tile([0.0, 1.0], (4, 1)))  # from the ego
    normals = clearest_normals(samples, at_mean, np.zeros(2), at_mean)
    np.testing.assert_allclose(normals[0], np.tile([1.0, 0.0], (4, 1)))  # a fixed axis


def test_the_wrapper_takes_the_plan_only_after_an_optimal_step():
    env = SafetyFilterWrapper(gym.make("SafeNav/MultiObstacle-v0"), intersample=False)
    obs, _ = env.reset(seed=2)
    base = env.unwrapped
    checked = {"optimal": 0, "other": 0}
    for _ in range(25):
        previous = env._last_plan, env._plan_optimal
        samples = np.array(base.predictions)
        x0 = np.array(base.ego_state)
        y0 = x0[:2]
        action = _goal_seeking(obs)
        obs, _, terminated, truncated, info = env.step(action)
        report = info["filter"]
        if report.status == "error":
            break
        before = SimpleNamespace(dynamics=base.dynamics, input_bounds=base.input_bounds,
                                 ego_state=x0, applied_input=base.applied_input)
        reference, _ = hold_action_reference(before, report.proposed_action, env.horizon)
        plan = None
        if previous[0] is not None and previous[1]:
            plan = np.concatenate([previous[0][2:, :2], previous[0][-1:, :2]]) \
                - previous[0][1, :2] + y0
        expected = clearest_normals(samples, reference[1:, :2], y0, plan)
        np.testing.assert_allclose(report.normals, expected, atol=1e-9)
        checked["optimal" if plan is not None else "other"] += 1
        if terminated or truncated:
            break
    assert checked["optimal"] > 0 and checked["other"] > 0

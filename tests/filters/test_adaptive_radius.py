"""The adaptive Wasserstein radius: DR-CVaR scores, conformal quantile with ACI, wrapper."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401  (registers the ids)
from filters import SafetyFilterWrapper, safe_halfspaces
from filters.calibration import AdaptiveRadius, OnlineCalibration, Realisation, dr_cvar_scores
from filters.errors import InvalidArrayError, InvalidParameterError, InvalidTypeError
from filters.geometry import Disc
from filters.risk import empirical_cvar
from filters.wrapper import calibration_settings

HORIZON = 3
N_SAMPLES = 100
SIGMA = 0.1  # predicted spread per axis, m


def _realisations(rng: np.random.Generator, ratio: float, n_obs: int = 3) -> list[Realisation]:
    """One step's realisations: predicted errors N(0, SIGMA^2 I), realised ``ratio`` x wider."""
    out = []
    for k in range(1, HORIZON + 1):
        own = SIGMA * rng.standard_normal((n_obs, N_SAMPLES, 2))
        own -= own.mean(axis=1, keepdims=True)  # errors around the sample mean
        errors = ratio * SIGMA * rng.standard_normal((n_obs, 2))
        scores = np.linalg.norm(errors, axis=1)
        out.append(Realisation(k, 0, errors, scores, own, N_SAMPLES))
    return out


def _feed(radius: AdaptiveRadius, rng: np.random.Generator, ratio: float, steps: int) -> None:
    for _ in range(steps):
        radius.update(_realisations(rng, ratio))


# --------------------------------------------------------------------------- scores


def test_scores_bound_the_realised_projection_for_every_normal_and_are_tight():
    rng = np.random.default_rng(0)
    errors = 0.2 * rng.standard_normal((20, 2))
    own = 0.1 * rng.standard_normal((20, 50, 2)) * np.array([1.0, 2.0])
    scores = dr_cvar_scores(errors, own, 0.2, n_directions=64)
    angles = np.linspace(0.0, 2.0 * np.pi, 20_000, endpoint=False)
    u = np.stack([np.cos(angles), np.sin(angles)], axis=-1)  # u = -h, dense
    gaps = errors @ u.T - empirical_cvar(np.einsum("md,ojd->omj", u, own), 0.2)
    dense = np.maximum(gaps.max(axis=1), 0.0)
    # An upper bound on the supremum (the defining property), within its grid slack.
    assert np.all(scores >= dense - 1e-12)
    lipschitz = np.linalg.norm(errors, axis=1) + empirical_cvar(np.linalg.norm(own, axis=2), 0.2)
    assert np.all(scores - dense <= 2.0 * math.sin(math.pi / 128) * lipschitz + 1e-12)
    # With radius alpha * s, the DR-CVaR bound holds at the realised position for any h.
    for i in range(20):
        h = -u[rng.integers(len(u))]
        bound = empirical_cvar(-own[i] @ h, 0.2) + scores[i]
        assert -h @ errors[i] <= bound + 1e-12


def test_scores_in_one_dimension_are_exact_and_zero_inside_the_cvar_bounds():
    own = np.array([[[-1.0], [0.0], [1.0], [2.0], [-2.0]]])  # CVaR_0.2 of +-xi: 2
    assert dr_cvar_scores(np.array([[1.5]]), own, 0.2)[0] == 0.0
    assert dr_cvar_scores(np.array([[3.0]]), own, 0.2)[0] == pytest.approx(1.0, abs=1e-12)
    assert dr_cvar_scores(np.array([[-2.5]]), own, 0.2)[0] == pytest.approx(0.5, abs=1e-12)


def test_scores_reject_bad_input():
    with pytest.raises(InvalidArrayError, match="predicted_errors must have shape"):
        dr_cvar_scores(np.zeros((2, 2)), np.zeros((3, 5, 2)), 0.2)
    with pytest.raises(InvalidArrayError, match="d = 3"):
        dr_cvar_scores(np.zeros((1, 3)), np.zeros((1, 5, 3)), 0.2)
    with pytest.raises(InvalidArrayError, match="finite"):
        dr_cvar_scores(np.array([[np.nan, 0.0]]), np.zeros((1, 5, 2)), 0.2)
    with pytest.raises(InvalidParameterError, match="alpha"):
        dr_cvar_scores(np.zeros((1, 2)), np.zeros((1, 5, 2)), 0.0)
    with pytest.raises(InvalidParameterError, match="n_directions"):
        dr_cvar_scores(np.zeros((1, 2)), np.zeros((1, 5, 2)), 0.2, n_directions=2)
    with pytest.raises(InvalidParameterError, match="miscoverage"):
        AdaptiveRadius(1.0, horizon=2)


# --------------------------------------------------------------------------- both directions


def test_radius_widens_when_the_realised_spread_is_twice_the_predicted():
    rng = np.random.default_rng(1)
    radius = AdaptiveRadius(0.2, horizon=HORIZON)
    assert np.all(radius.radii() == 0.05)  # the fallback before any data
    _feed(radius, rng, 1.0, 100)  # predictions right: the calibrated state
    matched = radius.radii()
    _feed(radius, rng, 2.0, 100)  # then the noise doubles: 300 new scores per look-ahead
    doubled = radius.radii()
    assert np.all(doubled > 2.0 * matched), (matched, doubled)
    assert np.all(doubled > 0.05)  # wider than the paper's hand-tuned radius
    # ACI saw more errors than alpha while the window caught up: levels below alpha.
    assert np.all(radius.scores.levels < 0.2)


def test_radius_stays_small_or_shrinks_when_the_predictions_match():
    rng = np.random.default_rng(2)
    radius = AdaptiveRadius(0.2, horizon=HORIZON)
    _feed(radius, rng, 1.0, 100)
    first = radius.radii()
    assert np.all(first < 0.05)  # narrower than the paper's radius when predictions are right
    _feed(radius, rng, 1.0, 100)
    assert np.all(radius.radii() < 1.3 * first) and np.all(radius.radii() < 0.05)
    # After a wide spell, matched data brings the radius back down.
    _feed(radius, rng, 2.0, 100)
    wide = radius.radii()
    _feed(radius, rng, 1.0, 100)
    assert np.all(radius.radii() < 0.5 * wide), (wide, radius.radii())
    assert np.all(radius.radii() < 0.05)


def test_a_floor_makes_the_radius_widen_only():
    rng = np.random.default_rng(5)
    free = AdaptiveRadius(0.2, horizon=HORIZON)
    floored = AdaptiveRadius(0.2, horizon=HORIZON, floor=0.03)
    for ratio in (1.0, 2.0, 1.0):
        state = rng.bit_generator.state
        _feed(free, rng, ratio, 100)
        rng.bit_generator.state = state
        _feed(floored, rng, ratio, 100)
        np.testing.assert_array_equal(floored.radii(), np.maximum(free.radii(), 0.03))
        if ratio == 2.0:
            assert np.all(floored.radii() > 0.03)  # widened above the floor
    assert np.all(floored.radii() == 0.03)  # back down to the floor, not below
    with pytest.raises(InvalidParameterError, match="floor"):
        AdaptiveRadius(0.2, horizon=2, floor=-0.1)


def test_coverage_of_the_radius_is_near_its_miscoverage_on_exchangeable_data():
    rng = np.random.default_rng(3)
    radius = AdaptiveRadius(0.2, horizon=HORIZON, gamma=0.0)
    _feed(radius, rng, 2.0, 200)
    # Each score is covered by the radius in force when it arrived: the fraction
    # exceeded is close to 0.2 (split conformal over a 200-score window).
    exceeded = radius.scores.n_exceeded / radius.scores.n_scored
    assert np.all(np.abs(exceeded - 0.2) < 0.05), exceeded


# --------------------------------------------------------------------------- the wrapper


def test_online_calibration_feeds_the_adaptive_radius_and_keeps_the_wasserstein_input():
    env = gym.make("SafeNav/HeadOn-v0")
    base = env.unwrapped
    plain = OnlineCalibration(10, 0.2)
    adaptive = OnlineCalibration(10, 0.2, adaptive_alpha=0.2)
    with pytest.raises(InvalidParameterError, match="adaptive_alpha"):
        plain.adaptive_radii()
    base.reset(seed=0)
    for _ in range(15):
        for calibration in (plain, adaptive):
            calibration.update(base.predictions[:, :, :10], base.obstacle_positions)
        base.step(np.zeros(2, dtype=np.float32))
    assert np.array_equal(plain.radii(), adaptive.radii())  # epsilon="auto" unchanged
    assert np.array_equal(plain.margins(), adaptive.margins())
    radii = adaptive.adaptive_radii()
    assert radii.shape == (10,) and np.all(radii >= 0.0) and np.all(np.isfinite(radii))


def test_wrapper_uses_the_adaptive_radii_in_its_halfspaces():
    env = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), adaptive_epsilon=True,
                              epsilon=0.0, calibration_episodes=2)  # no floor
    assert env.adaptive_epsilon and env.calibration_episodes == 2
    env.reset(seed=0)
    base = env.unwrapped
    for _ in range(3):
        radii = env._calibration.adaptive_radii()  # in force for this step
        samples = np.array(base.predictions[:, :, :10])
        _, _, _, _, info = env.step(np.zeros(2))
    assert np.all(radii > 0.0)  # calibrated from step 0, not the fallback (0)
    assert np.all(np.diff(radii) > -0.02)  # wider further ahead (errors grow along the lane)
    # b = -(CVaR_a(-h.p) + eps_k / a) + delta - r for the reported normals h.
    report = info["filter"]
    losses = -np.einsum("okd,ojkd->okj", report.normals, samples)
    expected = -(empirical_cvar(losses, 0.2) + radii / 0.2) + 0.1 - 0.6
    np.testing.assert_allclose(report.offsets, expected, atol=1e-9)


def test_adaptive_option_settings_and_validation():
    assert calibration_settings("dr_cvar", 0.05, adaptive_epsilon=True) is not None
    assert calibration_settings("dr_cvar", 0.05) is None
    assert calibration_settings("cvar", 0.05, adaptive_epsilon=True) is None
    assert calibration_settings("none", 0.05, adaptive_epsilon=True) is None
    cvar = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), risk="cvar",
                               adaptive_epsilon=True)
    assert not cvar.adaptive_epsilon and cvar._calibration is None  # ignored, documented
    auto = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), epsilon="auto",
                               adaptive_epsilon=True, calibration_episodes=0)
    assert not auto.adaptive_epsilon and auto._calibration.adaptive is None
    with pytest.raises(InvalidTypeError, match="adaptive_epsilon"):
        SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), adaptive_epsilon="yes")


def test_radii_reach_safe_halfspaces_as_per_step_epsilon():
    rng = np.random.default_rng(4)
    radius = AdaptiveRadius(0.2, horizon=HORIZON)
    _feed(radius, rng, 2.0, 50)
    samples = 2.0 + SIGMA * rng.standard_normal((1, N_SAMPLES, HORIZON, 2))
    reference = np.zeros((HORIZON, 2))
    shapes = dict(ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.3)])
    adaptive = safe_halfspaces(reference, samples, epsilon=radius.radii(), **shapes)
    for k, value in enumerate(radius.radii()):
        fixed = safe_halfspaces(reference, samples, epsilon=float(value), **shapes)
        assert adaptive.offsets[0, k] == pytest.approx(fixed.offsets[0, k], abs=1e-9)

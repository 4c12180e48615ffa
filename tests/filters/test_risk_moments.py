"""The risks beyond the paper: gaussian_cc, moment_dr, conformal, and per-step epsilon."""

from __future__ import annotations

import math

import cvxpy as cp
import numpy as np
import pytest
from scipy import stats

from filters import Disc, safe_halfspaces
from filters.errors import InvalidArrayError, InvalidParameterError
from filters.halfspace_cvxpy import cvxpy_halfspace
from filters.risk import (
    CHANCE_RISKS,
    RISKS,
    cantelli_factor,
    empirical_cvar,
    gaussian_factor,
    risk_value,
)


def _instance(seed: int, n_obstacles: int = 3, n_samples: int = 40, horizon: int = 5):
    rng = np.random.default_rng(seed)
    y_ref = rng.uniform(-2, 2, size=(horizon, 2))
    centres = rng.uniform(-3, 3, size=(n_obstacles, 1, horizon, 2))
    scales = rng.uniform(0.05, 0.5, size=(n_obstacles, 1, 1, 2))
    mixing = rng.normal(size=(2, 2))
    samples = centres + (rng.normal(size=(n_obstacles, n_samples, horizon, 2)) * scales) @ mixing
    shapes = [Disc(float(r)) for r in rng.uniform(0.1, 0.5, size=n_obstacles)]
    return y_ref, samples, shapes


def _halfspaces(y_ref, samples, shapes, **kwargs):
    return safe_halfspaces(y_ref, samples, ego_shape=Disc(0.3), obstacle_shapes=shapes, **kwargs)


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("alpha", [0.01, 0.05, 0.2, 0.5, 0.8])
def test_gaussian_cc_equals_the_scipy_quantile_of_the_fitted_gaussian(seed, alpha):
    y_ref, samples, shapes = _instance(seed)
    delta = 0.1
    hs = _halfspaces(y_ref, samples, shapes, risk="gaussian_cc", alpha=alpha, delta=delta)
    for i, shape in enumerate(shapes):
        for t in range(y_ref.shape[0]):
            h = hs.normals[i, t]
            points = samples[i, :, t]
            sigma = np.cov(points.T)  # unbiased (N - 1), the documented choice
            quantile = stats.norm.ppf(1 - alpha, loc=-h @ points.mean(axis=0),
                                      scale=math.sqrt(h @ sigma @ h))
            expected = -(quantile - delta + shape.radius + 0.3)
            assert hs.offsets[i, t] == pytest.approx(expected, abs=1e-10)


def _worst_exceedance_lp(mean: float, std: float, threshold: float, atoms: list[float]) -> float:
    """max P(x >= threshold) over laws on a grid with the given mean and variance (CVXPY LP)."""
    grid = np.unique(np.concatenate([np.linspace(mean - 8 * std, mean + 8 * std, 801), atoms]))
    w = cp.Variable(grid.size, nonneg=True)
    constraints = [cp.sum(w) == 1, grid @ w == mean, (grid - mean) ** 2 @ w == std**2]
    problem = cp.Problem(cp.Maximize(cp.sum(w[grid >= threshold - 1e-12])), constraints)
    problem.solve(solver=cp.CLARABEL)
    return float(problem.value)


@pytest.mark.parametrize("alpha", [0.05, 0.2, 0.4])
def test_moment_dr_is_the_worst_case_quantile_over_all_laws_with_those_moments(alpha):
    # The moment_dr value R satisfies sup_P P(x >= R) = alpha over every law with the
    # sample mean and variance (Cantelli is tight): checked with a CVXPY moment LP.
    x = np.random.default_rng(7).laplace(size=60)
    mean, std = float(np.mean(x)), float(np.std(x, ddof=1))
    value = float(risk_value(x, "moment_dr", alpha))
    assert value == pytest.approx(mean + math.sqrt((1 - alpha) / alpha) * std, rel=1e-12)
    low_atom = mean - std * math.sqrt(alpha / (1 - alpha))  # the extremal two-point law
    worst = _worst_exceedance_lp(mean, std, value, [value, low_atom])
    assert worst == pytest.approx(alpha, abs=1e-6)
    # Any smaller threshold is exceeded with probability above alpha by some law.
    assert _worst_exceedance_lp(mean, std, value - 0.05 * std, [value - 0.05 * std]) > alpha + 1e-3


@pytest.mark.parametrize("seed", range(4))
def test_chance_offsets_are_ordered_as_the_theory_says(seed):
    y_ref, samples, shapes = _instance(seed, n_samples=25)
    for alpha in (0.01, 0.1, 0.2, 0.3, 0.45):
        b = {risk: _halfspaces(y_ref, samples, shapes, risk=risk, alpha=alpha).offsets
             for risk in ("mean", "gaussian_cc", "moment_dr")}
        assert np.all(b["moment_dr"] <= b["gaussian_cc"] + 1e-12)  # Cantelli more conservative
        assert np.all(b["gaussian_cc"] <= b["mean"] + 1e-12)
        assert cantelli_factor(alpha) >= gaussian_factor(alpha)
    for alpha in (0.5, 0.7, 0.95):  # z_{1-alpha} <= 0: the Gaussian fit is at or past the mean
        gauss = _halfspaces(y_ref, samples, shapes, risk="gaussian_cc", alpha=alpha).offsets
        mean = _halfspaces(y_ref, samples, shapes, risk="mean").offsets
        assert np.all(gauss >= mean - 1e-12)


def test_chance_offsets_shrink_as_alpha_shrinks():
    y_ref, samples, shapes = _instance(11)
    for risk in CHANCE_RISKS:
        offsets = [_halfspaces(y_ref, samples, shapes, risk=risk, alpha=a).offsets
                   for a in (0.4, 0.2, 0.1, 0.01)]
        for looser, tighter in zip(offsets, offsets[1:], strict=False):
            assert np.all(tighter < looser)


def test_factors_match_scipy():
    for alpha in (1e-6, 0.01, 0.2, 0.5, 0.9):
        # isf(alpha) = ppf(1 - alpha) without the rounding of 1 - alpha in the far tail
        assert gaussian_factor(alpha) == pytest.approx(stats.norm.isf(alpha), rel=1e-12,
                                                       abs=1e-15)
        assert gaussian_factor(alpha) == pytest.approx(stats.norm.ppf(1 - alpha), rel=1e-9)
        assert cantelli_factor(alpha) == pytest.approx(math.sqrt(1 / alpha - 1), rel=1e-12)


@pytest.mark.parametrize("risk", CHANCE_RISKS)
def test_a_single_sample_has_zero_spread_so_the_chance_risks_reduce_to_the_mean(risk):
    y_ref, samples, shapes = _instance(2, n_samples=1)
    chance = _halfspaces(y_ref, samples, shapes, risk=risk, alpha=0.1).offsets
    mean = _halfspaces(y_ref, samples, shapes, risk="mean").offsets
    np.testing.assert_allclose(chance, mean, rtol=0, atol=1e-12)


@pytest.mark.parametrize("risk", CHANCE_RISKS)
def test_alpha_one_is_rejected_for_chance_constraints_and_named(risk):
    x = np.random.default_rng(0).normal(size=10)
    with pytest.raises(InvalidParameterError, match="alpha") as info:
        risk_value(x, risk, 1.0)
    assert risk in str(info.value)
    y_ref, samples, shapes = _instance(0)
    with pytest.raises(InvalidParameterError, match="alpha"):
        _halfspaces(y_ref, samples, shapes, risk=risk, alpha=1.0)
    for bad in (0.0, -0.1, 1.5, math.nan):
        with pytest.raises(InvalidParameterError, match="alpha"):
            risk_value(x, risk, bad)
    assert float(risk_value(x, "cvar", 1.0)) == pytest.approx(np.mean(x))  # CVaR keeps (0, 1]


def test_risk_value_moments_use_the_unbiased_std():
    x = np.random.default_rng(5).normal(size=(3, 17))
    z = stats.norm.ppf(0.9)
    np.testing.assert_allclose(risk_value(x, "gaussian_cc", 0.1),
                               x.mean(-1) + z * x.std(-1, ddof=1), rtol=1e-12)
    np.testing.assert_allclose(risk_value(x.T, "moment_dr", 0.1, axis=0),
                               x.mean(-1) + 3.0 * x.std(-1, ddof=1), rtol=1e-12)


# --------------------------------------------------------------------------- conformal


def test_conformal_offsets_are_the_mean_offsets_minus_the_margins():
    y_ref, samples, shapes = _instance(3)
    n, horizon = samples.shape[0], samples.shape[2]
    mean = _halfspaces(y_ref, samples, shapes, risk="mean").offsets
    margins = np.linspace(0.05, 0.5, horizon)
    for given, expected in (
        (margins, mean - margins),
        (0.2, mean - 0.2),
        (np.outer(np.arange(1, n + 1), margins), mean - np.outer(np.arange(1, n + 1), margins)),
    ):
        hs = _halfspaces(y_ref, samples, shapes, risk="conformal", conformal_margins=given)
        np.testing.assert_allclose(hs.offsets, expected, rtol=0, atol=1e-12)


def test_conformal_margin_bounds_the_realised_loss_for_every_normal():
    # -h.p <= -h.mu + ||p - mu|| for every unit h: the score the calibration uses.
    rng = np.random.default_rng(8)
    for _ in range(200):
        points = rng.normal(size=(30, 2))
        realised = rng.normal(size=2) * 2
        mu = points.mean(axis=0)
        h = rng.normal(size=2)
        h /= np.linalg.norm(h)
        score = np.linalg.norm(realised - mu)
        bound = float(risk_value(-points @ h, "conformal", 0.2, margin=score))
        assert -h @ realised <= bound + 1e-12


def test_conformal_requires_valid_margins():
    y_ref, samples, shapes = _instance(4)
    with pytest.raises(InvalidParameterError, match="conformal_margins"):
        _halfspaces(y_ref, samples, shapes, risk="conformal")
    horizon = samples.shape[2]
    for bad in (np.full(horizon, -0.1), np.full(horizon, np.inf), np.zeros(horizon + 1),
                np.zeros((2, horizon, 1))):
        with pytest.raises(InvalidArrayError, match="conformal_margins"):
            _halfspaces(y_ref, samples, shapes, risk="conformal", conformal_margins=bad)
    with pytest.raises(InvalidParameterError, match="margin"):
        risk_value(np.ones(3), "conformal", 0.2)


# --------------------------------------------------------------------------- epsilon per step


@pytest.mark.parametrize("support", [None, "box"])
def test_dr_cvar_with_one_epsilon_per_step_equals_scalar_calls(support):
    y_ref, samples, shapes = _instance(6)
    horizon = samples.shape[2]
    polytope = None
    if support == "box":
        bound = float(np.abs(samples).max()) + 0.5
        polytope = (np.vstack([np.eye(2), -np.eye(2)]), np.full(4, bound))
    epsilons = np.linspace(0.0, 0.2, horizon)
    hs = _halfspaces(y_ref, samples, shapes, risk="dr_cvar", epsilon=epsilons, support=polytope)
    assert not hs.epsilon.flags.writeable
    for t, eps in enumerate(epsilons):
        single = _halfspaces(y_ref, samples, shapes, risk="dr_cvar", epsilon=float(eps),
                             support=polytope)
        np.testing.assert_allclose(hs.offsets[:, t], single.offsets[:, t], rtol=0, atol=1e-12)


def test_dr_cvar_epsilon_array_is_validated():
    y_ref, samples, shapes = _instance(6)
    horizon = samples.shape[2]
    for bad in (np.zeros(horizon + 1), np.full(horizon, -0.01), np.full(horizon, np.nan)):
        with pytest.raises(InvalidArrayError, match="epsilon"):
            _halfspaces(y_ref, samples, shapes, risk="dr_cvar", epsilon=bad)
    x = np.random.default_rng(1).normal(size=(4, 9))
    np.testing.assert_allclose(risk_value(x, "dr_cvar", 0.2, np.arange(4) * 0.1),
                               empirical_cvar(x, 0.2) + np.arange(4) * 0.1 / 0.2)


@pytest.mark.parametrize("risk", [r for r in RISKS if r not in ("mean", "cvar", "dr_cvar")])
def test_the_cvxpy_reference_refuses_the_risks_it_does_not_formulate(risk):
    with pytest.raises(InvalidParameterError, match="risk"):
        cvxpy_halfspace(np.zeros((3, 2)), np.array([1.0, 0.0]), 0.6, risk=risk)

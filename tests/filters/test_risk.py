"""Empirical CVaR and the risk metrics of :mod:`filters.risk`."""

from __future__ import annotations

import math

import numpy as np
import pytest

from filters.errors import InvalidArrayError, InvalidParameterError, InvalidTypeError
from filters.risk import RISKS, check_alpha, empirical_cvar, risk_value, tail_count


def cvar_by_minimisation(x: np.ndarray, alpha: float) -> float:
    """:math:`\\min_\\tau \\tau + \\mathrm{mean}((x - \\tau)_+)/\\alpha`, exactly.

    The objective is convex and piecewise linear in tau with kinks at the
    samples, so its minimum is attained at one of them.
    """
    x = np.asarray(x, dtype=float)
    taus = x[:, None]
    values = taus[:, 0] + np.mean(np.maximum(x[None, :] - taus, 0.0), axis=1) / alpha
    return float(np.min(values))


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("alpha", [0.01, 0.1, 0.2, 0.37, 0.5, 0.9, 1.0])
def test_cvar_equals_the_minimisation_formula(seed, alpha):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 80))
    x = rng.normal(size=n) * rng.uniform(0.1, 10)
    expected = cvar_by_minimisation(x, alpha)
    assert empirical_cvar(x, alpha) == pytest.approx(expected, rel=1e-12, abs=1e-12)


def test_cvar_with_fractional_atom_by_hand():
    # alpha N = 1.2: the largest sample with weight 1 and the next with weight 0.2.
    assert empirical_cvar([1.0, 2.0, 3.0, 4.0], 0.3) == pytest.approx((4.0 + 0.2 * 3.0) / 1.2)


@pytest.mark.parametrize("alpha, n", [(0.2, 50), (0.1, 30), (0.7, 10), (0.3, 10), (0.05, 60)])
def test_cvar_when_alpha_n_is_an_integer_in_exact_arithmetic(alpha, n):
    x = np.random.default_rng(n).normal(size=n)
    k = round(alpha * n)
    expected = np.mean(np.sort(x)[::-1][:k])
    assert empirical_cvar(x, alpha) == pytest.approx(expected, rel=1e-13)


@pytest.mark.parametrize(
    "alpha, n, mass", [(0.57, 100, 57.0), (0.29, 100, 29.0), (0.57, 1500, 855.0)]
)
def test_tail_count_snaps_rounding_error(alpha, n, mass):
    assert alpha * n != mass  # binary floating point misses the integer...
    assert tail_count(alpha, n) == mass  # ...and the snap restores it


def test_cvar_alpha_one_is_exactly_the_mean_and_tiny_alpha_the_max():
    x = np.random.default_rng(0).normal(size=(4, 33))
    np.testing.assert_array_equal(empirical_cvar(x, 1.0), np.mean(x, axis=-1))
    np.testing.assert_allclose(empirical_cvar(x, 1e-6), np.max(x, axis=-1))


def test_cvar_is_vectorised_over_other_axes():
    x = np.random.default_rng(1).normal(size=(3, 17, 4))
    result = empirical_cvar(x, 0.25, axis=1)
    assert result.shape == (3, 4)
    for i in range(3):
        for j in range(4):
            assert result[i, j] == pytest.approx(cvar_by_minimisation(x[i, :, j], 0.25), rel=1e-12)


def test_cvar_does_not_reorder_its_input():
    x = np.random.default_rng(2).normal(size=40)
    copy = x.copy()
    empirical_cvar(x, 0.2)
    np.testing.assert_array_equal(x, copy)


@pytest.mark.parametrize("alpha", [0.0, -0.2, 1.5, math.nan, math.inf, "a"])
def test_cvar_rejects_alpha_outside_unit_interval(alpha):
    with pytest.raises(InvalidParameterError, match="alpha"):
        empirical_cvar(np.ones(5), alpha)


def test_cvar_rejects_bad_samples():
    with pytest.raises(InvalidArrayError, match="x"):
        empirical_cvar(np.array([1.0, np.nan]), 0.5)
    with pytest.raises(InvalidArrayError, match="sample"):
        empirical_cvar(np.zeros((3, 0)), 0.5)
    with pytest.raises(InvalidArrayError, match="axis"):
        empirical_cvar(np.zeros((3, 2)), 0.5, axis=4)


def test_risk_values_follow_the_closed_forms():
    x = np.random.default_rng(3).normal(size=(2, 57))
    np.testing.assert_allclose(risk_value(x, "mean", 0.2, 0.05), np.mean(x, axis=-1))
    cvar = empirical_cvar(x, 0.2)
    np.testing.assert_allclose(risk_value(x, "cvar", 0.2, 0.05), cvar)
    np.testing.assert_allclose(risk_value(x, "dr_cvar", 0.2, 0.05), cvar + 0.05 / 0.2)
    np.testing.assert_allclose(risk_value(x.T, "cvar", 0.2, 0.0, axis=0), cvar)


@pytest.mark.parametrize("risk", RISKS)
def test_risk_metrics_are_translation_equivariant(risk):
    x = np.random.default_rng(4).normal(size=41)
    margin = 0.2 if risk == "conformal" else None
    shifted = risk_value(x + 2.5, risk, 0.3, 0.1, margin=margin)
    assert shifted == pytest.approx(risk_value(x, risk, 0.3, 0.1, margin=margin) + 2.5, rel=1e-13)


def test_risk_value_rejects_unknown_risk_and_names_the_choices():
    with pytest.raises(InvalidParameterError, match="risk") as info:
        risk_value(np.ones(3), "var", 0.2, 0.05)
    assert "var" in str(info.value) and "dr_cvar" in str(info.value)
    with pytest.raises(InvalidTypeError, match="risk"):
        risk_value(np.ones(3), 3, 0.2, 0.05)


@pytest.mark.parametrize("epsilon", [-0.01, math.nan, math.inf])
def test_risk_value_rejects_bad_epsilon(epsilon):
    with pytest.raises(InvalidParameterError, match="epsilon"):
        risk_value(np.ones(3), "dr_cvar", 0.2, epsilon)


def test_risk_value_rejects_bad_losses():
    with pytest.raises(InvalidArrayError, match="losses"):
        risk_value(np.array([np.inf, 1.0]), "mean", 0.2, 0.05)
    with pytest.raises(InvalidArrayError, match="losses"):
        risk_value(np.zeros(0), "mean", 0.2, 0.05)


@pytest.mark.parametrize("value", [True, np.bool_(False), "0.2", b"0.2"])
def test_a_bool_or_string_is_not_a_number(value):
    with pytest.raises(InvalidParameterError, match="alpha must be a real number"):
        check_alpha(value)

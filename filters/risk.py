"""Empirical risk metrics of sampled losses: mean, CVaR and Wasserstein DR-CVaR.

Conventions (see ``DESIGN.md`` section 1): a *loss* is bad when large, and
``alpha`` is the tail mass, so :math:`\\mathrm{CVaR}_\\alpha` averages the worst
``alpha`` fraction of the samples; ``alpha = 1`` gives the mean. All three
metrics are translation equivariant, :math:`R(x + c) = R(x) + c`, which is what
turns Definition 2 of the paper into closed forms (see :mod:`filters.halfspaces`).
"""

from __future__ import annotations

import math

import numpy as np

from filters._validation import finite_array, scalar_in_range
from filters.errors import InvalidArrayError, InvalidParameterError, InvalidTypeError

__all__ = ["RISKS", "check_risk", "empirical_cvar", "risk_value"]

#: Names of the risk metrics understood by :func:`risk_value` and ``safe_halfspaces``.
RISKS: tuple[str, ...] = ("mean", "cvar", "dr_cvar")


def check_risk(risk: object) -> str:
    """Return ``risk`` if it names a known metric.

    Raises
    ------
    InvalidTypeError
        If ``risk`` is not a string.
    InvalidParameterError
        If ``risk`` is not one of :data:`RISKS`.
    """
    if isinstance(risk, str) and risk in RISKS:
        return risk
    if not isinstance(risk, str):
        raise InvalidTypeError(f"risk must be a string, one of {RISKS}, got {risk!r}")
    if risk not in RISKS:
        raise InvalidParameterError(f"risk must be one of {RISKS}, got {risk!r}")
    return risk


def check_alpha(alpha: object) -> float:
    """Return ``alpha`` as a float in :math:`(0, 1]`, or raise ``InvalidParameterError``."""
    if type(alpha) is float and 0.0 < alpha <= 1.0:
        return alpha
    return scalar_in_range("alpha", alpha, low=0.0, high=1.0, low_inclusive=False)


def check_epsilon(epsilon: object) -> float:
    """Return ``epsilon`` as a finite float ``>= 0``, or raise ``InvalidParameterError``."""
    if type(epsilon) is float and 0.0 <= epsilon < math.inf:
        return epsilon
    value = scalar_in_range("epsilon", epsilon, low=0.0)
    if not math.isfinite(value):
        raise InvalidParameterError(f"epsilon must be finite and >= 0, got {epsilon!r}")
    return value


def tail_count(alpha: float, n: int) -> float:
    """Return :math:`\\alpha N`, snapped to the nearest integer when within rounding error.

    ``0.2 * 50`` and ``0.7 * 10`` are not exact in binary floating point; the
    snap makes ``floor(alpha N)`` the intended integer. The CVaR formula is
    continuous in :math:`\\alpha N`, so the snap changes values by ~1e-16 at most.
    """
    mass = alpha * n
    nearest = round(mass)
    if abs(mass - nearest) <= 1e-9 * max(1.0, mass):
        return float(nearest)
    return mass


def cvar_last_axis(x: np.ndarray, alpha: float, *, overwrite: bool = False) -> np.ndarray:
    """Empirical CVaR along the last axis of a finite, non-empty ``x`` (no validation).

    O(N) per row with :func:`numpy.partition`; see :func:`empirical_cvar`. With
    ``overwrite=True`` the samples of ``x`` are reordered in place (saves a copy).
    """
    n = x.shape[-1]
    mass = tail_count(alpha, n)
    k = min(int(math.floor(mass)), n)
    if k >= n:
        return np.mean(x, axis=-1)
    # Position n-k-1 of the ascending order holds the (k+1)-th largest sample;
    # everything to its right is the top k.
    if overwrite:
        x.partition(n - k - 1, axis=-1)
        part = x
    else:
        part = np.partition(x, n - k - 1, axis=-1)
    top = part[..., n - k :].sum(axis=-1)
    return (top + (mass - k) * part[..., n - k - 1]) / mass


def empirical_cvar(x: object, alpha: float, axis: int = -1) -> np.ndarray:
    """Exact empirical :math:`\\mathrm{CVaR}_\\alpha` of samples, fractional atom included.

    With the samples sorted in descending order :math:`x_{(1)} \\ge \\dots \\ge x_{(N)}`
    and :math:`k = \\lfloor \\alpha N \\rfloor`,

    .. math::

        \\mathrm{CVaR}_\\alpha(x) = \\frac{1}{\\alpha N}\\Big(\\sum_{j=1}^{k} x_{(j)}
        + (\\alpha N - k)\\, x_{(k+1)}\\Big)
        = \\min_{\\tau \\in \\mathbb{R}} \\; \\tau + \\frac{1}{\\alpha N}
        \\sum_{j=1}^{N} \\max(x_j - \\tau, 0),

    the sample-average form of the paper's CVaR definition (Notation section).
    ``alpha = 1`` returns the mean, ``alpha -> 0`` the maximum. Cost O(N) per
    reduced row.

    Parameters
    ----------
    x
        Samples (losses; large is bad), any shape; reduced along ``axis``.
    alpha
        Tail mass in :math:`(0, 1]`.
    axis
        The sample axis.

    Returns
    -------
    numpy.ndarray
        ``x`` with ``axis`` removed (a 0-d array for 1-D input).

    Raises
    ------
    InvalidArrayError
        If ``x`` holds NaN/inf, is 0-d, or has no samples along ``axis``.
    InvalidParameterError
        If ``alpha`` is outside :math:`(0, 1]`.
    """
    alpha = check_alpha(alpha)
    array = finite_array("x", x)
    if array.ndim == 0:
        raise InvalidArrayError(f"x must have at least one axis of samples, got scalar {x!r}")
    try:
        array = np.moveaxis(array, axis, -1)
    except (ValueError, IndexError) as exc:  # numpy AxisError subclasses both
        raise InvalidArrayError(
            f"axis {axis} is out of range for x of shape {array.shape}"
        ) from exc
    if array.shape[-1] == 0:
        raise InvalidArrayError(f"x must hold at least one sample along axis {axis}, got 0")
    return cvar_last_axis(array, alpha)


def risk_value(
    losses: object,
    risk: str = "dr_cvar",
    alpha: float = 0.2,
    epsilon: float = 0.05,
    *,
    axis: int = -1,
) -> np.ndarray:
    """Risk :math:`R` of sampled losses, for each metric of Definition 2, unbounded support.

    .. math::

        R_{\\text{mean}}(x) = \\frac{1}{N}\\sum_j x_j, \\qquad
        R_{\\text{cvar}}(x) = \\mathrm{CVaR}_\\alpha(x), \\qquad
        R_{\\text{dr\\_cvar}}(x) = \\mathrm{CVaR}_\\alpha(x) + \\frac{\\epsilon}{\\alpha}.

    The DR-CVaR row is the worst case over the 2-norm Wasserstein ball of radius
    :math:`\\epsilon` (metres) around the empirical distribution of positions
    :math:`p` with support :math:`\\mathbb{R}^d`, for the loss :math:`x = -h \\cdot p`
    with a unit normal :math:`h` (so the Lipschitz constant :math:`\\lVert h \\rVert_* = 1`);
    it is Proposition 1 with :math:`\\lambda = \\lVert h \\rVert_*/\\alpha`.
    For a bounded support see :func:`filters.halfspaces.safe_halfspaces`.

    Parameters
    ----------
    losses
        Samples of the loss (typically :math:`-h \\cdot p`, metres); reduced along ``axis``.
    risk
        One of :data:`RISKS`.
    alpha
        Tail mass in :math:`(0, 1]` (ignored by ``"mean"`` but still validated).
    epsilon
        Wasserstein radius :math:`\\ge 0` in metres (used by ``"dr_cvar"`` only).
    axis
        The sample axis.

    Returns
    -------
    numpy.ndarray
        ``losses`` with ``axis`` removed.

    Raises
    ------
    InvalidParameterError
        If ``risk`` is unknown, ``alpha`` is outside :math:`(0, 1]` or ``epsilon < 0``.
    InvalidArrayError
        If ``losses`` is empty along ``axis`` or holds NaN/inf.
    """
    risk = check_risk(risk)
    alpha = check_alpha(alpha)
    epsilon = check_epsilon(epsilon)
    array = finite_array("losses", losses)
    if array.ndim == 0 or array.shape[axis] == 0:
        raise InvalidArrayError(
            f"losses must hold at least one sample along axis {axis}, got shape {array.shape}"
        )
    return risk_of_samples(np.moveaxis(array, axis, -1), risk, alpha, epsilon)


def risk_of_samples(
    x: np.ndarray, risk: str, alpha: float, epsilon: float, *, overwrite: bool = False
) -> np.ndarray:
    """:func:`risk_value` along the last axis, without validation (for the hot path).

    ``overwrite=True`` lets the CVaR reorder the samples of ``x`` in place.
    """
    if risk == "mean":
        return np.mean(x, axis=-1)
    value = cvar_last_axis(x, alpha, overwrite=overwrite)
    if risk == "dr_cvar":
        value = value + epsilon / alpha
    return value

"""Empirical risk metrics of sampled losses.

The paper's three (mean, CVaR, Wasserstein DR-CVaR) and, beyond the paper
(the design page of the docs, docs/design.md), two chance constraints built from the first two
sample moments (``"gaussian_cc"``, ``"moment_dr"``) and an online conformal
margin (``"conformal"``).

Conventions (see the design page of the docs, docs/design.md): a *loss* is bad when large, and
``alpha`` is the tail mass, so :math:`\\mathrm{CVaR}_\\alpha` averages the worst
``alpha`` fraction of the samples; ``alpha = 1`` gives the mean. For the chance
constraints ``alpha`` is the allowed violation probability. Every metric is
translation equivariant, :math:`R(x + c) = R(x) + c`, which is what turns
Definition 2 of the paper into closed forms (see :mod:`filters.halfspaces`).

Moment-based metrics: for losses :math:`x_j = -h \\cdot p^j` with a unit normal
:math:`h`, the sample variance of the :math:`x_j` (unbiased, ``ddof = 1``) is exactly
:math:`h^\\top \\hat\\Sigma h` for the unbiased sample covariance :math:`\\hat\\Sigma` of the
positions, so

.. math::

    R_{\\text{gaussian\\_cc}}(x) = \\bar x + z_{1-\\alpha}\\, s(x), \\qquad
    R_{\\text{moment\\_dr}}(x) = \\bar x + \\sqrt{(1-\\alpha)/\\alpha}\\; s(x),

with :math:`\\bar x` the sample mean, :math:`s` the sample standard deviation
(``ddof = 1``; with a single sample the spread is unknown and :math:`s = 0` is used,
so both reduce to the mean), and :math:`z_{1-\\alpha} = \\Phi^{-1}(1-\\alpha)` the
standard normal quantile. ``gaussian_cc`` is the :math:`(1-\\alpha)`-quantile of a
Gaussian fit: :math:`R \\le c` gives :math:`P(x > c) \\le \\alpha` if the losses are
Gaussian with exactly these moments. ``moment_dr`` is the worst-case
:math:`(1-\\alpha)`-quantile over *every* law with that mean and variance (Cantelli's
inequality is tight), so it is never below ``gaussian_cc`` for
:math:`\\alpha < 1/2`. For :math:`\\alpha \\ge 1/2`, :math:`z_{1-\\alpha} \\le 0` and
``gaussian_cc`` lies at or below the mean (allowed: it is what the Gaussian fit says).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ndtri

from filters._validation import finite_array, finite_scalar, scalar_in_range
from filters.constants import ALPHA, EPSILON
from filters.errors import InvalidArrayError, InvalidParameterError, InvalidTypeError

__all__ = ["CHANCE_RISKS", "PAPER_RISKS", "RISKS", "cantelli_factor", "check_risk",
           "empirical_cvar", "gaussian_factor", "risk_value"]

#: The paper's metrics (Definition 2); the CVXPY reference of
#: :mod:`filters.halfspace_cvxpy` formulates these.
PAPER_RISKS: tuple[str, ...] = ("mean", "cvar", "dr_cvar")

#: Chance constraints from the first two sample moments: ``alpha`` must lie in (0, 1).
CHANCE_RISKS: tuple[str, ...] = ("gaussian_cc", "moment_dr")

#: Names of the risk metrics understood by :func:`risk_value` and ``safe_halfspaces``.
RISKS: tuple[str, ...] = (*PAPER_RISKS, *CHANCE_RISKS, "conformal")


def check_risk(risk: object, choices: tuple[str, ...] = RISKS) -> str:
    """Return ``risk`` if it names a known metric.

    Parameters
    ----------
    risk
        The name to check.
    choices
        The accepted names (default :data:`RISKS`; e.g. :data:`PAPER_RISKS` for a
        formulation that only covers the paper's metrics).

    Raises
    ------
    InvalidTypeError
        If ``risk`` is not a string.
    InvalidParameterError
        If ``risk`` is not one of ``choices``.
    """
    if not isinstance(risk, str):
        raise InvalidTypeError(f"risk must be a string, one of {choices}, got {risk!r}")
    if risk not in choices:
        raise InvalidParameterError(f"risk must be one of {choices}, got {risk!r}")
    return risk


def check_alpha(alpha: object, risk: str | None = None) -> float:
    """Return ``alpha`` as a float in :math:`(0, 1]`, or raise ``InvalidParameterError``.

    For the chance constraints (``risk`` in :data:`CHANCE_RISKS`) the domain is the
    open interval :math:`(0, 1)`: a violation probability of 1 constrains nothing
    (:math:`z_0 = -\\infty`, Cantelli factor 0 would be a silent mean).
    """
    if type(alpha) is float and 0.0 < alpha < 1.0:
        return alpha
    value = scalar_in_range("alpha", alpha, low=0.0, high=1.0, low_inclusive=False)
    if value == 1.0 and risk in CHANCE_RISKS:
        raise InvalidParameterError(
            f"alpha must lie in (0, 1) for risk={risk!r} (it is the allowed violation "
            f"probability of a chance constraint; 1 constrains nothing), got {alpha!r}")
    return value


def gaussian_factor(alpha: float) -> float:
    """:math:`z_{1-\\alpha} = \\Phi^{-1}(1 - \\alpha)`, the standard normal quantile (unchecked).

    Negative for :math:`\\alpha > 1/2`, zero at :math:`\\alpha = 1/2`.
    """
    return float(-ndtri(alpha))  # -Phi^{-1}(alpha) = Phi^{-1}(1 - alpha), exact in the tail


def cantelli_factor(alpha: float) -> float:
    """:math:`\\sqrt{(1-\\alpha)/\\alpha}`, the one-sided Chebyshev (Cantelli) factor (unchecked).

    For every law with mean :math:`\\mu` and standard deviation :math:`\\sigma`,
    :math:`P(x \\ge \\mu + k\\sigma) \\le 1/(1+k^2) = \\alpha`, with equality for a two-point law.
    """
    return math.sqrt((1.0 - alpha) / alpha)


def check_epsilon_array(epsilon: object, length: int) -> float | np.ndarray:
    """Return a scalar radius as a float, or a per-step radius as a read-only ``(length,)`` array.

    Raises
    ------
    InvalidParameterError
        If a scalar is negative or not finite.
    InvalidArrayError
        If an array does not have shape ``(length,)`` or holds negative or
        non-finite entries.
    """
    if np.ndim(epsilon) == 0:
        return check_epsilon(epsilon)
    array = _nonnegative("epsilon", finite_array("epsilon", epsilon, shape=(length,))).copy()
    array.flags.writeable = False
    return array


def check_margins(margins: object, shape: tuple[int, ...]) -> np.ndarray:
    """Return conformal margins as a float array broadcastable to ``shape``.

    Accepted: a scalar, shape ``(T,)`` (one margin per look-ahead step) or
    ``(n_obstacles, T)``, where ``shape = (n_obstacles, T)``; finite and ``>= 0`` (m).

    Raises
    ------
    InvalidParameterError
        If ``margins`` is ``None``.
    InvalidArrayError
        For another shape, or a negative or non-finite entry.
    """
    if margins is None:
        raise InvalidParameterError(
            "risk='conformal' needs conformal_margins: one margin q_k >= 0 (m) per "
            "look-ahead step, e.g. filters.calibration.ConformalMargin(...).margins()")
    array = finite_array("conformal_margins", margins)
    if array.ndim > len(shape) or array.shape != shape[len(shape) - array.ndim :]:
        raise InvalidArrayError(f"conformal_margins must be a scalar or have shape {shape[1:]} "
                                f"or {shape}, got {array.shape}")
    return _nonnegative("conformal_margins", array)


def check_epsilon(epsilon: object) -> float:
    """Return ``epsilon`` as a finite float ``>= 0``, or raise ``InvalidParameterError``."""
    if type(epsilon) is float and 0.0 <= epsilon < math.inf:
        return epsilon
    return finite_scalar("epsilon (metres)", epsilon, low=0.0)


def tail_count(alpha: float, n: int) -> float:
    """Return :math:`\\alpha N`, snapped to the nearest integer when within rounding error.

    ``0.2 * 50`` and ``0.7 * 10`` are not exact in binary floating point; the
    snap makes ``floor(alpha N)`` the intended integer. The CVaR formula is
    continuous in :math:`\\alpha N`, so the snap changes values by ~1e-16 at most.
    """
    mass = alpha * n
    nearest = round(mass)
    return float(nearest) if abs(mass - nearest) <= 1e-9 * max(1.0, mass) else mass


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
    part = x if overwrite else np.partition(x, n - k - 1, axis=-1)
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
    return cvar_last_axis(_samples_last("x", x, axis), check_alpha(alpha))


def risk_value(
    losses: object,
    risk: str = "dr_cvar",
    alpha: float = ALPHA,
    epsilon: float | object = EPSILON,
    *,
    axis: int = -1,
    margin: object | None = None,
) -> np.ndarray:
    """Risk :math:`R` of sampled losses, for every metric of :data:`RISKS`, unbounded support.

    .. math::

        R_{\\text{mean}}(x) = \\bar x, \\qquad
        R_{\\text{cvar}}(x) = \\mathrm{CVaR}_\\alpha(x), \\qquad
        R_{\\text{dr\\_cvar}}(x) = \\mathrm{CVaR}_\\alpha(x) + \\frac{\\epsilon}{\\alpha},

        R_{\\text{gaussian\\_cc}}(x) = \\bar x + z_{1-\\alpha} s(x), \\qquad
        R_{\\text{moment\\_dr}}(x) = \\bar x + \\sqrt{\\tfrac{1-\\alpha}{\\alpha}}\\, s(x), \\qquad
        R_{\\text{conformal}}(x) = \\bar x + q,

    with :math:`\\bar x` the sample mean and :math:`s` the sample standard deviation
    (``ddof = 1``, and :math:`s = 0` for a single sample); see the module docstring.

    The DR-CVaR row is the worst case over the 2-norm Wasserstein ball of radius
    :math:`\\epsilon` (metres) around the empirical distribution of positions
    :math:`p` with support :math:`\\mathbb{R}^d`, for the loss :math:`x = -h \\cdot p`
    with a unit normal :math:`h` (so the Lipschitz constant :math:`\\lVert h \\rVert_* = 1`);
    it is Proposition 1 with :math:`\\lambda = \\lVert h \\rVert_*/\\alpha`.
    For a bounded support see :func:`filters.halfspaces.safe_halfspaces`.

    The conformal row bounds the realised loss :math:`-h \\cdot p` whenever
    :math:`\\lVert p - \\hat\\mu \\rVert \\le q` (Cauchy-Schwarz, :math:`\\lVert h \\rVert = 1`), so
    with :math:`q` the conformal quantile of past errors
    (:class:`filters.calibration.ConformalMargin`) it holds with the conformal
    coverage :math:`1 - \\alpha`; ``alpha`` itself is not used by this row.

    Parameters
    ----------
    losses
        Samples of the loss (typically :math:`-h \\cdot p`, metres); reduced along ``axis``.
    risk
        One of :data:`RISKS`.
    alpha
        Tail mass / violation probability in :math:`(0, 1]`; in :math:`(0, 1)` for
        :data:`CHANCE_RISKS`. Ignored by ``"mean"`` and ``"conformal"`` but still validated.
    epsilon
        Wasserstein radius :math:`\\ge 0` in metres (``"dr_cvar"`` only): a scalar, or an
        array broadcastable against the result (e.g. one radius per prediction step).
    axis
        The sample axis.
    margin
        Conformal margin :math:`q \\ge 0` in metres, broadcastable against the result;
        required by ``"conformal"``, ignored otherwise.

    Returns
    -------
    numpy.ndarray
        ``losses`` with ``axis`` removed.

    Raises
    ------
    InvalidParameterError
        If ``risk`` is unknown, ``alpha`` is outside its domain, ``epsilon < 0``, or
        ``margin`` is missing for ``"conformal"``.
    InvalidArrayError
        If ``losses`` is empty along ``axis`` or holds NaN/inf, or ``epsilon`` /
        ``margin`` is negative, non-finite or does not broadcast.
    """
    risk = check_risk(risk)
    alpha = check_alpha(alpha, risk)
    x = _samples_last("losses", losses, axis)
    epsilon = check_epsilon(epsilon) if np.ndim(epsilon) == 0 and not isinstance(
        epsilon, np.ndarray) else _broadcastable("epsilon", epsilon, x.shape[:-1])
    if risk == "conformal":  # (check_margins raises for a missing margin, naming it)
        margin = check_margins(None, (1, 1)) if margin is None else _broadcastable(
            "margin", margin, x.shape[:-1])
    return risk_of_samples(x, risk, alpha, epsilon, margin=margin)


def _samples_last(name: str, value: object, axis: int) -> np.ndarray:
    """Finite samples with the sample ``axis`` (at least one sample) moved last."""
    array = finite_array(name, value)
    try:
        if array.ndim and array.shape[axis]:
            return np.moveaxis(array, axis, -1)
    except IndexError as exc:
        raise InvalidArrayError(f"axis {axis} is out of range for {name} of shape "
                                f"{array.shape}") from exc
    raise InvalidArrayError(
        f"{name} must hold at least one sample along axis {axis}, got shape {array.shape}")


def _nonnegative(name: str, array: np.ndarray) -> np.ndarray:
    """``array`` if every entry is ``>= 0``, else ``InvalidArrayError``."""
    if np.any(array < 0.0):
        raise InvalidArrayError(f"{name} must be >= 0 (metres), got minimum {float(array.min())}")
    return array


def _broadcastable(name: str, value: object, shape: tuple[int, ...]) -> np.ndarray:
    """A finite array ``>= 0`` that broadcasts to ``shape``, or raise ``InvalidArrayError``."""
    array = finite_array(name, value)
    try:
        np.broadcast_shapes(array.shape, shape)
    except ValueError as exc:
        raise InvalidArrayError(f"{name} of shape {array.shape} does not broadcast against the "
                                f"result shape {shape}") from exc
    return _nonnegative(name, array)


def risk_of_samples(
    x: np.ndarray,
    risk: str,
    alpha: float,
    epsilon: float | np.ndarray,
    *,
    overwrite: bool = False,
    margin: np.ndarray | float | None = None,
) -> np.ndarray:
    """:func:`risk_value` along the last axis, without validation (for the hot path).

    ``overwrite=True`` lets the CVaR reorder the samples of ``x`` in place.
    ``epsilon`` and ``margin`` broadcast against the result.
    """
    if risk == "mean":
        return np.mean(x, axis=-1)
    if risk in CHANCE_RISKS:
        factor = gaussian_factor(alpha) if risk == "gaussian_cc" else cantelli_factor(alpha)
        spread = np.std(x, axis=-1, ddof=1) if x.shape[-1] > 1 else 0.0  # s = 0: one sample
        return np.mean(x, axis=-1) + factor * spread
    if risk == "conformal":
        return np.mean(x, axis=-1) + margin
    value = cvar_last_axis(x, alpha, overwrite=overwrite)
    return value + epsilon / alpha if risk == "dr_cvar" else value

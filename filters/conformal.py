"""Online conformal margins per look-ahead step, with adaptive conformal inference (ACI).

:class:`ConformalMargin` keeps a sliding window of the scores of
:class:`filters.prediction_record.PredictionRecord` per look-ahead and returns their
split-conformal quantile (the margins of ``risk="conformal"`` of
:func:`filters.safe_halfspaces`); :func:`conformal_rank` is the rank of that quantile.
:class:`AdaptiveRadius` runs the same machinery on :func:`dr_cvar_scores`, the radius
each realisation needed, and gives DR-CVaR's Wasserstein radius per look-ahead
(``adaptive_epsilon=True`` of :class:`filters.SafetyFilterWrapper`).
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from filters._validation import (
    finite_array,
    finite_scalar,
    integer_at_least,
    lookahead_index,
    scalar_in_range,
)
from filters.errors import InvalidArrayError
from filters.risk import check_alpha, cvar_last_axis
from filters.wasserstein import grid_directions

if TYPE_CHECKING:
    from filters.prediction_record import Realisation

__all__ = ["AdaptiveRadius", "ConformalMargin", "conformal_rank", "dr_cvar_scores"]


def conformal_rank(n: int, alpha: float) -> int:
    """:math:`\\lceil (n+1)(1-\\alpha) \\rceil`, the split-conformal rank among ``n`` scores.

    With exchangeable scores :math:`s_1..s_{n+1}`, the ``rank``-th smallest of the first
    ``n`` bounds :math:`s_{n+1}` with probability at least :math:`1-\\alpha` (and at most
    :math:`1 - \\alpha + 1/(n+1)` without ties). A rank above ``n`` means no finite margin
    has that coverage; a rank ``<= 0`` (:math:`\\alpha \\ge 1`) means margin 0 suffices.
    A relative rounding slack of ``1e-12`` keeps exact integers exact.
    """
    value = (n + 1) * (1.0 - alpha)
    return int(math.ceil(value - 1e-12 * max(1.0, abs(value))))


class ConformalMargin:
    """Online conformal margins :math:`q_k`, one per look-ahead step, with ACI.

    For look-ahead ``k`` with the ``n`` most recent scores (at most ``window``, pooled
    over obstacles) and the current level :math:`\\alpha_{t,k}`,

    .. math::

        q_k = s_{(r)}, \\qquad r = \\lceil (n + 1)(1 - \\alpha_{t,k}) \\rceil,

    the ``r``-th smallest score (split conformal: marginal coverage
    :math:`P(s \\le q_k) \\ge 1 - \\alpha_{t,k}` for exchangeable scores). Each
    :meth:`update` at look-ahead ``k`` then moves the level by adaptive conformal
    inference (Gibbs & Candès, NeurIPS 2021, eq. (2)),

    .. math::

        \\alpha_{t+1,k} = \\alpha_{t,k} + \\gamma\\,(\\alpha - \\mathrm{err}_{t,k}),

    where :math:`\\mathrm{err}_{t,k} \\in [0, 1]` is the fraction of the new scores above
    the margin in force just before the update (with several obstacles per step a
    fraction, not a 0/1 flag; the feedback arrives ``k`` steps after the prediction
    was issued). ``gamma = 0`` is plain split conformal over a sliding window.

    Guarantees. With exchangeable scores and ``gamma = 0``: marginal coverage
    :math:`\\ge 1 - \\alpha` per look-ahead once ``n >= (1 - \\alpha)/\\alpha`` scores are in the
    window (distribution free; pooling obstacles assumes their scores exchangeable).
    With ``gamma > 0`` and *any* sequence: Gibbs & Candès' Proposition 4.1,
    :math:`|\\frac1T \\sum_t \\mathrm{err}_t - \\alpha|
    \\le (\\max(\\alpha, 1-\\alpha) + \\gamma)/(\\gamma T)`,
    holds when a level :math:`\\le 0` yields an infinite margin. Here the level is
    clipped to :math:`[-\\gamma, 1 + \\gamma]` (the range that proposition shows it never
    leaves) and a level with rank ``> n`` uses ``fallback``; with a finite fallback the
    bound gets an extra term, the fraction of steps at which the fallback was exceeded.

    Parameters
    ----------
    alpha
        Target miscoverage in :math:`(0, 1)` (the filter's violation probability).
    horizon
        ``T``: number of look-ahead steps.
    window
        Most recent scores used per look-ahead (default 200).
    gamma
        ACI step size ``>= 0`` (default 0.005, Gibbs & Candès' choice).
    fallback
        Margin (m) when too few scores give a finite conformal quantile (rank ``> n``,
        including before any data): a number ``>= 0`` (``math.inf`` by default: no
        finite margin is valid yet, and :func:`filters.safe_halfspaces` rejects it, so
        a filter must pass a finite value, e.g. 1.0 m), or ``"max"`` for the largest
        score seen so far at that look-ahead (``inf`` before any).

    Raises
    ------
    InvalidParameterError
        For a parameter outside its domain.
    """

    def __init__(self, alpha: float, *, horizon: int, window: int = 200, gamma: float = 0.005,
                 fallback: float | str = math.inf) -> None:
        self.alpha = _open_unit("alpha", alpha)
        self.horizon = T = integer_at_least("horizon", horizon)
        self.window = integer_at_least("window", window)
        self.gamma = scalar_in_range("gamma", gamma, low=0.0)
        self.fallback = "max" if fallback == "max" else scalar_in_range("fallback", fallback,
                                                                        low=0.0)
        self.levels = np.full(T, self.alpha)
        self._windows: list[deque[float]] = [deque(maxlen=self.window) for _ in range(T)]
        # The same scores kept sorted (bisect), so a margin is one lookup, not a partition.
        self._sorted: list[list[float]] = [[] for _ in range(T)]
        self._max_seen = np.full(T, -math.inf)
        self.n_scored, self.n_exceeded = np.zeros(T, dtype=np.int64), np.zeros(T, dtype=np.int64)

    def margin(self, lookahead: int) -> float:
        """Current margin :math:`q_k` in m for look-ahead ``k`` in ``1..T`` (see the class)."""
        k = lookahead_index(lookahead, self.horizon)
        ordered = self._sorted[k]
        rank = conformal_rank(len(ordered), float(self.levels[k]))
        if rank <= 0:
            return 0.0
        if rank <= len(ordered):
            return ordered[rank - 1]
        if self.fallback == "max":
            return float(self._max_seen[k]) if self._max_seen[k] > -math.inf else math.inf
        return float(self.fallback)

    def margins(self) -> np.ndarray:
        """Margins for every look-ahead, shape ``(T,)``, m (``conformal_margins=``)."""
        return np.array([self.margin(k) for k in range(1, self.horizon + 1)])

    def update_scores(self, lookahead: int, scores: object) -> float:
        """Add the scores realised at one step for look-ahead ``k``; return :math:`\\mathrm{err}`.

        Raises
        ------
        InvalidArrayError
            If ``scores`` is not a finite 1-D array of values ``>= 0``.
        """
        k = lookahead_index(lookahead, self.horizon)
        values = finite_array("scores", scores).reshape(-1)
        if np.any(values < 0.0):
            raise InvalidArrayError(f"scores must be >= 0 (norms, m), got {values.tolist()}")
        if values.size == 0:
            return 0.0
        exceeded = int(np.count_nonzero(values > self.margin(k + 1)))
        err = exceeded / values.size
        level = self.levels[k] + self.gamma * (self.alpha - err)
        self.levels[k] = min(max(level, -self.gamma), 1.0 + self.gamma)
        window, ordered = self._windows[k], self._sorted[k]
        for value in values.tolist():
            if len(window) == self.window:
                del ordered[bisect.bisect_left(ordered, window.popleft())]
            window.append(value)
            bisect.insort(ordered, value)
        self._max_seen[k] = max(self._max_seen[k], float(values.max()))
        self.n_scored[k] += values.size
        self.n_exceeded[k] += exceeded
        return err

    def update(self, realisations: tuple[Realisation, ...] | list[Realisation]) -> None:
        """Feed the output of :meth:`PredictionRecord.update` (look-aheads beyond ``T`` skipped)."""
        for realisation in realisations:
            if realisation.lookahead <= self.horizon:
                self.update_scores(realisation.lookahead, realisation.scores)

    def coverage(self) -> np.ndarray:
        """Empirical coverage so far per look-ahead, shape ``(T,)`` (``nan``: nothing scored)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return 1.0 - self.n_exceeded / self.n_scored


def _open_unit(name: str, value: object) -> float:
    return scalar_in_range(name, value, low=0.0, high=1.0, low_inclusive=False,
                           high_inclusive=False)


def dr_cvar_scores(
    errors: object, predicted_errors: object, alpha: float, *, n_directions: int = 64
) -> np.ndarray:
    """The shift beyond :math:`\\mathrm{CVaR}_\\alpha` each realisation needed, one per obstacle.

    For a realised error :math:`e = p - \\hat\\mu` and the predictor's own errors
    :math:`\\xi_j = \\hat p_j - \\hat\\mu` (``j = 1..N_s``), the score is an upper bound on

    .. math::

        s^\\star = \\Big(\\sup_{\\lVert u \\rVert = 1}\\; u \\cdot e
        - \\mathrm{CVaR}_\\alpha(u \\cdot \\xi)\\Big)_+ ,

    the smallest :math:`s \\ge 0` with
    :math:`-h \\cdot p \\le \\mathrm{CVaR}_\\alpha(-h \\cdot \\hat p) + s`
    for *every* unit normal :math:`h` (``u = -h``; CVaR is translation equivariant).
    So a DR-CVaR halfspace with radius :math:`\\epsilon \\ge \\alpha s` (unbounded support:
    :math:`R = \\mathrm{CVaR}_\\alpha + \\epsilon/\\alpha`) bounds the realised position,
    whatever normal the filter picks: the realised loss of an ego on the halfspace's
    boundary is at most :math:`\\delta`. The supremum is taken over ``n_directions``
    directions :math:`u_m` on the circle and made an upper bound with their spacing:
    :math:`f(u) = u \\cdot e - \\mathrm{CVaR}_\\alpha(u \\cdot \\xi)` is Lipschitz with
    constant :math:`L = \\lVert e \\rVert + \\mathrm{CVaR}_\\alpha(\\lVert \\xi \\rVert)`
    (CVaR is monotone, subadditive and positively homogeneous), and every unit ``u`` is
    within :math:`2 \\sin(\\pi / 2M)` of a grid direction, so

    .. math::

        s = \\Big(\\max_m f(u_m) + 2 \\sin\\tfrac{\\pi}{2M} L\\Big)_+ \\;\\ge\\; s^\\star .

    In ``d = 1`` the directions are :math:`\\pm 1` and the score is exact.

    Parameters
    ----------
    errors
        :math:`e`, shape ``(n_obs, d)``, m (:attr:`Realisation.errors`).
    predicted_errors
        :math:`\\xi`, shape ``(n_obs, N_s, d)``, m (:attr:`Realisation.predicted_errors`).
    alpha
        CVaR tail mass in :math:`(0, 1]`.
    n_directions
        ``M`` for ``d = 2`` (default 64: the bound's slack is 0.025 L).

    Returns
    -------
    numpy.ndarray
        Shape ``(n_obs,)``, m, ``>= 0``.

    Raises
    ------
    InvalidArrayError
        For non-finite or mismatched arrays, no samples, or ``d`` not 1 or 2.
    InvalidParameterError
        For ``alpha`` outside :math:`(0, 1]` or ``n_directions < 3``.
    """
    alpha = check_alpha(alpha)
    e = finite_array("errors", errors, ndim=2)
    xi = finite_array("predicted_errors", predicted_errors, ndim=3)
    n_obs, dim = e.shape
    if xi.shape[0] != n_obs or xi.shape[2] != dim or xi.shape[1] == 0:
        raise InvalidArrayError(
            f"predicted_errors must have shape ({n_obs}, N_s >= 1, {dim}) to match errors "
            f"{e.shape}, got {xi.shape}")
    count = integer_at_least("n_directions", n_directions, low=3)
    directions, slack = grid_directions(dim, count, "dr_cvar_scores", full=True)
    projected = directions @ xi.transpose(0, 2, 1)  # (n_obs, M, N_s)
    gap = e @ directions.T - cvar_last_axis(projected, alpha, overwrite=True)  # (n_obs, M)
    worst = gap.max(axis=1)
    if slack:
        norms = np.sqrt((xi * xi).sum(axis=-1))
        worst += slack * (np.sqrt((e * e).sum(axis=-1)) + cvar_last_axis(norms, alpha))
    return np.maximum(worst, 0.0)


class AdaptiveRadius:
    """DR-CVaR's Wasserstein radius per look-ahead, from the radii the realisations needed.

    Each realisation at look-ahead ``k`` (one per obstacle and step) gets the score
    :math:`s` of :func:`dr_cvar_scores`: the shift beyond the predicted CVaR it
    needed for every normal. A :class:`ConformalMargin` at target miscoverage
    ``miscoverage`` keeps these scores (sliding window, split-conformal quantile
    :math:`q_k`, adaptive conformal inference on the level) and the radius is

    .. math::

        \\epsilon_k = \\alpha\\, q_k ,

    so that :math:`\\mathrm{CVaR}_\\alpha + \\epsilon_k/\\alpha = \\mathrm{CVaR}_\\alpha + q_k`
    (never below ``floor``: :math:`\\epsilon_k = \\max(\\epsilon_{\\min}, \\alpha q_k)`).
    When the realised positions stray farther from the predictions than their samples
    say (a spread understated, a bias), the scores grow and the radius with them; when
    the samples describe reality the scores are mostly 0 and the radius shrinks. ACI
    moves the level on the observed miscoverage: a realisation whose score exceeds the
    current :math:`q_k` is an error (``err = 1``), i.e. *some* normal's halfspace would
    not have held the realised position at its risk level.

    Guarantees (those of :class:`ConformalMargin` applied to these scores, per
    look-ahead, pooled over obstacles): with exchangeable scores and ``gamma = 0``,
    :math:`P(s \\le q_k) \\ge 1 - \\text{miscoverage}`; with ``gamma > 0`` and any
    sequence, Gibbs & Candès' long-run bound on the fraction of errors (see
    :class:`ConformalMargin`, and the filter guide for what it does not promise).

    Parameters
    ----------
    alpha
        The CVaR tail mass of the halfspaces, in :math:`(0, 1]`.
    horizon
        ``T``.
    miscoverage
        Target fraction of realisations outside the bound, in :math:`(0, 1)` (default
        ``alpha``).
    window, gamma
        Of :class:`ConformalMargin` (defaults 200 and 0.005).
    fallback
        Radius (m) before any score at a look-ahead (default 0.05, the paper's
        hand-tuned radius); with scores but too few for the current level, the
        largest score seen gives the radius.
    floor
        Smallest radius :math:`\\epsilon_{\\min}` (m, default 0: the radius follows the
        data both ways). A floor at a hand-tuned radius makes the calibration widen
        only: the radius then comes back down to the floor, not below, when the
        predictions match.
    n_directions
        Of :func:`dr_cvar_scores`.

    Raises
    ------
    InvalidParameterError
        For a parameter outside its domain.
    """

    def __init__(self, alpha: float, *, horizon: int, miscoverage: float | None = None,
                 window: int = 200, gamma: float = 0.005, fallback: float = 0.05,
                 floor: float = 0.0, n_directions: int = 64) -> None:
        self.alpha = check_alpha(alpha)
        self.fallback = finite_scalar("fallback", fallback, low=0.0)
        self.floor = finite_scalar("floor", floor, low=0.0)
        self.n_directions = integer_at_least("n_directions", n_directions, low=3)
        level = _open_unit("miscoverage (alpha unless given)",
                           self.alpha if miscoverage is None else miscoverage)
        self.scores = ConformalMargin(level, horizon=horizon, window=window, gamma=gamma,
                                      fallback="max")

    @property
    def horizon(self) -> int:
        """``T``."""
        return self.scores.horizon

    def update(self, realisations: tuple[Realisation, ...] | list[Realisation]) -> None:
        """Score and feed the output of :meth:`PredictionRecord.update` (all samples kept).

        The realisations of one step are scored in one call of :func:`dr_cvar_scores`
        when their arrays have the same shapes (they do within an episode).
        """
        kept = [r for r in realisations if r.lookahead <= self.horizon]
        if not kept:
            return
        groups = [kept] if len({(r.errors.shape, r.predicted_errors.shape) for r in kept}) == 1 \
            else [[r] for r in kept]
        scores = [row for group in groups for row in dr_cvar_scores(
            np.concatenate([r.errors for r in group]),
            np.concatenate([r.predicted_errors for r in group]), self.alpha,
            n_directions=self.n_directions).reshape(len(group), -1)]
        for r, values in zip(kept, scores, strict=True):
            self.scores.update_scores(r.lookahead, values)

    def radius(self, lookahead: int) -> float:
        """:math:`\\epsilon_k = \\max(\\epsilon_{\\min}, \\alpha q_k)` in m at look-ahead ``k``.

        ``fallback`` before any score at ``k``; the largest score seen times
        :math:`\\alpha` while the window is too short for the current level (never a
        radius smaller than the data asked for).
        """
        margin = self.scores.margin(lookahead)
        return self.fallback if math.isinf(margin) else max(self.floor, self.alpha * margin)

    def radii(self) -> np.ndarray:
        """Radii for every look-ahead, shape ``(T,)``, m (``epsilon=`` of ``safe_halfspaces``)."""
        return np.array([self.radius(k) for k in range(1, self.horizon + 1)])

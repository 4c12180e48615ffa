"""Online conformal margins per look-ahead step, with adaptive conformal inference (ACI).

:class:`ConformalMargin` keeps a sliding window of the scores of
:class:`filters.prediction_record.PredictionRecord` per look-ahead and returns their
split-conformal quantile (the margins of ``risk="conformal"`` of
:func:`filters.safe_halfspaces`); :func:`conformal_rank` is the rank of that quantile.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from filters._validation import finite_array, integer_at_least, scalar_in_range
from filters.errors import InvalidArrayError, InvalidParameterError

if TYPE_CHECKING:
    from filters.prediction_record import Realisation

__all__ = ["ConformalMargin", "conformal_rank"]


def _fallback(value: object) -> float | str:
    if value == "max":
        return "max"
    number = scalar_in_range("fallback", value, low=0.0)
    return number



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

    def __init__(
        self,
        alpha: float,
        *,
        horizon: int,
        window: int = 200,
        gamma: float = 0.005,
        fallback: float | str = math.inf,
    ) -> None:
        self.alpha = scalar_in_range(
            "alpha", alpha, low=0.0, high=1.0, low_inclusive=False, high_inclusive=False
        )
        self.horizon = integer_at_least("horizon", horizon)
        self.window = integer_at_least("window", window)
        self.gamma = scalar_in_range("gamma", gamma, low=0.0)
        self.fallback = _fallback(fallback)
        self.levels = np.full(self.horizon, self.alpha)
        self._windows: list[deque[float]] = [deque(maxlen=self.window) for _ in range(self.horizon)]
        # The same scores kept sorted (bisect), so a margin is one lookup, not a partition.
        self._sorted: list[list[float]] = [[] for _ in range(self.horizon)]
        self._max_seen = np.full(self.horizon, -math.inf)
        self.n_scored = np.zeros(self.horizon, dtype=np.int64)
        self.n_exceeded = np.zeros(self.horizon, dtype=np.int64)

    def margin(self, lookahead: int) -> float:
        """Current margin :math:`q_k` in m for look-ahead ``k`` in ``1..T`` (see the class)."""
        k = self._index(lookahead)
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
        k = self._index(lookahead)
        values = finite_array("scores", scores).reshape(-1)
        if np.any(values < 0.0):
            raise InvalidArrayError(f"scores must be >= 0 (norms, m), got {values.tolist()}")
        if values.size == 0:
            return 0.0
        q = self.margin(k + 1)
        exceeded = int(np.count_nonzero(values > q))
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

    def _index(self, lookahead: int) -> int:
        k = integer_at_least("lookahead", lookahead)
        if k > self.horizon:
            raise InvalidParameterError(f"lookahead must be in 1..{self.horizon}, got {k}")
        return k - 1

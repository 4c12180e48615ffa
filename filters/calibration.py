"""Online calibration from realised against predicted obstacle positions.

Three pieces, usable on their own or chained (a filter wrapper does the chaining):

* :class:`PredictionRecord` keeps the prediction samples issued over the last ``T``
  steps and, when the realised position for a predicted time arrives, returns one
  :class:`Realisation` per look-ahead ``k``: the error of the realised position from
  the sample mean, its norm (the conformal *score*), and the predictor's own errors.
* :class:`ConformalMargin`: per look-ahead, a split-conformal quantile of past
  scores over a sliding window, with adaptive conformal inference (ACI) moving the
  miscoverage level online. It feeds ``risk="conformal"`` of
  :func:`filters.safe_halfspaces`.
* :class:`WassersteinRadius`: per look-ahead, a data-driven Wasserstein radius for
  ``risk="dr_cvar"`` (``epsilon`` of shape ``(T,)``).

Timeline (one call of :meth:`PredictionRecord.update` per control step ``t``): the
environment reports the realised positions :math:`p_t` (``(n_obs, d)``) and samples
:math:`\\hat p^{(j)}_{t+k}`, ``k = 1..T``. The samples issued at :math:`t - k` for
look-ahead ``k`` are compared with :math:`p_t`:

.. math::

    \\hat\\mu_{t,k} = \\frac{1}{N_s}\\sum_j \\hat p^{(j)}_{t-k+k}, \\qquad
    e_{t,k} = p_t - \\hat\\mu_{t,k}, \\qquad
    s_{t,k} = \\lVert e_{t,k} \\rVert_2 .

Why the Euclidean score: for every unit normal :math:`h`, Cauchy-Schwarz gives
:math:`-h \\cdot p_t \\le -h \\cdot \\hat\\mu + \\lVert p_t - \\hat\\mu \\rVert`, so a margin
:math:`q_k` with :math:`P(s_{t,k} \\le q_k) \\ge 1 - \\alpha` makes
:math:`R = \\overline{(-h \\cdot p)} + q_k` an upper bound on the realised loss
:math:`-h \\cdot p_t` with probability :math:`\\ge 1 - \\alpha`, *whatever* the normal the
filter picks (the normal depends on the ego reference, which is chosen after the
margin). An :math:`h`-projected score would be tighter but only valid for the
normal it was computed with.

No gym or environment import: the inputs are plain arrays. Every random draw (the
bootstrap of :class:`WassersteinRadius`) comes from a seeded
:class:`numpy.random.Generator`.
"""

from __future__ import annotations

import bisect
import copy
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from filters._validation import finite_array, scalar_in_range
from filters.errors import InvalidArrayError, InvalidParameterError

__all__ = [
    "ConformalMargin",
    "OnlineCalibration",
    "PredictionRecord",
    "Realisation",
    "WassersteinRadius",
    "conformal_rank",
    "sliced_wasserstein_max",
]


def _count(name: str, value: object, *, low: int = 1) -> int:
    if type(value) is int and value >= low:  # the common case, checked every step
        return value
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low:
        raise InvalidParameterError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


def _fallback(value: object) -> float | str:
    if value == "max":
        return "max"
    number = scalar_in_range("fallback", value, low=0.0)
    return number


@dataclass(frozen=True, eq=False)
class Realisation:
    """Realised against predicted positions for one look-ahead step ``k``.

    Attributes
    ----------
    lookahead
        ``k`` in ``1..T``: the samples were issued ``k`` steps before ``step``.
    step
        Index of the :meth:`PredictionRecord.update` call that realised them (from 0).
    errors
        :math:`e = p_{\\text{realised}} - \\hat\\mu`, shape ``(n_obs, d)``, m.
    scores
        :math:`s = \\lVert e \\rVert_2`, shape ``(n_obs,)``, m.
    predicted_errors
        The predictor's own errors :math:`\\hat p^{(j)} - \\hat\\mu`, shape
        ``(n_obs, m, d)`` with ``m <= N_s`` (the first ``keep_samples`` samples), m.
    n_samples
        ``N_s``, the number of samples the mean was taken over.
    """

    lookahead: int
    step: int
    errors: np.ndarray
    scores: np.ndarray
    predicted_errors: np.ndarray
    n_samples: int


class PredictionRecord:
    """Record of issued predictions, matched with the realised positions as they arrive.

    Parameters
    ----------
    horizon
        ``T``: look-ahead steps tracked (samples with more steps are cut to ``T``).
    keep_samples
        Predicted errors kept per obstacle in each :class:`Realisation` (the first
        ``keep_samples`` samples; ``None``: all). Bounds memory for long records.
    memory
        Scores kept per look-ahead for :meth:`scores` (the most recent ``memory`` steps).

    Examples
    --------
    >>> record = PredictionRecord(horizon=10)
    >>> for samples, positions in stream:      # doctest: +SKIP
    ...     realised = record.update(samples, positions)
    ...     margin.update(realised)
    """

    def __init__(
        self, horizon: int, *, keep_samples: int | None = None, memory: int = 10_000
    ) -> None:
        self.horizon = _count("horizon", horizon)
        self.keep_samples = None if keep_samples is None else _count("keep_samples", keep_samples)
        self.memory = _count("memory", memory)
        self._pending: deque[tuple[int, np.ndarray]] = deque(maxlen=self.horizon)
        self._scores: list[deque[np.ndarray]] = [
            deque(maxlen=self.memory) for _ in range(self.horizon)
        ]
        self.step = 0

    def reset(self) -> None:
        """Forget the pending predictions (call at an episode boundary); keep the scores."""
        self._pending.clear()

    def update(self, samples: object, realised_positions: object) -> tuple[Realisation, ...]:
        """Match ``realised_positions`` with earlier predictions, then store ``samples``.

        Parameters
        ----------
        samples
            Predictions issued now for steps ``t+1..t+T'``, shape
            ``(n_obs, N_s, T', d)`` with ``T' >= 1`` (only the first ``T`` steps are kept), m.
        realised_positions
            Positions realised now, :math:`p_t`, shape ``(n_obs, d)``, m.

        Returns
        -------
        tuple of Realisation
            One per look-ahead ``k`` whose prediction (issued ``k`` steps ago, in this
            episode) is realised now, in increasing ``k``; empty on the first call.

        Raises
        ------
        InvalidArrayError
            If an array has the wrong shape or holds NaN/inf, or the obstacle count or
            dimension changed without :meth:`reset`.
        """
        points = finite_array("samples", samples, ndim=4)
        positions = finite_array("realised_positions", realised_positions, ndim=2)
        n_obs, n_samples, steps, dim = points.shape
        if n_samples == 0 or steps == 0:
            raise InvalidArrayError(
                f"samples must hold at least one sample and one step, got shape {points.shape}"
            )
        if positions.shape != (n_obs, dim):
            raise InvalidArrayError(
                f"realised_positions must have shape ({n_obs}, {dim}) to match samples "
                f"{points.shape}, got {positions.shape}"
            )
        if self._pending and self._pending[-1][1].shape[0::3] != (n_obs, dim):
            old = self._pending[-1][1].shape
            raise InvalidArrayError(
                f"samples have shape {points.shape} but the pending ones {old}: the obstacle "
                "count or dimension changed; call reset() at an episode boundary"
            )
        realised = []
        for issued, old in reversed(self._pending):  # newest first: k = 1, 2, ...
            k = self.step - issued
            if k > old.shape[2]:
                continue
            predicted = old[:, :, k - 1]  # (n_obs, N_s, d)
            mean = predicted.mean(axis=1)
            errors = positions - mean
            scores = np.sqrt((errors * errors).sum(axis=-1))
            kept = predicted if self.keep_samples is None else predicted[:, : self.keep_samples]
            own = kept - mean[:, None, :]
            for array in (errors, scores, own):
                array.flags.writeable = False
            self._scores[k - 1].append(scores)
            realised.append(Realisation(k, self.step, errors, scores, own, predicted.shape[1]))
        stored = np.array(points[:, :, : self.horizon], dtype=np.float64)
        self._pending.append((self.step, stored))
        self.step += 1
        return tuple(sorted(realised, key=lambda r: r.lookahead))

    def scores(self, lookahead: int) -> np.ndarray:
        """All kept scores at ``lookahead`` (chronological, pooled over obstacles), m."""
        k = _count("lookahead", lookahead)
        if k > self.horizon:
            raise InvalidParameterError(f"lookahead must be in 1..{self.horizon}, got {k}")
        kept = self._scores[k - 1]
        return np.concatenate(list(kept)) if kept else np.zeros(0)


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
        self.horizon = _count("horizon", horizon)
        self.window = _count("window", window)
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
        k = _count("lookahead", lookahead)
        if k > self.horizon:
            raise InvalidParameterError(f"lookahead must be in 1..{self.horizon}, got {k}")
        return k - 1


def _directions(dim: int, count: int) -> np.ndarray:
    """Unit directions: ``[[1]]`` for ``d = 1``; ``count`` evenly spaced on a half circle for 2."""
    if dim == 1:
        return np.ones((1, 1))
    if dim == 2:
        angles = np.pi * np.arange(count) / count
        return np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    raise InvalidArrayError(f"WassersteinRadius supports d = 1 or 2 positions, got d = {dim}")


def _grid_slack(dim: int, count: int) -> float:
    """Largest :math:`\\lVert h - h_m \\rVert` from a unit ``h`` to the nearest ``±`` grid one."""
    return 0.0 if dim == 1 else 2.0 * math.sin(math.pi / (4.0 * count))


def sliced_wasserstein_max(a: object, b: object, directions: object) -> np.ndarray:
    """1-D Wasserstein-1 distances of the projections of two point clouds, one per direction.

    .. math::

        W_1(h_\\# \\hat P_a, h_\\# \\hat P_b) = \\int_0^1 |F_a^{-1}(u) - F_b^{-1}(u)|\\, du

    for the empirical laws of :math:`h \\cdot a_i` and :math:`h \\cdot b_j`, exactly
    (the quantile functions are step functions on the merged grid
    :math:`\\{i/n_a\\} \\cup \\{j/n_b\\}`), vectorised over directions.

    Parameters
    ----------
    a, b
        Points, shapes ``(n_a, d)`` and ``(n_b, d)``, ``n_a, n_b >= 1``.
    directions
        Unit directions ``(M, d)``.

    Returns
    -------
    numpy.ndarray
        Shape ``(M,)``, in the units of the points.

    Raises
    ------
    InvalidArrayError
        For empty, non-finite or mismatched arrays.
    """
    pa = finite_array("a", a, ndim=2)
    pb = finite_array("b", b, ndim=2)
    h = finite_array("directions", directions, ndim=2)
    if pa.shape[0] == 0 or pb.shape[0] == 0 or not (pa.shape[1] == pb.shape[1] == h.shape[1]):
        raise InvalidArrayError(
            f"a, b and directions must be (n_a, d), (n_b, d), (M, d) with n >= 1, got "
            f"{pa.shape}, {pb.shape}, {h.shape}"
        )
    return _sliced_w1(pa, pb, h)


def _sliced_w1(a: np.ndarray, b: np.ndarray, directions: np.ndarray) -> np.ndarray:
    na, nb = a.shape[0], b.shape[0]
    qa = np.sort(directions @ a.T, axis=1)  # (M, na), sorted projections
    qb = np.sort(directions @ b.T, axis=1)
    grid = np.union1d(np.arange(1, na + 1) / na, np.arange(1, nb + 1) / nb)
    widths = np.diff(grid, prepend=0.0)
    mids = grid - 0.5 * widths
    ia = np.minimum((mids * na).astype(np.int64), na - 1)
    ib = np.minimum((mids * nb).astype(np.int64), nb - 1)
    return np.abs(qa[:, ia] - qb[:, ib]) @ widths


def _bootstrap_fluctuation(
    points: np.ndarray, directions: np.ndarray, n_boot: int, level: float, rng: np.random.Generator
) -> float:
    """Bootstrap quantile at ``level`` of :math:`\\sup_h \\sqrt{n}\\, W_1(h_\\#\\hat P_n, h_\\# P)`.

    On :math:`[y_{(j)}, y_{(j+1)})` the bootstrapped empirical process is
    :math:`n^{-1/2}(S_j - \\tfrac{j}{n} S_n)`, :math:`S_j` the partial sums of i.i.d.
    :math:`N(0, 1)` multipliers in the sorted order of the projections; the same
    multipliers serve every direction, so the supremum is taken jointly.
    """
    n = points.shape[0]
    if n < 2:
        return math.inf
    proj = points @ directions.T  # (n, M)
    order = np.argsort(proj, axis=0)
    gaps = np.diff(np.take_along_axis(proj, order, axis=0), axis=0)  # (n - 1, M)
    g = rng.standard_normal((n_boot, n))
    partial = np.cumsum(g[:, order], axis=1)[:, :-1, :]  # (B, n - 1, M)
    fraction = (np.arange(1, n) / n)[None, :, None]
    bridge = np.abs(partial - fraction * g.sum(axis=1)[:, None, None])
    stat = np.einsum("bjm,jm->bm", bridge, gaps) / math.sqrt(n)  # ~ sqrt(n) W1, per direction
    return float(np.quantile(stat.max(axis=1), level))


class WassersteinRadius:
    """Data-driven Wasserstein radii :math:`\\epsilon_k` for DR-CVaR, one per look-ahead.

    What the radius must cover. With unbounded support and the 2-norm cost, the
    DR-CVaR halfspace (:math:`\\mathrm{CVaR}_\\alpha(-h\\cdot p) + \\epsilon/\\alpha`) equals the
    worst :math:`\\mathrm{CVaR}_\\alpha` over the 1-D laws within :math:`W_1` distance
    :math:`\\epsilon` of the projected samples :math:`h_\\# \\hat P_t` (a 1-D perturbation lifts
    to a d-D one along :math:`h` at the same cost). So the bound holds at step ``t``
    whenever :math:`\\sup_{\\lVert h \\rVert = 1} W_1(h_\\# Q_t, h_\\# \\hat P_t) \\le \\epsilon_k`,
    :math:`Q_t` the law of the realised position. Writing both around the sample mean
    (predicted errors :math:`\\xi = \\hat p - \\hat\\mu`, realised error
    :math:`e = p - \\hat\\mu`; :math:`W_1` is translation invariant) and using the triangle
    inequality,

    .. math::

        \\epsilon_k = \\underbrace{\\max_m W_1(h_{m\\#} \\hat E_n, h_{m\\#} \\hat\\Xi) +
        2\\sin\\tfrac{\\pi}{4M}\\,
        (\\overline{\\lVert e \\rVert} + \\overline{\\lVert \\xi \\rVert})}_{D_k}
        + \\frac{c_E}{\\sqrt n} + c_\\Xi\\Big(\\frac{1}{\\sqrt{N_s}} + \\frac{1}{\\sqrt{m}}\\Big),

    with :math:`\\hat E_n` the last ``n <= window`` realised errors at look-ahead ``k``
    (pooled over obstacles), :math:`\\hat\\Xi` a pool of ``m <= max_predicted``
    predicted errors at ``k``, :math:`h_m` ``M = n_directions`` directions on the half
    circle, and :math:`c_E`, :math:`c_\\Xi` the ``(1 + confidence)/2``-quantiles of
    :math:`\\sup_h \\sqrt{n} W_1(h_\\# \\hat E_n, h_\\# E)` (and the same for :math:`\\hat\\Xi`),
    estimated by a multiplier bootstrap of the empirical process (joint over the
    directions). The first term is the sliced distance between the data, the second
    the finite-sample fluctuation of the realised errors, the third that of the
    filter's own ``N_s`` samples (and of the pool) around the predictor's law.

    What is guaranteed and what is heuristic.

    * Exact: :math:`D_k \\ge \\sup_{\\lVert h \\rVert = 1} W_1(h_\\#\\hat E_n, h_\\#\\hat\\Xi)`
      for the
      two empirical laws (the map :math:`h \\mapsto W_1(h_\\# P, h_\\# Q)` is Lipschitz with
      constant :math:`E_P\\lVert \\cdot \\rVert + E_Q\\lVert \\cdot \\rVert`, and every unit ``h``
      is within :math:`2\\sin(\\pi/4M)` of a grid direction up to sign); the reduction
      of DR-CVaR to the projected 1-D ball.
    * Heuristic: the finite-sample terms rely on the bootstrap approximating the law
      of :math:`\\sqrt n W_1` (valid asymptotically when
      :math:`\\int \\sqrt{F(1-F)} < \\infty`, del Barrio, Giné & Matrán 1999; no finite-n
      constant), evaluated on the grid directions only; and the whole construction
      assumes the errors at look-ahead ``k`` are stationary in time and exchangeable
      across obstacles and steps (a drifting or time-varying predictor breaks it;
      nothing here adapts like ACI does). Consecutive errors at one look-ahead overlap
      in time and are correlated, which the bootstrap ignores. With these caveats,
      ``confidence`` is the intended probability that the realised law at a step lies
      in the ball.

    Parameters
    ----------
    horizon
        ``T``.
    confidence
        Intended coverage in :math:`(0, 1)` (default 0.9).
    window
        Realised errors kept per look-ahead (default 200, pooled over obstacles).
    max_predicted
        Predicted errors kept per look-ahead (default 1000).
    n_directions
        Grid directions ``M`` on the half circle for ``d = 2`` (default 32).
    n_bootstrap
        Bootstrap draws (default 50). The bootstrap uses every other grid direction
        when ``n_directions >= 16``.
    refresh
        Recompute the radius of a look-ahead after this many updates of it (default
        10; ``1``: after every update). The radius is piecewise constant in between
        (a few ms per look-ahead per recomputation at the defaults).
    bootstrap_refresh
        Recompute the bootstrap constants :math:`c_E, c_\\Xi` of a look-ahead after this
        many updates of it (default 100; they scale with the spread of the errors,
        which changes slowly, and cost ~10 ms per look-ahead).
    min_errors
        Realised errors needed at a look-ahead before the radius is estimated (default 10).
    fallback
        Radius (m) before that: ``>= 0`` (default ``math.inf``, which
        :func:`filters.safe_halfspaces` rejects; a filter passes a finite value, e.g.
        the hand-tuned 0.05 m).
    seed
        Seed of the bootstrap's generator (or a :class:`numpy.random.Generator`).

    Raises
    ------
    InvalidParameterError
        For a parameter outside its domain.
    """

    def __init__(
        self,
        *,
        horizon: int,
        confidence: float = 0.9,
        window: int = 200,
        max_predicted: int = 1000,
        n_directions: int = 32,
        n_bootstrap: int = 50,
        refresh: int = 10,
        bootstrap_refresh: int = 100,
        min_errors: int = 10,
        fallback: float = math.inf,
        seed: int | np.random.Generator = 0,
    ) -> None:
        self.horizon = _count("horizon", horizon)
        self.confidence = scalar_in_range(
            "confidence", confidence, low=0.0, high=1.0, low_inclusive=False,
            high_inclusive=False,
        )
        self.window = _count("window", window)
        self.max_predicted = _count("max_predicted", max_predicted)
        self.n_directions = _count("n_directions", n_directions)
        self.n_bootstrap = _count("n_bootstrap", n_bootstrap, low=10)
        self.refresh = _count("refresh", refresh)
        self.bootstrap_refresh = _count("bootstrap_refresh", bootstrap_refresh)
        self.min_errors = _count("min_errors", min_errors, low=2)
        self.fallback = scalar_in_range("fallback", fallback, low=0.0)
        self._rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        self._errors: list[deque[np.ndarray]] = [deque() for _ in range(self.horizon)]
        self._predicted: list[deque[np.ndarray]] = [deque() for _ in range(self.horizon)]
        self._n_errors = np.zeros(self.horizon, dtype=np.int64)
        self._n_predicted = np.zeros(self.horizon, dtype=np.int64)
        self._n_samples = np.zeros(self.horizon, dtype=np.int64)  # N_s of the centre
        self._cache: list[float | None] = [None] * self.horizon
        self._constants: list[tuple[float, float] | None] = [None] * self.horizon
        self._since = np.zeros(self.horizon, dtype=np.int64)  # updates since the radius
        self._since_bootstrap = np.zeros(self.horizon, dtype=np.int64)
        self._dim: int | None = None

    def update_errors(
        self,
        lookahead: int,
        errors: object,
        predicted_errors: object,
        *,
        n_samples: int | None = None,
    ) -> None:
        """Add realised errors ``(n, d)``, predicted errors ``(m, d)`` or ``(n, m, d)`` at ``k``.

        ``n_samples`` is ``N_s``, the number of samples of the filter's empirical law
        (default: the number of predicted errors per obstacle given).

        Raises
        ------
        InvalidArrayError
            For non-finite or mismatched arrays, or ``d`` not 1 or 2.
        """
        k = self._index(lookahead)
        e = finite_array("errors", errors, ndim=2)
        xi = finite_array("predicted_errors", predicted_errors)
        per_obstacle = xi.shape[-2] if xi.ndim == 3 else xi.shape[0]
        if xi.ndim == 3:
            xi = xi.reshape(-1, xi.shape[-1])
        if xi.ndim != 2 or xi.shape[1] != e.shape[1] or xi.shape[0] == 0:
            raise InvalidArrayError(
                f"predicted_errors must have shape (m, {e.shape[1]}) or (n, m, {e.shape[1]}) "
                f"with m >= 1, got {np.shape(predicted_errors)}"
            )
        if self._dim is None:
            _directions(e.shape[1], 1)  # rejects d > 2
            self._dim = e.shape[1]
        elif e.shape[1] != self._dim:
            raise InvalidArrayError(f"errors must have d = {self._dim}, got shape {e.shape}")
        size = per_obstacle if n_samples is None else _count("n_samples", n_samples)
        self._n_samples[k] = size if self._n_samples[k] == 0 else min(self._n_samples[k], size)
        self._push(self._errors[k], e, self._n_errors, k, self.window)
        self._push(self._predicted[k], xi, self._n_predicted, k, self.max_predicted)
        self._since[k] += 1
        self._since_bootstrap[k] += 1
        if self._since[k] >= self.refresh:
            self._cache[k] = None

    @staticmethod
    def _push(buffer: deque, rows: np.ndarray, counts: np.ndarray, k: int, cap: int) -> None:
        buffer.append(rows[-cap:])
        counts[k] += min(rows.shape[0], cap)
        while counts[k] - buffer[0].shape[0] >= cap:
            counts[k] -= buffer.popleft().shape[0]

    def update(self, realisations: tuple[Realisation, ...] | list[Realisation]) -> None:
        """Feed the output of :meth:`PredictionRecord.update` (look-aheads beyond ``T`` skipped)."""
        for r in realisations:
            if r.lookahead <= self.horizon:
                self.update_errors(r.lookahead, r.errors, r.predicted_errors,
                                   n_samples=r.n_samples)

    def radius(self, lookahead: int) -> float:
        """:math:`\\epsilon_k` in m (``fallback`` with fewer than ``min_errors`` errors)."""
        k = self._index(lookahead)
        if self._n_errors[k] < self.min_errors:
            return self.fallback
        cached = self._cache[k]
        if cached is not None:
            return cached
        self._since[k] = 0
        errors = np.concatenate(list(self._errors[k]))[-self.window :]
        predicted = np.concatenate(list(self._predicted[k]))[-self.max_predicted :]
        dim = errors.shape[1]
        directions = _directions(dim, self.n_directions)
        distance = float(_sliced_w1(errors, predicted, directions).max())
        mean_norms = (np.linalg.norm(errors, axis=1).mean()
                      + np.linalg.norm(predicted, axis=1).mean())
        distance += _grid_slack(dim, self.n_directions) * float(mean_norms)
        if self._constants[k] is None or self._since_bootstrap[k] >= self.bootstrap_refresh:
            level = 0.5 * (1.0 + self.confidence)
            boot = directions[::2] if directions.shape[0] >= 16 else directions
            c_e = _bootstrap_fluctuation(errors, boot, self.n_bootstrap, level, self._rng)
            pool = predicted[-200:]  # the limit law does not depend on the sample size
            c_xi = _bootstrap_fluctuation(pool, boot, self.n_bootstrap, level, self._rng)
            self._constants[k] = (c_e, c_xi)
            self._since_bootstrap[k] = 0
        c_e, c_xi = self._constants[k]
        n, m, n_s = errors.shape[0], predicted.shape[0], int(self._n_samples[k])
        value = distance + c_e / math.sqrt(n) + c_xi * (1.0 / math.sqrt(n_s) + 1.0 / math.sqrt(m))
        self._cache[k] = value
        return value

    def radii(self) -> np.ndarray:
        """Radii for every look-ahead, shape ``(T,)``, m (``epsilon=`` of ``safe_halfspaces``)."""
        return np.array([self.radius(k) for k in range(1, self.horizon + 1)])

    def _index(self, lookahead: int) -> int:
        k = _count("lookahead", lookahead)
        if k > self.horizon:
            raise InvalidParameterError(f"lookahead must be in 1..{self.horizon}, got {k}")
        return k - 1


class OnlineCalibration:
    """A :class:`PredictionRecord` feeding a :class:`ConformalMargin` and a Wasserstein radius.

    The one object a filter wrapper needs for ``risk="conformal"`` and
    ``epsilon="auto"``: call :meth:`reset` at each episode start (it drops the pending
    predictions only: the calibration itself carries over between episodes) and
    :meth:`update` with every new set of predictions and realised positions (after
    reset and after each step), then read :meth:`margins` / :meth:`radii` for the
    halfspaces of this step.

    Split-conformal practice (what :class:`filters.SafetyFilterWrapper` does with its
    ``calibration_episodes``): feed held-out episodes first, keep a copy
    (:meth:`copy`; the bootstrap generator's state included) and start every episode
    from a fresh copy of it, so that an episode depends on its own data only.

    Parameters
    ----------
    horizon
        ``T``.
    alpha
        Target miscoverage of the conformal margins, in :math:`(0, 1)`.
    margin_fallback, radius_fallback
        Values before enough data (m), see :class:`ConformalMargin` and
        :class:`WassersteinRadius`. Defaults: 1.0 m and the paper's 0.05 m, both finite
        so that :func:`filters.safe_halfspaces` accepts them from the first step.
    keep_samples
        Predicted errors kept per obstacle and step (default 20); see
        :class:`PredictionRecord`.
    conformal, wasserstein
        Extra keyword arguments of :class:`ConformalMargin` / :class:`WassersteinRadius`
        (e.g. ``{"gamma": 0.01}``, ``{"confidence": 0.95, "seed": 1}``).
    """

    def __init__(
        self,
        horizon: int,
        alpha: float,
        *,
        margin_fallback: float | str = 1.0,
        radius_fallback: float = 0.05,
        keep_samples: int = 20,
        conformal: dict | None = None,
        wasserstein: dict | None = None,
    ) -> None:
        self.record = PredictionRecord(horizon, keep_samples=keep_samples)
        self.conformal = ConformalMargin(alpha, horizon=horizon, fallback=margin_fallback,
                                         **(conformal or {}))
        self.wasserstein = WassersteinRadius(horizon=horizon, fallback=radius_fallback,
                                             **(wasserstein or {}))

    def reset(self) -> None:
        """Start a new episode: pending predictions are dropped, the calibration kept."""
        self.record.reset()

    def copy(self) -> OnlineCalibration:
        """An independent copy: equal to :func:`copy.deepcopy`, faster.

        The arrays kept in the record and the radius's buffers are never written after
        they are stored, so the copy shares them; every container, counter, level and
        the bootstrap generator's state is copied, so updating one copy never changes
        the other.
        """
        shared: dict[int, object] = {}
        for _, samples in self.record._pending:
            shared[id(samples)] = samples
        for buffers in (self.record._scores, self.wasserstein._errors,
                        self.wasserstein._predicted):
            for buffer in buffers:
                for array in buffer:
                    shared[id(array)] = array
        return copy.deepcopy(self, shared)

    def update(
        self, samples: object, realised_positions: object, present: object | None = None
    ) -> tuple[Realisation, ...]:
        """Record this step (see :meth:`PredictionRecord.update`) and update both estimators.

        ``present`` is an optional boolean mask ``(n_rows,)`` selecting the real
        obstacles of padded arrays (``info["obstacle_present"]``).
        """
        if present is not None:
            mask = np.asarray(present, dtype=bool)
            samples = np.asarray(samples)[mask]
            realised_positions = np.asarray(realised_positions)[mask]
        realised = self.record.update(samples, realised_positions)
        self.conformal.update(realised)
        self.wasserstein.update(realised)
        return realised

    def margins(self) -> np.ndarray:
        """Conformal margins ``(T,)``, m (``conformal_margins=``)."""
        return self.conformal.margins()

    def radii(self) -> np.ndarray:
        """Wasserstein radii ``(T,)``, m (``epsilon=``)."""
        return self.wasserstein.radii()

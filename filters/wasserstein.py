"""Data-driven Wasserstein radii per look-ahead step for ``risk="dr_cvar"``.

:class:`WassersteinRadius` turns the realised and predicted errors of
:class:`filters.prediction_record.PredictionRecord` into a radius :math:`\\epsilon_k`
per look-ahead (``epsilon`` of shape ``(T,)`` of :func:`filters.safe_halfspaces`), from
the sliced Wasserstein-1 distance (:func:`sliced_wasserstein_max`) and a bootstrap of
its finite-sample fluctuation. Every random draw (the bootstrap) comes from a seeded
:class:`numpy.random.Generator`.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from filters._validation import finite_array, integer_at_least, lookahead_index, scalar_in_range
from filters.errors import InvalidArrayError

if TYPE_CHECKING:
    from filters.prediction_record import Realisation

__all__ = ["WassersteinRadius", "sliced_wasserstein_max"]


def grid_directions(
    dim: int, count: int, caller: str, *, full: bool = False
) -> tuple[np.ndarray, float]:
    """Unit directions of a grid and its slack, for ``d = 1`` or ``2`` positions.

    ``full=False``: ``[[1]]`` for ``d = 1``, else ``count`` directions evenly spaced on
    the half circle, :math:`\\theta_m = \\pi m / M` (a grid up to sign); ``full=True``:
    ``[[1], [-1]]``, else ``count`` on the full circle, :math:`\\theta_m = 2\\pi m / M`.
    The slack is the largest distance :math:`\\lVert h - h_m \\rVert` from a unit ``h`` to
    the nearest grid direction (up to sign for the half circle): 0 for ``d = 1``, else
    :math:`2 \\sin(\\pi / 4M)` (half) or :math:`2 \\sin(\\pi / 2M)` (full).

    Raises
    ------
    InvalidArrayError
        For ``d`` other than 1 or 2 (``caller`` names who asked).
    """
    if dim == 1:
        return (np.array([[1.0], [-1.0]]) if full else np.ones((1, 1))), 0.0
    if dim != 2:
        raise InvalidArrayError(f"{caller} supports d = 1 or 2 positions, got d = {dim}")
    span = 2.0 * np.pi if full else np.pi
    angles = span * np.arange(count) / count
    return np.stack([np.cos(angles), np.sin(angles)], axis=-1), 2.0 * math.sin(span / (4 * count))


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
    a, b, h = (finite_array(name, value, ndim=2) for name, value in
               (("a", a), ("b", b), ("directions", directions)))
    if a.shape[0] == 0 or b.shape[0] == 0 or not (a.shape[1] == b.shape[1] == h.shape[1]):
        raise InvalidArrayError(
            f"a, b and directions must be (n_a, d), (n_b, d), (M, d) with n >= 1, got "
            f"{a.shape}, {b.shape}, {h.shape}")
    return _sliced_w1(a, b, h)


def _sliced_w1(a: np.ndarray, b: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """:func:`sliced_wasserstein_max` on checked arrays."""
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

    def __init__(self, *, horizon: int, confidence: float = 0.9, window: int = 200,
                 max_predicted: int = 1000, n_directions: int = 32, n_bootstrap: int = 50,
                 refresh: int = 10, bootstrap_refresh: int = 100, min_errors: int = 10,
                 fallback: float = math.inf, seed: int | np.random.Generator = 0) -> None:
        self.horizon = T = integer_at_least("horizon", horizon)
        self.confidence = scalar_in_range("confidence", confidence, low=0.0, high=1.0,
                                          low_inclusive=False, high_inclusive=False)
        for name, value, low in (("window", window, 1), ("max_predicted", max_predicted, 1),
                                 ("n_directions", n_directions, 1), ("refresh", refresh, 1),
                                 ("n_bootstrap", n_bootstrap, 10), ("min_errors", min_errors, 2),
                                 ("bootstrap_refresh", bootstrap_refresh, 1)):
            setattr(self, name, integer_at_least(name, value, low=low))
        self.fallback = scalar_in_range("fallback", fallback, low=0.0)
        self._rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        # The last `window` realised and `max_predicted` predicted errors per look-ahead, (n, d)
        # arrays replaced, never written in place (OnlineCalibration.copy shares them).
        self._errors, self._predicted = ([np.zeros((0, 0))] * T for _ in range(2))  # d: set later
        # N_s of the centre, updates since the radius / bootstrap
        self._n_samples, self._since, self._since_bootstrap = (
            np.zeros(T, dtype=np.int64) for _ in range(3))
        self._cache: list[float | None] = [None] * T
        self._constants: list[tuple[float, float] | None] = [None] * T
        self._dim: int | None = None

    def update_errors(self, lookahead: int, errors: object, predicted_errors: object, *,
                      n_samples: int | None = None) -> None:
        """Add realised errors ``(n, d)``, predicted errors ``(m, d)`` or ``(n, m, d)`` at ``k``.

        ``n_samples`` is ``N_s``, the number of samples of the filter's empirical law
        (default: the number of predicted errors per obstacle given).

        Raises
        ------
        InvalidArrayError
            For non-finite or mismatched arrays, or ``d`` not 1 or 2.
        """
        k = lookahead_index(lookahead, self.horizon)
        e = finite_array("errors", errors, ndim=2)
        xi = finite_array("predicted_errors", predicted_errors)
        per_obstacle = xi.shape[-2] if xi.ndim >= 2 else 0
        xi = xi.reshape(-1, xi.shape[-1]) if xi.ndim == 3 else xi
        if xi.ndim != 2 or xi.shape[1] != e.shape[1] or xi.shape[0] == 0:
            raise InvalidArrayError(
                f"predicted_errors must have shape (m, {e.shape[1]}) or (n, m, {e.shape[1]}) "
                f"with m >= 1, got {np.shape(predicted_errors)}")
        if self._dim is None:
            grid_directions(e.shape[1], 1, "WassersteinRadius")  # rejects d > 2
            self._dim = e.shape[1]
            self._errors, self._predicted = ([np.zeros((0, self._dim))] * self.horizon
                                             for _ in range(2))
        elif e.shape[1] != self._dim:
            raise InvalidArrayError(f"errors must have d = {self._dim}, got shape {e.shape}")
        size = per_obstacle if n_samples is None else integer_at_least("n_samples", n_samples)
        self._n_samples[k] = size if self._n_samples[k] == 0 else min(self._n_samples[k], size)
        self._errors[k] = np.concatenate([self._errors[k], e])[-self.window :]
        self._predicted[k] = np.concatenate([self._predicted[k], xi])[-self.max_predicted :]
        self._since[k] += 1
        self._since_bootstrap[k] += 1  # (the cache is dropped after `refresh` updates)
        if self._since[k] >= self.refresh:
            self._cache[k] = None

    def update(self, realisations: tuple[Realisation, ...] | list[Realisation]) -> None:
        """Feed the output of :meth:`PredictionRecord.update` (look-aheads beyond ``T`` skipped)."""
        for r in realisations:
            if r.lookahead <= self.horizon:
                self.update_errors(r.lookahead, r.errors, r.predicted_errors, n_samples=r.n_samples)

    def radius(self, lookahead: int) -> float:
        """:math:`\\epsilon_k` in m (``fallback`` with fewer than ``min_errors`` errors)."""
        k = lookahead_index(lookahead, self.horizon)
        if len(self._errors[k]) < self.min_errors:
            return self.fallback
        if self._cache[k] is not None:
            return self._cache[k]
        self._since[k] = 0
        errors, predicted = self._errors[k], self._predicted[k]
        directions, slack = grid_directions(errors.shape[1], self.n_directions, "WassersteinRadius")
        mean_norms = float(np.linalg.norm(errors, axis=1).mean()
                           + np.linalg.norm(predicted, axis=1).mean())
        distance = float(_sliced_w1(errors, predicted, directions).max()) + slack * mean_norms
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

"""The prediction record: issued prediction samples matched with the realised positions.

:class:`PredictionRecord` keeps the samples issued over the last ``T`` steps and returns
one :class:`Realisation` per look-ahead ``k`` when the realised position for a predicted
time arrives: the scores of :class:`filters.conformal.ConformalMargin` and the errors of
:class:`filters.wasserstein.WassersteinRadius` (chained by
:class:`filters.calibration.OnlineCalibration`).

Timeline (one call of :meth:`PredictionRecord.update` per control step ``t``): the
environment reports the realised positions :math:`p_t` (``(n_obs, d)``) and samples
:math:`\\hat p^{(j)}_{t+k}`, ``k = 1..T``. The samples issued at :math:`t - k` for
look-ahead ``k`` are compared with :math:`p_t`, obstacle by obstacle:

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

Which row is which obstacle: by default row ``i`` is the same obstacle at every step.
Where rows change hands (the ``K`` nearest pedestrians of a recorded scene fill ``K``
slots, and a slot passes to a newcomer), the caller passes ``ids``: one identity per row,
negative for an empty row. A prediction issued for obstacle ``n`` is then compared with
the position of obstacle ``n`` only, wherever its row is now; an obstacle that has left,
and an empty row, give no score.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from filters._validation import finite_array, integer_at_least, lookahead_index
from filters.errors import InvalidArrayError

__all__ = ["PredictionRecord", "Realisation"]


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
    ids
        Identity of each scored obstacle, ``(n_obs,)`` (the row index when the caller
        gave no ``ids``).
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
    ids: np.ndarray | None = None


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

    def __init__(self, horizon: int, *, keep_samples: int | None = None,
                 memory: int = 10_000) -> None:
        self.horizon = integer_at_least("horizon", horizon)
        self.keep_samples = keep_samples if keep_samples is None else integer_at_least(
            "keep_samples", keep_samples)
        self.memory = integer_at_least("memory", memory)
        T = self.horizon
        self._pending: deque[tuple[int, np.ndarray, np.ndarray]] = deque(maxlen=T)
        self._scores: list[deque[np.ndarray]] = [deque(maxlen=self.memory) for _ in range(T)]
        self.step = 0

    def reset(self) -> None:
        """Forget the pending predictions (call at an episode boundary); keep the scores."""
        self._pending.clear()

    def update(
        self, samples: object, realised_positions: object, ids: object | None = None
    ) -> tuple[Realisation, ...]:
        """Match ``realised_positions`` with earlier predictions, then store ``samples``.

        Parameters
        ----------
        samples
            Predictions issued now for steps ``t+1..t+T'``, shape
            ``(n_obs, N_s, T', d)`` with ``T' >= 1`` (only the first ``T`` steps are kept), m.
        realised_positions
            Positions realised now, :math:`p_t`, shape ``(n_obs, d)``, m.
        ids
            Identity of the obstacle in each row, integers ``(n_obs,)``, distinct among
            the rows ``>= 0``; a negative id marks an empty row (neither scored nor
            stored). ``None``: row ``i`` is obstacle ``i`` at every step.

        Returns
        -------
        tuple of Realisation
            One per look-ahead ``k`` whose prediction (issued ``k`` steps ago, in this
            episode) is realised now for at least one obstacle, in increasing ``k``;
            empty on the first call.

        Raises
        ------
        InvalidArrayError
            If an array has the wrong shape or holds NaN/inf, ``ids`` repeats an id or
            has the wrong shape, or (without ``ids``) the obstacle count or dimension
            changed without :meth:`reset`.
        """
        points = finite_array("samples", samples, ndim=4)
        positions = finite_array("realised_positions", realised_positions, ndim=2)
        n_obs, n_samples, steps, dim = points.shape
        if n_samples == 0 or steps == 0:
            raise InvalidArrayError(
                f"samples must hold at least one sample and one step, got shape {points.shape}")
        if positions.shape != (n_obs, dim):
            raise InvalidArrayError(f"realised_positions must have shape ({n_obs}, {dim}) to "
                                    f"match samples {points.shape}, got {positions.shape}")
        identities = np.arange(n_obs) if ids is None else _identities(ids, n_obs)
        if self._pending:
            old = self._pending[-1][1].shape
            if old[3] != dim or (ids is None and old[0] != n_obs):
                raise InvalidArrayError(
                    f"samples have shape {points.shape} but the pending ones {old}: the "
                    "obstacle count or dimension changed; call reset() at an episode boundary "
                    "(or pass ids)")
        if not (occupied := identities >= 0).all():
            points, positions, identities = (points[occupied], positions[occupied],
                                             identities[occupied])  # the occupied rows only
        realised = []
        for issued, old, old_ids in reversed(self._pending):  # newest first: k = 1, 2, ...
            k = self.step - issued
            if k > old.shape[2]:
                continue
            now, rows = positions, slice(None)
            if not np.array_equal(identities, old_ids):  # pair obstacle by obstacle
                _, rows, current = np.intersect1d(old_ids, identities, assume_unique=True,
                                                  return_indices=True)
                now = positions[current]
            predicted = old[rows, :, k - 1]  # (n_obs, N_s, d)
            if predicted.shape[0] == 0:  # nobody to score (every row empty)
                continue
            mean = predicted.mean(axis=1)
            errors = now - mean
            scores = np.sqrt((errors * errors).sum(axis=-1))
            own = predicted[:, : self.keep_samples] - mean[:, None, :]  # (None: all)
            scored = old_ids[rows]
            for array in (errors, scores, own, scored):
                array.flags.writeable = False
            self._scores[k - 1].append(scores)
            realised.append(Realisation(k, self.step, errors, scores, own, predicted.shape[1],
                                        scored))
        stored = np.array(points[:, :, : self.horizon], dtype=np.float64)
        self._pending.append((self.step, stored, identities))
        self.step += 1
        return tuple(sorted(realised, key=lambda r: r.lookahead))

    def scores(self, lookahead: int) -> np.ndarray:
        """All kept scores at ``lookahead`` (chronological, pooled over obstacles), m."""
        kept = self._scores[lookahead_index(lookahead, self.horizon)]
        return np.concatenate(list(kept)) if kept else np.zeros(0)


def _identities(ids: object, n_obs: int) -> np.ndarray:
    """``ids`` as a read-only int64 array ``(n_obs,)``, distinct among the values ``>= 0``."""
    array = np.asarray(ids)
    if array.shape != (n_obs,) or not (array.size == 0 or np.issubdtype(array.dtype, np.integer)):
        raise InvalidArrayError(
            f"ids must be {n_obs} integers (one per row, negative: empty row), got {ids!r}")
    identities = array.astype(np.int64)
    occupied = identities[identities >= 0]
    if np.unique(occupied).size != occupied.size:
        raise InvalidArrayError(f"ids must be distinct among the occupied rows, got {ids!r}")
    identities.flags.writeable = False
    return identities

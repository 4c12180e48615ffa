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
* :class:`AdaptiveRadius`: per look-ahead, DR-CVaR's radius from a conformal quantile
  (with ACI) of the radii the realisations needed (``adaptive_epsilon=True``).
* :class:`OnlineCalibration` (this module) chains the three for a filter wrapper.

No gym or environment import: the inputs are plain arrays. Every random draw (the
bootstrap of :class:`WassersteinRadius`) comes from a seeded
:class:`numpy.random.Generator`.

The timeline of a record and why the score is Euclidean: :mod:`filters.prediction_record`.
The pieces live in :mod:`filters.prediction_record`, :mod:`filters.conformal` and
:mod:`filters.wasserstein`; they stay importable from here.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np

from filters.conformal import AdaptiveRadius, ConformalMargin, conformal_rank, dr_cvar_scores
from filters.errors import InvalidArrayError, InvalidParameterError
from filters.prediction_record import PredictionRecord, Realisation
from filters.wasserstein import WassersteinRadius, sliced_wasserstein_max

__all__ = ["AdaptiveRadius", "ConformalMargin", "OnlineCalibration", "PredictionRecord",
           "Realisation", "WassersteinRadius", "conformal_rank", "dr_cvar_scores",
           "sliced_wasserstein_max"]


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
    adaptive_alpha
        If given, the CVaR tail mass of an :class:`AdaptiveRadius` (fallback
        ``radius_fallback``) fed as well, read by :meth:`adaptive_radii`; the record then
        keeps every sample (the scores need the CVaR of all ``N_s``), and the
        Wasserstein radius still gets the first ``keep_samples``.
    adaptive
        Extra keyword arguments of :class:`AdaptiveRadius` (e.g. ``{"gamma": 0.01}``).
    """

    def __init__(self, horizon: int, alpha: float, *, margin_fallback: float | str = 1.0,
                 radius_fallback: float = 0.05, keep_samples: int = 20,
                 conformal: dict | None = None, wasserstein: dict | None = None,
                 adaptive_alpha: float | None = None, adaptive: dict | None = None) -> None:
        self.keep_samples = keep_samples
        self.adaptive = None if adaptive_alpha is None else AdaptiveRadius(
            adaptive_alpha, horizon=horizon, fallback=radius_fallback, **(adaptive or {}))
        self.record = PredictionRecord(
            horizon, keep_samples=keep_samples if self.adaptive is None else None)
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
        shared = [pending[1] for pending in self.record._pending]
        shared += [array for buffer in self.record._scores for array in buffer]
        shared += self.wasserstein._errors + self.wasserstein._predicted
        return copy.deepcopy(self, {id(array): array for array in shared})

    def update(self, samples: object, realised_positions: object, present: object | None = None,
               ids: object | None = None) -> tuple[Realisation, ...]:
        """Record this step (see :meth:`PredictionRecord.update`) and update both estimators.

        ``present`` is an optional boolean mask ``(n_rows,)`` selecting the real
        obstacles of padded arrays (``info["obstacle_present"]``); without ``ids``, row
        ``i`` of the padded arrays is then obstacle ``i`` at every step, so a prediction
        is never scored against another row's obstacle when the rows present change.
        ``ids`` (one integer per row, negative for an empty row) makes each prediction
        meet the realised position of its own obstacle when rows change hands (the slots
        of ``SafeNav/Pedestrians-v0``, ``env.unwrapped.obstacle_ids``).

        Raises
        ------
        InvalidArrayError
            As :meth:`PredictionRecord.update`, and if ``present`` is not one flag per row.
        """
        if present is not None:
            mask = np.asarray(present)
            samples, realised_positions = np.asarray(samples), np.asarray(realised_positions)
            if mask.dtype != bool or mask.shape != samples.shape[:1]:
                raise InvalidArrayError(
                    f"present must be {samples.shape[:1]} booleans (one per row of samples), "
                    f"got {present!r}")
            ids = np.arange(mask.size) if ids is None else np.asarray(ids)
            if ids.shape != mask.shape or realised_positions.shape[:1] != mask.shape:
                raise InvalidArrayError(
                    f"ids {ids.shape} and realised_positions {realised_positions.shape} must "
                    f"have one row per flag of present {mask.shape}")
            samples, realised_positions, ids = samples[mask], realised_positions[mask], ids[mask]
        realised = self.record.update(samples, realised_positions, ids)
        self.conformal.update(realised)
        kept = realised
        if self.adaptive is not None:  # the Wasserstein radius sees what it saw without it
            self.adaptive.update(realised)
            keep = self.keep_samples
            kept = [dataclasses.replace(r, predicted_errors=r.predicted_errors[:, :keep])
                    for r in realised]
        self.wasserstein.update(kept)
        return realised

    def margins(self) -> np.ndarray:
        """Conformal margins ``(T,)``, m (``conformal_margins=``)."""
        return self.conformal.margins()

    def radii(self) -> np.ndarray:
        """Wasserstein radii ``(T,)``, m (``epsilon=``)."""
        return self.wasserstein.radii()

    def adaptive_radii(self) -> np.ndarray:
        """Radii ``(T,)`` of the :class:`AdaptiveRadius`, m (``epsilon=``).

        Raises
        ------
        InvalidParameterError
            If this calibration was built without ``adaptive_alpha``.
        """
        if self.adaptive is None:
            raise InvalidParameterError(
                "adaptive_radii() needs an OnlineCalibration built with adaptive_alpha=...")
        return self.adaptive.radii()

"""Recorded-replay obstacle model: the ``K`` pedestrians nearest the ego, in fixed slots.

:class:`ReplayModel` stands in for :class:`~safe_nav_env.obstacles.ObstacleModel`
inside :class:`~safe_nav_env.env.SafeNavEnv` (same attributes and methods; it is what
:class:`~safe_nav_env.pedestrians.env.PedestrianEnv`'s ``_obstacle_model`` returns), so the
environment's dynamics, observation, reward, continuous-time collisions and the
safety-filter protocol work unchanged.

At recording step ``j`` (the episode's start step plus the steps taken) the
obstacles are the ``K`` pedestrians present at ``j`` nearest the ego (centre
distance). They sit in ``K`` fixed *slots*: a pedestrian keeps its slot while it
stays among the ``K`` nearest, a newcomer takes the lowest free slot (nearest
newcomer first), and a slot without a pedestrian is *absent*. An absent slot is
parked at a fixed point :data:`PARK_DISTANCE` m beyond the arena's upper corner, at
rest, with exact predictions, so that every array keeps ``K`` finite rows (the
safety filter and its calibration need a fixed count); :attr:`ReplayModel.present`
marks it, and the environment masks it in the observation and in ``info``
(:class:`~safe_nav_env.env.SafeNavEnv`).

Over one step, a slot's chord for the continuous-time collision check runs from its
pedestrian's own position at ``j - 1`` (at ``j`` for a pedestrian that appeared at
``j``) to its position at ``j``: never from one pedestrian to another.

Realised positions are the recording; the velocities and predictions come from the
positions at steps ``<= j`` only (:mod:`~safe_nav_env.pedestrians.forecast`,
:mod:`~safe_nav_env.pedestrians.residuals`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from safe_nav_env.pedestrians.forecast import NEW, Forecaster, headings, strata_of
from safe_nav_env.pedestrians.recording import Recording
from safe_nav_env.pedestrians.residuals import ResidualBank

__all__ = ["PARK_DISTANCE", "ReplayModel"]

PARK_DISTANCE = 100.0
"""Distance of the parking point of absent slots beyond the arena's upper corner, per axis, m."""


class ReplayModel:
    """State of the ``K`` obstacle slots over a replayed recording (see the module docstring).

    Parameters
    ----------
    recording
        The scene's tracks at the environment's ``dt``.
    forecaster, bank
        Nominal forecaster and residual bank of the predictions.
    max_obstacles
        Number of slots ``K``.
    radius
        Pedestrian radius, m.
    arena
        ``((x_min, y_min), (x_max, y_max))``, m; fixes the parking point.
    ego_position
        Called with no argument, returns the ego position ``(2,)`` used to pick the
        nearest pedestrians (the environment's, after its move).

    Attributes
    ----------
    n, radii, starts, initial_velocities
        As :class:`~safe_nav_env.obstacles.ObstacleModel`'s (``starts``: parked).
    positions, velocities
        Current slot positions (m) and estimated velocities (m/s), ``(K, 2)``.
    chord_starts
        Where each slot's chord over the last step starts, ``(K, 2)``, m.
    slots
        Pedestrian index per slot, ``-1`` when absent, ``(K,)``.
    start_step, step_count
        Recording step of the episode's start, steps taken since.
    """

    def __init__(self, recording: Recording, forecaster: Forecaster, bank: ResidualBank, *,
                 max_obstacles: int, radius: float,
                 arena: tuple[tuple[float, float], tuple[float, float]],
                 ego_position: Callable[[], np.ndarray]) -> None:
        self.recording = recording
        self.forecaster = forecaster
        self.bank = bank
        self.n = int(max_obstacles)
        self.radii = np.full(self.n, float(radius))
        self.radii.flags.writeable = False
        self.parked = np.asarray(arena[1], dtype=np.float64) + PARK_DISTANCE
        self.starts = np.tile(self.parked, (self.n, 1))
        self.initial_velocities = np.zeros((self.n, 2))
        self._ego_position = ego_position
        self._present = [np.flatnonzero(~np.isnan(row[:, 0])) for row in recording.positions]
        self.start_step = 0
        self.reset(None)  # the slots at step 0, as ObstacleModel starts at its reset state

    @property
    def present(self) -> np.ndarray:
        """Whether each slot holds a pedestrian, ``(K,)`` bool."""
        return self.slots >= 0

    @property
    def step_index(self) -> int:
        """Current recording step ``j``."""
        return self.start_step + self.step_count

    def pedestrians_at(self, step: int) -> tuple[np.ndarray, np.ndarray]:
        """Indices ``(m,)`` and positions ``(m, 2)`` of the pedestrians present at ``step``."""
        if not 0 <= step < self.recording.n_steps:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 2))
        index = self._present[step]
        return index, self.recording.positions[step, index]

    # ----------------------------------------------------------- ObstacleModel API

    def reset(self, rng: np.random.Generator | None) -> None:
        """Fill the slots at the start step (no randomness used; ``rng`` for the interface)."""
        self.step_count = 0
        self.slots = np.full(self.n, -1, dtype=np.int64)
        self._update(first=True)

    def step(self, rng: np.random.Generator, law: object = None) -> np.ndarray:
        """Advance one recording step; return the new slot positions ``(K, 2)``, m.

        ``rng`` and ``law`` are unused: the realised motion is the recording.
        """
        self.step_count += 1
        self._update(first=False)
        return self.positions

    def predict(
        self, rng: np.random.Generator, law: object, n_samples: int, horizon: int
    ) -> np.ndarray:
        """Prediction samples for steps ``j+1 .. j+T``, ``(K, N_s, T, 2)``, m.

        Nominal forecast from the window of positions up to ``j`` plus whole residual
        trajectories drawn from the bank with ``rng`` (for the occupied slots only);
        absent slots get their parking point in every sample. ``law`` is unused.
        """
        present = self.present
        if present.all():
            rows = slice(None)
        else:  # draw for the occupied slots only; the others are parked
            rows = np.flatnonzero(present)
        velocities, strata = self.velocities[rows], self._strata[rows]
        nominal = self.forecaster.nominal(self._nominal_origin[rows], velocities, horizon)
        drawn = self.bank.sample(rng, nominal, strata, headings(velocities, strata), n_samples)
        if isinstance(rows, slice):
            return drawn
        samples = np.empty((self.n, int(n_samples), int(horizon), 2))
        samples[:] = self.parked
        samples[rows] = drawn
        return samples

    # -------------------------------------------------------------------- internals

    def _update(self, *, first: bool) -> None:
        j = self.step_index
        index, points = self.pedestrians_at(j)
        ego = np.asarray(self._ego_position(), dtype=np.float64)
        delta = points - ego
        d2 = delta[:, 0] ** 2 + delta[:, 1] ** 2
        chosen = index[np.argsort(d2, kind="stable")[: self.n]].tolist()  # nearest first
        wanted = set(chosen)
        slots = [ped if ped in wanted else -1 for ped in self.slots.tolist()]
        held = set(slots)
        free = (k for k, ped in enumerate(slots) if ped < 0)
        for ped in chosen:
            if ped not in held:
                slots[next(free)] = ped
        self.slots = np.array(slots, dtype=np.int64)
        # Positions, chord starts, velocity estimates and strata of the slots at step j.
        rec = self.recording
        present = self.present
        positions = self.starts.copy()
        chord = self.starts.copy()
        velocities = np.zeros((self.n, 2))
        origins = self.starts.copy()
        lengths = np.zeros(self.n, dtype=np.int64)
        h = self.forecaster.history_steps
        occupied = np.flatnonzero(present)
        peds = self.slots[occupied]
        # Window of each pedestrian: its positions at steps max(first, j - H + 1) .. j.
        length = np.minimum(j - rec.first[peds] + 1, h)
        lengths[occupied] = length
        positions[occupied] = rec.positions[j, peds]
        moved = (length >= 2) & (not first)  # present at j - 1 too: the chord starts there
        chord[occupied] = np.where(moved[:, None], rec.positions[j - 1, peds], positions[occupied])
        full = length == h
        if full.any():  # one product for all the full windows, (m, h, 2)
            window = rec.positions[j - h + 1 : j + 1][:, peds[full]]  # steps <= j only
            origins[occupied[full]], velocities[occupied[full]] = (
                self.forecaster.estimate_windows(np.swapaxes(window, 0, 1)))
        for slot, ped, size in zip(occupied[~full].tolist(), peds[~full].tolist(),
                                   length[~full].tolist(), strict=True):
            window = rec.positions[j - size + 1 : j + 1, ped]  # steps <= j only
            origins[slot], velocities[slot] = self.forecaster.estimate(window)
        strata = np.where(present, strata_of(velocities, lengths), NEW)
        self.positions = positions
        self.chord_starts = chord
        self.velocities = velocities
        self._nominal_origin = origins
        self._strata = strata

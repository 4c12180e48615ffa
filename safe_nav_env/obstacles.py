"""Vectorised obstacle motion, prediction sampling and distances to collision.

All obstacles of a scenario are kept in arrays of shape ``(n_obstacles, 2)`` and
moved and predicted together; the prediction samples are drawn in one call, with
no Python loop over samples or steps.

Nominal motion
--------------
Obstacle ``i`` has a lane: the line through an anchor point ``a_i`` along its
current velocity ``v_i`` (unit direction ``e_i``). With ``Π(p) = a + ((p - a)·e) e``
the projection onto the lane, the nominal next position and the realised one are

.. math::

    \\bar p_{t+1} = \\Pi(p_t) + T_s v_t, \\qquad p_{t+1} = \\bar p_{t+1} + w_t,

where ``w_t`` follows the reality law: the lateral drift is pulled back to the lane
each step while the along-lane position is a random walk, as in the authors' code.
After the step the anchor moves to ``\\bar p_{t+1}``. A turning obstacle (see
:class:`~safe_nav_env.scenarios.ObstacleSpec`) rotates its velocity by the
increment of its heading schedule ``θ(s) = sign(ω) min(|ω| max(s - s_0, 0), Θ)``
each step. An obstacle with zero velocity keeps ``\\bar p_{t+1} = a`` (its start).
A stopping obstacle (``stop_window``) has ``\\bar p_{t+1} = \\Pi(p_t)`` once halted; its
nominal velocity ``v_t``, and so the predictions below, keep the lane speed.

Predictions
-----------
At time ``t`` the ``k``-th predicted position (``k = 1..T``) of sample ``j`` is

.. math::

    \\hat p^{(j)}_{t+k} = \\Pi(p_t) + T_s \\sum_{m=0}^{k-1} R(\\Delta θ^{(j)}_m) v_t + ε^{(j)}_k,

with independent ``ε^{(j)}_k`` from the prediction law and ``Δθ_m = 0`` (straight
hypothesis) or ``θ(s_{t+m}) - θ(s_t)`` (turning hypothesis, chosen per sample with
probability ``turn_probability``). Without turning this is the nominal
constant-velocity trajectory from the obstacle's current position plus noise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from safe_nav_env.noise import NoiseLaw
from safe_nav_env.scenarios import ObstacleSpec


def distance_to_collision(ego_position: np.ndarray, obstacle_positions: np.ndarray,
                          ego_radius: float, obstacle_radii: np.ndarray) -> np.ndarray:
    """Signed clearance between the ego disc and each obstacle disc.

    .. math::  d_i = \\lVert y - p_i \\rVert - r_A - r_{O,i}

    Parameters
    ----------
    ego_position
        Ego position ``y``, shape ``(2,)``, in m.
    obstacle_positions
        Obstacle positions ``p_i``, shape ``(n, 2)``, in m.
    ego_radius, obstacle_radii
        ``r_A`` (float) and ``r_O`` (shape ``(n,)``), in m.

    Returns
    -------
    numpy.ndarray
        Shape ``(n,)``, in m; ``d_i <= 0`` is a collision (touching counts).
    """
    delta = obstacle_positions - ego_position
    return np.hypot(delta[:, 0], delta[:, 1]) - (obstacle_radii + ego_radius)


def _rotate(vectors: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotate ``vectors[..., 2]`` counter-clockwise by ``angles[...]`` (broadcast), in rad."""
    cos, sin = np.cos(angles), np.sin(angles)
    x, y = vectors[..., 0], vectors[..., 1]
    return np.stack((cos * x - sin * y, sin * x + cos * y), axis=-1)


class ObstacleModel:
    """State and motion of a set of obstacles (see the module docstring).

    Parameters
    ----------
    specs
        The obstacles.
    dt
        Sampling time ``T_s``, in s.

    Attributes
    ----------
    positions
        Current positions, shape ``(n, 2)``, in m (a new array after each step).
    velocities
        Current nominal velocities, shape ``(n, 2)``, in m/s.
    chord_starts
        Where each obstacle's chord over the last step starts, shape ``(n, 2)``, in m:
        its positions before the step (after :meth:`reset`, the start positions). The
        environment's continuous-time collision check runs along these chords.
    radii
        Radii, shape ``(n,)``, in m.
    turning
        Whether each obstacle turns in this episode, shape ``(n,)`` (drawn at reset).
    stop_times
        When each obstacle halts in this episode, in s (drawn at reset from its
        ``stop_window``; ``inf``: never), shape ``(n,)``. From the first step that
        starts at or after its stop time, an obstacle's nominal next position is its
        current projected position ``Π(p_t)`` (no advance along the lane); its
        :attr:`velocities` and the predictions keep the lane speed.
    present
        ``None``: every row is an obstacle. A scene's model whose rows are slots that may
        be empty (:class:`~safe_nav_env.pedestrians.replay.ReplayModel`) gives a ``(n,)``
        bool mask instead; the environment masks the empty rows in the observation and in
        ``info``.
    """

    present: np.ndarray | None = None

    def __init__(self, specs: Sequence[ObstacleSpec], dt: float) -> None:
        self.dt = float(dt)
        self.n = len(specs)
        self.starts = np.array([s.start for s in specs], dtype=np.float64).reshape(self.n, 2)
        self.initial_velocities = np.array(
            [s.velocity for s in specs], dtype=np.float64
        ).reshape(self.n, 2)
        self.radii = np.array([s.radius for s in specs], dtype=np.float64)
        self.turn_rates = np.array([s.turn_rate for s in specs], dtype=np.float64)
        self.turn_probabilities = np.array([s.turn_probability for s in specs])
        self.turn_starts = np.array([s.turn_start for s in specs], dtype=np.float64)
        self.turn_angles = np.array([s.turn_angle for s in specs], dtype=np.float64)
        self.can_turn = self.turn_rates != 0.0
        self.any_can_turn = bool(self.can_turn.any())
        windows = [s.stop_window or (math.inf, math.inf) for s in specs]
        self.stop_windows = np.array(windows, dtype=np.float64).reshape(self.n, 2)
        self.can_stop = np.isfinite(self.stop_windows[:, 0])
        self.any_can_stop = bool(self.can_stop.any())
        self.stop_times = np.full(self.n, math.inf)
        self.radii.flags.writeable = False
        self.reset(None)

    def _set_state(
        self, positions: np.ndarray, velocities: np.ndarray, anchors: np.ndarray
    ) -> None:
        self.chord_starts = self.positions if self.step_count else positions
        self.positions = positions
        self.velocities = velocities
        self.anchors = anchors
        speed = np.hypot(velocities[:, 0], velocities[:, 1])
        moving = speed > 0.0
        # Unit lane directions (zero for a stationary obstacle, which then holds station).
        self._directions = velocities / np.where(moving, speed, 1.0)[:, None]
        self._projected: np.ndarray | None = None
        self._offsets: np.ndarray | None = None  # k T_s v_t, valid while v_t is unchanged

    def reset(self, rng: np.random.Generator | None) -> None:
        """Put every obstacle at its start and draw which ones turn (and when they stop) in
        this episode; without ``rng`` (at construction) none turns or stops."""
        self.step_count = 0
        self._set_state(self.starts.copy(), self.initial_velocities.copy(), self.starts.copy())
        self.turning = np.zeros(self.n, dtype=bool)
        if rng is None:
            return
        if self.any_can_turn:
            self.turning = self.can_turn & (rng.random(self.n) < self.turn_probabilities)
        if self.any_can_stop:
            low, high = self.stop_windows[:, 0], self.stop_windows[:, 1]
            draws = low + (high - low) * rng.random(self.n)
            self.stop_times = np.where(self.can_stop, draws, math.inf)

    def heading(self, times: np.ndarray) -> np.ndarray:
        """Heading offset ``θ(s)`` of the turning schedule at ``times`` (s), shape ``(n, ...)``.

        ``times`` broadcasts against ``(n, 1)``; the result is in rad.
        """
        shape = (self.n,) + (1,) * (np.ndim(times))
        rate = self.turn_rates.reshape(shape)
        elapsed = np.maximum(np.asarray(times) - self.turn_starts.reshape(shape), 0.0)
        turned = np.minimum(np.abs(rate) * elapsed, self.turn_angles.reshape(shape))
        return np.sign(rate) * turned

    def projected(self) -> np.ndarray:
        """Current positions projected onto their lanes ``Π(p_t)``, shape ``(n, 2)``."""
        if self._projected is None:
            e, a = self._directions, self.anchors
            d = self.positions - a
            along = d[:, 0] * e[:, 0] + d[:, 1] * e[:, 1]
            self._projected = a + along[:, None] * e
        return self._projected

    def nominal_next(self) -> np.ndarray:
        """Nominal next positions ``Π(p_t) + T_s v_t``, shape ``(n, 2)``, in m."""
        return self.projected() + self.dt * self.velocities

    def step(self, rng: np.random.Generator, law: NoiseLaw) -> np.ndarray:
        """Advance one step: ``p_{t+1} = Π(p_t) + T_s v_t + w_t`` with ``w_t`` from ``law``.

        Returns the new positions (also stored in :attr:`positions`); the arrays
        :attr:`positions` and :attr:`velocities` are replaced, never modified in place.
        """
        nominal = self.nominal_next()
        if self.any_can_stop:  # halted obstacles do not advance along their lanes
            halted = self.stop_times <= self.step_count * self.dt
            if halted.any():
                nominal = np.where(halted[:, None], self.projected(), nominal)
        positions = nominal + law.sample(rng, (self.n, 2))
        self.step_count += 1
        if self.any_can_turn and self.turning.any():
            times = np.array([self.step_count - 1, self.step_count]) * self.dt
            theta = self.heading(times)
            increment = np.where(self.turning, theta[:, 1] - theta[:, 0], 0.0)
            self._set_state(positions, _rotate(self.velocities, increment), nominal)
        else:
            self.chord_starts = self.positions
            self.positions, self.velocities, self.anchors = (
                positions, self.velocities.copy(), nominal
            )
            self._projected = None
        return positions

    def nominal_predictions(self, horizon: int) -> tuple[np.ndarray, np.ndarray | None]:
        """Nominal predicted positions for steps ``t+1..t+T``.

        Returns
        -------
        straight
            Shape ``(n, T, 2)``: constant current velocity from ``Π(p_t)``.
        turning
            Shape ``(n, T, 2)`` for the turning hypothesis, or ``None`` if no
            obstacle can turn.
        """
        offsets = self._offsets
        if offsets is None or offsets.shape[1] != horizon:  # k T_s v_t, k = 1..T
            k = np.arange(1, horizon + 1, dtype=np.float64)
            offsets = self._offsets = (self.dt * k)[None, :, None] * self.velocities[:, None]
        base = self.projected()
        straight = base[:, None, :] + offsets
        if not self.any_can_turn:
            return straight, None
        times = (self.step_count + np.arange(horizon + 1)) * self.dt
        theta = self.heading(times)  # (n, T + 1)
        delta = theta[:, :-1] - theta[:, :1]  # heading change at steps t .. t+T-1
        velocities = _rotate(self.velocities[:, None, :], delta)  # (n, T, 2)
        turning = base[:, None, :] + self.dt * np.cumsum(velocities, axis=1)
        return straight, turning

    def predict(
        self, rng: np.random.Generator, law: NoiseLaw, n_samples: int, horizon: int
    ) -> np.ndarray:
        """Draw prediction samples for steps ``t+1..t+T``.

        Parameters
        ----------
        rng
            Source of randomness.
        law
            Prediction noise law, added independently at each sample and step.
        n_samples, horizon
            ``N_s`` and ``T``.

        Returns
        -------
        numpy.ndarray
            Shape ``(n, n_samples, horizon, 2)``, in m.
        """
        samples = law.sample(rng, (self.n, n_samples, horizon, 2))
        straight, turning = self.nominal_predictions(horizon)
        if turning is None:
            samples += straight[:, None]
        else:
            probability = np.where(self.can_turn, self.turn_probabilities, 0.0)
            mode = rng.random((self.n, n_samples)) < probability[:, None]
            samples += np.where(mode[:, :, None, None], turning[:, None], straight[:, None])
        return samples

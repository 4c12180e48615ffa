"""Nominal pedestrian forecasts from the observed past only.

Given the last ``L <= H`` observed positions of a pedestrian (steps ``t-L+1 .. t``,
the current one included, ``H`` = ``history_steps``), a forecaster estimates its
position :math:`\\hat p_t` and velocity :math:`\\hat v_t` and predicts the nominal
constant-velocity trajectory

.. math::

    \\bar p_{t+k} = \\hat p_t + k\\,T_s\\,\\hat v_t, \\qquad k = 1, \\dots, T.

Both estimates are linear in the window, :math:`(\\hat p_t, \\hat v_t)^\\top = W_L\\,Y`
with ``Y`` the ``(L, 2)`` window, so a forecaster is the table of weight matrices
``W_L`` (``L = 1 .. H``):

* ``"constant_velocity"``: the last observed velocity,
  :math:`\\hat p_t = y_t`, :math:`\\hat v_t = (y_t - y_{t-1}) / T_s` (zero when ``L = 1``);
* ``"kalman"``: the filtered state of the project's
  :class:`~safe_nav_env.predictors.ConstantVelocityKalman` after the window (its
  recursion is linear in the observations and its gains do not depend on them, so
  ``W_L`` is read off by filtering the ``L`` unit vectors; there is one Kalman
  filter in the code base).

Each forecast also carries a *stratum*, which selects the residual law
(:mod:`safe_nav_env.pedestrians.residuals`): ``NEW`` (one observation, velocity
unknown), ``STANDING`` (:math:`\\lVert \\hat v_t \\rVert <` :data:`STANDING_SPEED`) or
``MOVING``; and the heading frame ``(e, n)`` (unit velocity and its left normal)
in which the residuals of a moving pedestrian are expressed (:func:`headings`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from safe_nav_env.errors import ConfigError
from safe_nav_env.options import _option
from safe_nav_env.predictors import ConstantVelocityKalman

__all__ = ["FORECASTERS", "MOVING", "NEW", "STANDING", "STANDING_SPEED", "STRATA", "Forecaster",
    "headings", "strata_of"]

NEW, STANDING, MOVING = 0, 1, 2
STRATA = ("new", "standing", "moving")
"""Names of the strata, indexed by the codes ``NEW``, ``STANDING``, ``MOVING``."""

STANDING_SPEED = 0.2
"""Speed below which a pedestrian counts as standing, m/s."""

FORECASTERS = ("constant_velocity", "kalman")
"""Names accepted by :class:`Forecaster`."""

KALMAN_SETTINGS = {"acceleration_psd": 1.0, "measurement_variance": 0.0025,
                   "initial_speed_std": 1.5}
"""Parameters of the pedestrian Kalman forecaster: white acceleration of
1 m²/s³ (people turn and change pace within a second or two), tracking jitter of
5 cm (std), prior walking speed spread 1.5 m/s per axis."""


@dataclass(frozen=True)
class Forecaster:
    """Linear estimator of position and velocity on a window of past positions.

    Parameters
    ----------
    name
        ``"constant_velocity"`` or ``"kalman"``.
    dt
        Sampling time ``T_s``, s.
    history_steps
        Longest window ``H`` used, in steps (default 8, 1.6 s at 0.2 s).

    Raises
    ------
    ConfigError
        For an unknown name or a non-positive ``dt`` or ``history_steps``.
    """

    name: str = "constant_velocity"
    dt: float = 0.2
    history_steps: int = 8
    weights: tuple[np.ndarray, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.name not in FORECASTERS:
            raise ConfigError(f"predictor must be one of {list(FORECASTERS)}, got {self.name!r}")
        object.__setattr__(self, "dt", _option("dt (s)", self.dt, strict=True))
        h = _option("history_steps", self.history_steps, low=2, integer=True)
        object.__setattr__(self, "history_steps", h)
        # index L: the (2, L) weights of a window of L rows
        tables = [np.zeros((2, 0))] + [self._weights(length) for length in range(1, h + 1)]
        for table in tables:
            table.flags.writeable = False
        object.__setattr__(self, "weights", tuple(tables))

    def _weights(self, length: int) -> np.ndarray:
        """``W_L``: row 0 the position weights, row 1 the velocity weights (1/s)."""
        if self.name == "constant_velocity":
            w = np.zeros((2, length))
            w[0, -1] = 1.0
            if length >= 2:
                w[1, -1], w[1, -2] = 1.0 / self.dt, -1.0 / self.dt
            return w
        kalman = ConstantVelocityKalman(**KALMAN_SETTINGS)
        mean, _ = kalman.filter(np.eye(length)[:, :, None], self.dt)  # (L obs, 1 axis, 2)
        return np.ascontiguousarray(mean[:, 0, :].T)

    def estimate(self, window: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and velocity (m/s) estimates from a ``(L, 2)`` window, ``1 <= L <= H``."""
        est = self.weights[window.shape[0]] @ window
        return est[0], est[1]

    def estimate_windows(self, windows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Vectorised :meth:`estimate` for windows ``(n, L, 2)`` of one length ``L``."""
        est = np.matmul(self.weights[windows.shape[1]], windows)  # (n, 2, 2)
        return est[:, 0], est[:, 1]

    def nominal(self, position: np.ndarray, velocity: np.ndarray, horizon: int) -> np.ndarray:
        """Nominal trajectory :math:`\\hat p + k T_s \\hat v`, ``k = 1..T``: ``(..., T, 2)``, m."""
        k = self.dt * np.arange(1, horizon + 1)
        return position[..., None, :] + k[:, None] * velocity[..., None, :]


def strata_of(velocities: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Stratum code per forecast, from velocity estimates ``(n, 2)`` and window lengths ``(n,)``."""
    speed = np.hypot(velocities[:, 0], velocities[:, 1])
    codes = np.where(speed < STANDING_SPEED, STANDING, MOVING)
    return np.where(lengths <= 1, NEW, codes)


def headings(velocities: np.ndarray, strata: np.ndarray) -> np.ndarray:
    """Heading frame of each forecast as a unit complex number ``h = e_x + i e_y``, ``(n,)``.

    ``e`` is the unit velocity for ``MOVING`` forecasts and the x axis (``h = 1``)
    otherwise; the frame's second axis is the left normal ``i h``. A world residual
    ``r = r_x + i r_y`` has frame coordinates ``conj(h) r`` (along, across) and back
    ``h c``: the rotation ``R = [e, n]`` as a complex product.
    """
    h = np.ones(velocities.shape[0], dtype=np.complex128)
    moving = strata == MOVING
    if moving.any():
        v = velocities[moving, 0] + 1j * velocities[moving, 1]
        h[moving] = v / np.abs(v)
    return h

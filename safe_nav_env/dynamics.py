"""Linear discrete-time models of the ego robot and of the obstacles.

The ego robot is the double integrator of the paper (Section IV-B),

.. math::

    x_{t+1} = A x_t + B u_t, \\qquad y_t = C x_t, \\qquad
    A = \\begin{bmatrix} I & T_s I \\\\ 0 & I \\end{bmatrix}, \\quad
    B = \\begin{bmatrix} \\tfrac{T_s^2}{2} I \\\\ T_s I \\end{bmatrix}, \\quad
    C = \\begin{bmatrix} I & 0 \\end{bmatrix},

with state ``x = [p, v]`` (position in m, velocity in m/s), input ``u`` the
acceleration in m/s² and output ``y`` the position. The obstacles are single
integrators ``A = I``, ``B = T_s I``, ``C = I`` driven by their velocity.
"""

from __future__ import annotations

import numpy as np

from safe_nav_env.errors import ConfigError


def _check(dt: float, dim: int) -> None:
    if not (np.isfinite(dt) and dt > 0):
        raise ConfigError(f"dt must be a finite number > 0 (in s), got {dt!r}")
    if int(dim) != dim or dim < 1:
        raise ConfigError(f"dim must be a positive integer, got {dim!r}")


def _read_only(*arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    for array in arrays:
        array.flags.writeable = False
    return arrays


def double_integrator(dt: float, dim: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the read-only matrices ``(A, B, C)`` of a ``dim``-axis double integrator.

    Parameters
    ----------
    dt
        Sampling time ``T_s``, in s (the paper uses 0.2 s).
    dim
        Number of position axes ``d``.

    Returns
    -------
    A, B, C
        Shapes ``(2d, 2d)``, ``(2d, d)`` and ``(d, 2d)``; the input is held
        constant over each sampling interval (zero-order hold, exact discretisation).

    Raises
    ------
    ConfigError
        If ``dt`` is not a finite positive number or ``dim`` not a positive integer.
    """
    _check(dt, dim)
    eye, zero = np.eye(dim), np.zeros((dim, dim))
    A = np.block([[eye, dt * eye], [zero, eye]])
    B = np.vstack([0.5 * dt**2 * eye, dt * eye])
    C = np.hstack([eye, zero])
    return _read_only(A, B, C)  # type: ignore[return-value]


def single_integrator(dt: float, dim: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the read-only matrices ``(A, B, C) = (I, T_s I, I)`` of a single integrator.

    Parameters
    ----------
    dt
        Sampling time ``T_s``, in s.
    dim
        Number of position axes ``d``; the input is the velocity, in m/s.

    Raises
    ------
    ConfigError
        If ``dt`` is not a finite positive number or ``dim`` not a positive integer.
    """
    _check(dt, dim)
    eye = np.eye(dim)
    return _read_only(eye.copy(), dt * eye, eye.copy())  # type: ignore[return-value]

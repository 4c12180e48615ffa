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

The ego's speed is limited, :math:`\\|v\\|_2 \\le v_\\max`, without leaving the double
integrator: :func:`applied_acceleration` changes the input, never the state update
(see there).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from safe_nav_env.errors import InvalidActionError
from safe_nav_env.options import _option


def _check(dt: float, dim: int) -> None:
    _option("dt (s)", dt, strict=True)
    _option("dim", dim, low=1, integer=True)


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


def parse_action(action: Any) -> tuple[float, float]:
    """The two accelerations ``(a_x, a_y)`` of ``action``, in m/s², as Python floats.

    Raises
    ------
    InvalidActionError
        If ``action`` does not have 2 entries or holds NaN or infinite values.
    """
    try:
        u = np.asarray(action, dtype=np.float64).ravel()
    except (TypeError, ValueError) as exc:
        raise InvalidActionError(f"action must be 2 accelerations (a_x, a_y) in m/s², shape "
                                 f"(2,), got {action!r}") from exc
    if u.shape != (2,):  # a scalar is not broadcast to both axes
        raise InvalidActionError(
            f"action must have shape (2,) (a_x, a_y in m/s²), got shape {np.shape(action)}: "
            f"{action!r}")
    ux, uy = u.tolist()
    if not (math.isfinite(ux) and math.isfinite(uy)):
        raise InvalidActionError(f"action must be finite, got {action!r}")
    return ux, uy


def applied_acceleration(velocity: tuple[float, float], action: tuple[float, float], dt: float,
                         max_acceleration: float, max_speed: float) -> tuple[float, float]:
    r"""The acceleration the ego applies for ``action``: the box, then the speed limit.

    The action is clipped to the box :math:`|u_i| \le a_\max`. If the next velocity
    :math:`v + T_s u` then lies in the disc :math:`\|v'\|_2 \le v_\max`, that is the
    applied input. Otherwise the applied input is the point of

    .. math::

        K = \{u : |u_i| \le a_\max,\ \|v + T_s u\|_2 \le v_\max\}

    closest to the clipped action (the Euclidean projection onto a convex set: first
    the projection onto the disc, :math:`v' \mapsto v_\max v' / \|v'\|`; if that leaves
    the box, the closest point where the circle crosses a face of the box). The state
    update stays the double integrator's, :math:`p' = p + T_s v + \tfrac{T_s^2}{2} u`,
    :math:`v' = v + T_s u`, with this :math:`u`. ``K`` is not empty while
    :math:`\|v\| \le v_\max` (``u = 0`` is in it); above the limit (only from a start
    faster than it) the ego brakes as hard as the box allows,
    :math:`u = \mathrm{clip}(-v / T_s)`, until it is back under it.

    Parameters
    ----------
    velocity
        :math:`v`, in m/s.
    action
        Proposed acceleration, in m/s² (finite).
    dt
        :math:`T_s`, in s.
    max_acceleration
        :math:`a_\max`, in m/s² per axis.
    max_speed
        :math:`v_\max`, in m/s (``inf``: no limit).

    Returns
    -------
    tuple of float
        The applied acceleration, in m/s².
    """
    a = max_acceleration
    ux, uy = action[0], action[1]  # clipped to the box (a NaN stays NaN, as with min/max)
    if ux > a:
        ux = a
    elif ux < -a:
        ux = -a
    if uy > a:
        uy = a
    elif uy < -a:
        uy = -a
    vx, vy = velocity
    nx, ny = vx + dt * ux, vy + dt * uy
    limit = max_speed * max_speed
    if nx * nx + ny * ny <= limit:  # also every case with max_speed = inf
        return ux, uy
    # Below the limit, u = 0 keeps |v'| < v_max, so K has an interior point; at or above
    # it, K is empty or one point if even the hardest braking cannot get inside.
    if vx * vx + vy * vy >= limit:
        bx, by = _hardest_braking(vx, vy, dt, a)
        if math.hypot(vx + dt * bx, vy + dt * by) >= max_speed:
            return bx, by
    # The projection onto the disc, v' = v_max n / |n| with n = v + T_s u; in u-space
    # the disc has centre c = -v / dt and radius r = v_max / dt.
    scale = max_speed / math.hypot(nx, ny)
    px, py = (scale * nx - vx) / dt, (scale * ny - vy) / dt
    if -a <= px <= a and -a <= py <= a:
        return px, py
    cx, cy, r = -vx / dt, -vy / dt, max_speed / dt
    best, best_distance = _hardest_braking(vx, vy, dt, a), math.inf
    for axis in (0, 1):  # where the circle crosses the faces u_axis = ±a
        centre, other = (cx, cy) if axis == 0 else (cy, cx)
        for face in (-a, a):
            reach = r * r - (face - centre) ** 2
            if reach < 0.0:
                continue
            for root in (other - math.sqrt(reach), other + math.sqrt(reach)):
                if -a <= root <= a:
                    point = (face, root) if axis == 0 else (root, face)
                    distance = math.hypot(point[0] - ux, point[1] - uy)
                    if distance < best_distance:
                        best, best_distance = point, distance
    return best


def _hardest_braking(vx: float, vy: float, dt: float, a: float) -> tuple[float, float]:
    """:math:`\\mathrm{clip}(-v / T_s)` to the box :math:`|u_i| \\le a`, in m/s²: the input
    of the box that brings the velocity closest to 0."""
    return min(max(-vx / dt, -a), a), min(max(-vy / dt, -a), a)

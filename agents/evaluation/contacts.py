"""Where and when a recorded episode touched an obstacle, in continuous time.

The environment reports each step's minimum clearance; the figures also need the
instant and the positions of the first contact. :func:`step_clearance` solves for them
on the ego's constant-acceleration arc against the obstacle's chord, and
:func:`find_collisions` marks the first contact with each obstacle in a trajectory
(:class:`agents.evaluation.trajectory.Trajectory`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from filters._validation import finite_array, scalar_in_range
from filters.errors import InvalidArrayError
from safe_nav_env.collision import swept_clearance

__all__ = ["CollisionMark", "StepClearance", "find_collisions", "step_clearance"]


@dataclass(frozen=True)
class StepClearance:
    """Closest approach of the ego and one obstacle during one step.

    Attributes
    ----------
    clearance
        :math:`\\min_{s \\in [0, dt]} \\|y(s) - p(s)\\| - r_A - r_O`, in m.
    contact
        The first ``s`` at which the clearance reaches 0 (``nan`` if it stays > 0), in s.
    """

    clearance: float
    contact: float


def step_clearance(
    ego_position: np.ndarray,
    ego_velocity: np.ndarray,
    ego_input: np.ndarray,
    obstacle_start: np.ndarray,
    obstacle_end: np.ndarray,
    *,
    radius_sum: float,
    dt: float,
) -> StepClearance:
    r"""Exact minimum clearance over one step and the first contact: ego on its arc,
    obstacle on its chord.

    .. math::
        \Delta(\tau) = (p - q_0) + \tau\,(dt\,v - (q_1 - q_0)) + \tau^2 \tfrac{dt^2}{2} u,
        \qquad \tau = s / dt \in [0, 1]

    The clearance is the environment's own
    (:func:`safe_nav_env.collision.swept_clearance`); the first contact is the smallest
    root in the step of the quartic :math:`\|\Delta(\tau)\|^2 - (r_A + r_O)^2`.

    Parameters
    ----------
    ego_position, ego_velocity, ego_input
        Ego position (m), velocity (m/s) and the input held over the step (m/s²).
    obstacle_start, obstacle_end
        Obstacle positions at the start and the end of the step, in m.
    radius_sum
        :math:`r_A + r_O`, in m, ``>= 0``.
    dt
        Step length, in s, ``> 0``.

    Raises
    ------
    InvalidArrayError
        If a vector is not finite.
    InvalidParameterError
        If ``dt <= 0`` or ``radius_sum < 0``.
    """
    p, v, u, q0, q1 = (finite_array(name, value, ndim=1) for name, value in (
        ("ego_position", ego_position), ("ego_velocity", ego_velocity), ("ego_input", ego_input),
        ("obstacle_start", obstacle_start), ("obstacle_end", obstacle_end)))
    dt = scalar_in_range("dt", dt, low=0.0, high=np.inf, low_inclusive=False,
                         high_inclusive=False)
    radius_sum = scalar_in_range("radius_sum", radius_sum, low=0.0, high=np.inf,
                                 high_inclusive=False)
    (clearance,) = swept_clearance(np.concatenate([p, v]), u, dt, [q0], [q1], [radius_sum])
    if clearance > 0.0:
        return StepClearance(clearance=clearance, contact=math.nan)
    d0, w, c = p - q0, dt * v - (q1 - q0), 0.5 * dt * dt * u
    excess = np.array([c @ c, 2 * w @ c, w @ w + 2 * d0 @ c, 2 * d0 @ w,
                       d0 @ d0 - radius_sum**2])
    roots = np.roots(excess)  # a touching (double) root may carry a rounding-size imaginary part
    inside = [t.real for t in roots if abs(t.imag) <= 1e-6 and 0.0 <= t.real <= 1.0]
    first = 0.0 if excess[-1] <= 0.0 else min(inside, default=float(np.clip(
        roots[np.argmin(np.abs(roots.imag))].real, 0.0, 1.0)))
    return StepClearance(clearance=clearance, contact=float(first * dt))


@dataclass(frozen=True)
class CollisionMark:
    """Where and when the ego first touches one obstacle in an episode.

    ``step`` is the 1-based step during which contact happens; ``time`` the
    contact time from the episode start, in s; positions at that instant, in m;
    ``exact`` is ``False`` when the ego was taken on the chord between its samples.
    """

    obstacle: int
    step: int
    time: float
    ego_position: np.ndarray
    obstacle_position: np.ndarray
    clearance: float
    exact: bool


def find_collisions(trajectory: Any, *, dt: float | None = None) -> list[CollisionMark]:
    """First contact of the ego with each obstacle, in continuous time.

    Uses ``trajectory.ego_velocities``, ``.inputs`` and ``.dt`` when present (exact);
    otherwise the ego is taken on the chord between its samples (``exact=False``)
    with step length ``dt`` (default ``trajectory.dt``, else 0.2 s).
    ``clearance`` is the deepest clearance of that step, in m.
    """
    ego = np.asarray(trajectory.ego, dtype=float)
    obstacles = np.asarray(trajectory.obstacles, dtype=float)
    if obstacles.ndim != 3 or obstacles.shape[0] != ego.shape[0]:
        raise InvalidArrayError(f"obstacles must have shape ({ego.shape[0]}, n, 2), got "
                                f"{obstacles.shape}")
    radii = np.asarray(trajectory.obstacle_radii, dtype=float) + float(trajectory.ego_radius)
    velocities = getattr(trajectory, "ego_velocities", None)
    inputs = getattr(trajectory, "inputs", None)
    step_length = float(dt if dt is not None else getattr(trajectory, "dt", 0.2))
    exact = velocities is not None and inputs is not None
    if not exact:  # the ego on the chord between its samples
        velocities, inputs = np.diff(ego, axis=0) / step_length, np.zeros((len(ego) - 1, 2))
    marks = []
    for i in range(obstacles.shape[1]):
        for k in range(ego.shape[0] - 1):
            v, u = np.asarray(velocities[k], dtype=float), np.asarray(inputs[k], dtype=float)
            result = step_clearance(ego[k], v, u, obstacles[k, i], obstacles[k + 1, i],
                                    radius_sum=float(radii[i]), dt=step_length)
            if result.clearance <= 0.0:
                s = result.contact
                marks.append(CollisionMark(
                    obstacle=i, step=k + 1, time=k * step_length + s,
                    ego_position=ego[k] + s * v + 0.5 * s * s * u,
                    obstacle_position=obstacles[k, i]
                    + (s / step_length) * (obstacles[k + 1, i] - obstacles[k, i]),
                    clearance=result.clearance, exact=exact))
                break
    return marks

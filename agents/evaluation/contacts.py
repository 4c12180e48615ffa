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
from scipy.optimize import brentq

from filters._validation import finite_array, scalar_in_range
from filters.errors import InvalidArrayError
from safe_nav_env.collision import real_cubic_roots

__all__ = ["CollisionMark", "StepClearance", "find_collisions", "step_clearance"]


@dataclass(frozen=True)
class StepClearance:
    """Closest approach of the ego and one obstacle during one step.

    Attributes
    ----------
    clearance
        :math:`\\min_{s \\in [0, dt]} \\|y(s) - p(s)\\| - r_A - r_O`, in m.
    closest
        The time ``s`` of that minimum within the step, in s.
    contact
        The first ``s`` at which the clearance reaches 0 (``nan`` if it stays > 0), in s.
    """

    clearance: float
    closest: float
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
    r"""Exact minimum clearance over one step: ego on its arc, obstacle on its chord.

    .. math::
        \Delta(s) = (p - q_0) + s\,(v - (q_1 - q_0)/dt) + \tfrac{s^2}{2} u,
        \qquad s \in [0, dt]

    :math:`\|\Delta(s)\|^2` is a quartic in s; its minimum is at an end point or at a
    real root of its cubic derivative, and the first contact is the smallest root
    of :math:`\|\Delta(s)\|^2 = (r_A + r_O)^2` in the step.

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
    # In the normalised time tau = s / dt (as safe_nav_env.collision.swept_clearance):
    # ||d0 + tau w + tau² c||² = c4 tau⁴ + c3 tau³ + c2 tau² + c1 tau + c0
    d0, w, c = p - q0, dt * v - (q1 - q0), 0.5 * dt * dt * u
    quartic = np.array([c @ c, 2 * w @ c, w @ w + 2 * d0 @ c, 2 * d0 @ w, d0 @ d0])
    stationary = real_cubic_roots(*(quartic[:4] * [2.0, 1.5, 1.0, 0.5]))  # half the derivative
    candidates = [0.0, 1.0] + [t for t in stationary if 0.0 < t < 1.0]
    values = [np.polyval(quartic, t) for t in candidates]
    best = int(np.argmin(values))
    closest = candidates[best]
    clearance = math.sqrt(max(values[best], 0.0)) - radius_sum
    contact = math.nan
    if clearance <= 0.0:  # the first root of ||.||² = radius_sum², bracketed: between two
        # successive candidates up to the closest approach ||.||² is monotone
        def excess(t: float) -> float:
            return float(np.polyval(quartic, t)) - radius_sum**2

        ends = sorted(t for t in candidates if t <= closest)
        j = next(i for i, t in enumerate(ends) if excess(t) <= 0.0)
        contact = ends[0] if j == 0 else brentq(excess, ends[j - 1], ends[j], xtol=1e-15)
    return StepClearance(clearance=clearance, closest=closest * dt, contact=contact * dt)


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

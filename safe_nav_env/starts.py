"""Randomised ego starts, for training a planner on the states a safety filter leads it into.

A filtered policy does not stay on the straight, fast approach it was trained on: a
correction early on can make it pass beside the goal, brake at the arena wall, or
stop near the goal with the wrong velocity. A planner trained only from the
scenario's start has never seen those states. :class:`RandomStart` replaces the
scenario's ego start, in a share of the episodes, by a random state: near the goal or
anywhere in the arena, at rest or moving in any direction. It is a training option
(``gym.make(..., random_start=0.5)``); the evaluation scenarios keep their starts.

Positions are in m, velocities in m/s.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from safe_nav_env.errors import ConfigError
from safe_nav_env.options import _finite_array, _from_fields, _option

_ATTEMPTS = 100
"""Position draws before a random start gives up and keeps the scenario's start."""


@dataclass(frozen=True)
class RandomStart:
    """How often, and from where, an episode starts at a random ego state.

    At each reset, with probability ``probability``, the ego's initial state is
    drawn instead of taken from the scenario:

    * position: with probability ``near_goal``, at a distance
      :math:`U(\\text{goal\\_distance})` from the goal in a uniform direction;
      otherwise uniform in the arena. Either way at least ``wall_margin`` inside the
      arena, outside the goal tolerance, and at least ``clearance`` (edge to edge)
      from every obstacle; a draw that fails is repeated (up to 100 times, then the
      scenario's start is kept);
    * velocity: zero with probability ``rest``, else a speed :math:`U(0,
      \\text{max\\_speed})` in a uniform direction;
    * goal: with probability ``random_goal``, the goal is drawn too, uniform in the
      arena (``wall_margin`` inside), before the start; otherwise it is the scenario's.

    The obstacles are the scenario's. With ``probability = 0`` nothing
    is drawn, so the episodes are those of the plain environment, bit for bit.

    Parameters
    ----------
    probability
        Share of the episodes that start at a random state, in [0, 1].
    near_goal
        Share of the random starts drawn near the goal, in [0, 1].
    goal_distance
        ``(low, high)`` distance from the goal of a start near the goal, in m,
        ``0 < low <= high``.
    max_speed
        Largest initial speed, in m/s, ``>= 0``.
    rest
        Share of the random starts at rest, in [0, 1].
    clearance
        Smallest edge-to-edge distance to an obstacle at the start, in m, ``>= 0``.
    wall_margin
        Smallest distance of the start position (and of a random goal) inside the arena's
        walls, in m, ``>= 0``.
    random_goal
        Share of the random starts whose goal is drawn too, in [0, 1].

    Raises
    ------
    ConfigError
        If a field is out of its range; the message names it.
    """

    probability: float = 0.5
    near_goal: float = 0.5
    goal_distance: tuple[float, float] = (0.35, 2.0)
    max_speed: float = 3.0
    rest: float = 1.0 / 3.0
    clearance: float = 0.5
    wall_margin: float = 0.3
    random_goal: float = 0.0

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for name in ("probability", "near_goal", "rest", "random_goal"):
            set_(self, name, _option(f"random_start.{name}", getattr(self, name), high=1.0))
        for name in ("max_speed", "clearance", "wall_margin"):
            set_(self, name, _option(f"random_start.{name}", getattr(self, name)))
        distance = _finite_array("random_start.goal_distance", self.goal_distance,
                                 "(low, high) in m", "(2,)", lambda shape: shape == (2,)).tolist()
        low = _option("random_start.goal_distance[0]", distance[0], strict=True)
        high = _option("random_start.goal_distance[1]", distance[1], low=low)
        set_(self, "goal_distance", (low, high))

    def draw(self, rng: np.random.Generator, *, goal: np.ndarray, goal_tolerance: float,
             arena: tuple[tuple[float, float], tuple[float, float]], ego_radius: float,
             obstacle_positions: np.ndarray,
             obstacle_radii: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """A random initial ego state ``(p_x, p_y, v_x, v_y)`` and goal ``(x, y)``, or ``None``.

        ``None`` (keep the scenario's start and goal) when this episode is not a random
        start (probability ``1 - probability``) or when no position satisfying the
        constraints was found.
        """
        if self.probability == 0.0 or rng.random() >= self.probability:
            return None
        low = np.asarray(arena[0], dtype=float) + self.wall_margin
        high = np.asarray(arena[1], dtype=float) - self.wall_margin
        if np.any(low > high):
            return None
        goal = np.asarray(goal, dtype=float)
        if rng.random() < self.random_goal:
            goal = rng.uniform(low, high)
        edge = np.asarray(obstacle_radii, dtype=float) + ego_radius + self.clearance
        obstacles = np.asarray(obstacle_positions, dtype=float).reshape(-1, 2)
        near = rng.random() < self.near_goal
        for _ in range(_ATTEMPTS):
            if near:
                distance = rng.uniform(*self.goal_distance)
                angle = rng.uniform(0.0, 2.0 * math.pi)
                position = goal + distance * np.array([math.cos(angle), math.sin(angle)])
            else:
                position = rng.uniform(low, high)
            if np.any(position < low) or np.any(position > high):
                continue
            if math.hypot(*(position - goal)) <= goal_tolerance:
                continue
            if obstacles.shape[0] and np.any(
                    np.hypot(*(obstacles - position).T) < edge):
                continue
            break
        else:
            return None
        velocity = np.zeros(2)
        if rng.random() >= self.rest:
            speed = rng.uniform(0.0, self.max_speed)
            heading = rng.uniform(0.0, 2.0 * math.pi)
            velocity = speed * np.array([math.cos(heading), math.sin(heading)])
        return np.concatenate([position, velocity]), goal


def resolve_random_start(value: Any) -> RandomStart | None:
    """The :class:`RandomStart` of ``gym.make(..., random_start=value)``.

    ``None`` or ``0``: no random starts; a number in (0, 1]: :class:`RandomStart` with
    that ``probability`` and the other fields at their defaults; a mapping of the
    fields; or a :class:`RandomStart`.

    Raises
    ------
    ConfigError
        If ``value`` is none of these, or a field is out of its range.
    """
    if value is None:
        return None
    if isinstance(value, Mapping):
        value = _from_fields(RandomStart, value, "random_start", ConfigError)
    elif isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool):
        value = RandomStart(probability=value)
    elif not isinstance(value, RandomStart):
        raise ConfigError("random_start must be None, a probability in [0, 1], a mapping of "
                          f"RandomStart fields or a RandomStart, got {value!r}")
    return None if value.probability == 0.0 else value

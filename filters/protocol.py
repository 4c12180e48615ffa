"""What the safety filter wrapper reads from an environment.

:mod:`filters` knows nothing of :mod:`safe_nav_env`. :class:`SafetyFilterWrapper`
talks to ``env.unwrapped`` through the small protocol below, so any environment
that offers these attributes can be filtered.

Conventions: positions in m, velocities in m/s, accelerations in m/s², time in s.
The ego state is ``x = [p_x, p_y, v_x, v_y]`` and its position is ``y = C x``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class FilterableEnv(Protocol):
    """Attributes of ``env.unwrapped`` used by :class:`filters.SafetyFilterWrapper`.

    Attributes
    ----------
    dt
        Sampling time ``T_s`` of the ego dynamics, in s.
    dynamics
        ``(A, B, C)``: ``x_{t+1} = A x_t + B u_t``, ``y_t = C x_t``; shapes
        ``(n, n)``, ``(n, m)``, ``(d, n)``.
    ego_state
        Current ego state ``x_t``, shape ``(n,)``.
    ego_radius
        Radius of the ego disc, in m.
    obstacle_radii
        Radius of each obstacle disc, shape ``(n_obstacles,)``, in m. The number
        of obstacles may change from one episode to the next.
    obstacle_positions, obstacle_velocities
        Current positions and nominal velocities, shape ``(n_obstacles, d)``.
    predictions
        Prediction samples for steps ``t+1 .. t+T``, shape
        ``(n_obstacles, n_samples, T, d)``, drawn when the current observation was made.
    input_bounds
        ``(low, high)`` of the ego input box, each shape ``(m,)``.
    position_bounds
        ``(low, high)`` of the box the ego position must stay in (the arena),
        each shape ``(d,)``.
    goal
        Goal position, shape ``(d,)``.
    render_hooks
        Callables ``hook(ax)`` that the renderer calls with the matplotlib axes
        after drawing the scene, so a wrapper can draw its halfspaces.

    Optional: ``max_speed``, the ego's speed limit ``||v||_2 <= max_speed`` in m/s
    (the velocity is the state's second half), which the filter then keeps; ``inf`` or
    absent: none. ``applied_input(state, action) -> u``, the input the environment
    applies for a finite ``action`` at ``state`` (clipped to the box and to the speed
    limit), which the reference makers use to roll their references out as the
    environment would; absent: the action clipped to the box. ``state`` (length
    ``2 d``) and ``action`` (length ``d``) come as sequences of floats (lists in the
    held-action reference, arrays elsewhere): accept both.
    """

    dt: float
    dynamics: tuple[np.ndarray, np.ndarray, np.ndarray]
    ego_state: np.ndarray
    ego_radius: float
    obstacle_radii: np.ndarray
    obstacle_positions: np.ndarray
    obstacle_velocities: np.ndarray
    predictions: np.ndarray
    input_bounds: tuple[np.ndarray, np.ndarray]
    position_bounds: tuple[np.ndarray, np.ndarray]
    goal: np.ndarray
    render_hooks: list[Callable[[Any], None]]

    def observe(
        self,
        ego_state: np.ndarray,
        obstacle_positions: np.ndarray,
        obstacle_velocities: np.ndarray,
    ) -> np.ndarray:
        """Observation the agent would receive in the given (hypothetical) situation.

        Used to roll a policy out over the horizon against the obstacles'
        predicted mean motion without touching the environment's state.
        """
        ...

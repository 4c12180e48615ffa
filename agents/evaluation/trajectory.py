"""What one episode did, step by step: the :class:`Trajectory` the runner records.

:func:`agents.evaluation.runner.run_episode` fills a :class:`TrajectoryRecorder` from the
environment after every step when asked (``record_trajectory=True``); the figures
(:mod:`agents.evaluation.plots`) and the paper's reproduction
(:mod:`agents.experiments.reproduce`) read the result.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Trajectory", "TrajectoryRecorder"]


@dataclass
class Trajectory:
    """What one episode did, step by step (``S`` steps, ``n`` obstacles), for plots and reports.

    Attributes
    ----------
    ego
        (S+1, 2) ego positions at the samples, in m.
    obstacles
        (S+1, n, 2) realised obstacle positions, in m.
    obstacle_radii, ego_radius, goal
        Radii (m) and the goal position (m) of the episode.
    halfspaces
        Per step with halfspaces, ``(normals (n, T, 2), offsets (n, T))``.
    statuses
        The filter's status at each step 1..S.
    frames
        ``rgb_array`` frames, if rendered.
    collisions
        ``collisions[t]``: the continuous-time collision flag of step ``t + 1``
        (``info["collision"]``).
    ego_states
        (S+1, 4) ego states ``[p, v]`` (m, m/s).
    inputs
        (S, 2) applied accelerations, in m/s².
    distances
        (S+1, n) sampled distances to collision, in m (``info["distance_to_collision"]``;
        with padded info, one column per slot, ``inf`` for an absent obstacle).
    swept
        (S, n) minimum clearance over each step, in m (continuous time,
        ``info["swept_distance_to_collision"]``, padded likewise).
    filter_times
        (S,) the filter's time per step, in s.
    dt
        Sampling time, in s.
    """

    ego: np.ndarray
    obstacles: np.ndarray
    obstacle_radii: np.ndarray
    ego_radius: float
    goal: np.ndarray
    halfspaces: list[tuple[np.ndarray, np.ndarray]]
    statuses: list[str]
    frames: list[np.ndarray]
    collisions: list[bool] = field(default_factory=list)
    ego_states: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    inputs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    distances: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    swept: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    filter_times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    dt: float = 0.0


class TrajectoryRecorder:
    """Collects an episode's states, distances, inputs, halfspaces and frames.

    The collisions, statuses and filter times come from ``per_step``, the list of
    ``(collision, sampled collision, status, intervention, filter time)`` per step that
    :class:`agents.evaluation.runner.EpisodeStats` fills (its ``per_step``).
    """

    def __init__(self, env: Any, render: bool, info: dict[str, Any],
                 per_step: list[tuple[bool, bool, str, float, float]]) -> None:
        self._env, self._base, self._render, self._per_step = env, env.unwrapped, render, per_step
        # Per sample (states, obstacles, distances, frames) and per step (the others).
        (self._states, self._obstacles, self._distances, self._inputs, self._swept,
         self._halfspaces, self._frames) = ([] for _ in range(7))
        self._snapshot(info)

    def _snapshot(self, info: dict[str, Any]) -> None:
        self._states.append(np.array(self._base.ego_state, dtype=float))
        self._obstacles.append(np.array(self._base.obstacle_positions, dtype=float))
        self._distances.append(np.array(info["distance_to_collision"], dtype=float))
        if self._render:
            self._frames.append(self._env.render())

    def record(self, info: dict[str, Any]) -> None:
        """After a step: the new state and positions, the clearances and what the filter did."""
        self._snapshot(info)
        report = info["filter"]
        self._inputs.append(np.array(report["applied_action"], dtype=float))
        self._swept.append(np.array(info["swept_distance_to_collision"], dtype=float))
        if report["normals"] is not None:
            self._halfspaces.append((np.array(report["normals"]), np.array(report["offsets"])))

    def trajectory(self) -> Trajectory:
        base = self._base
        n = len(base.obstacle_radii)

        def stack(rows: list, shape: tuple[int, ...]) -> np.ndarray:
            if not rows:  # no step: the width of an empty series is its nominal one
                return np.zeros((0, *(n if size == -1 else size for size in shape)))
            return np.asarray(rows, dtype=float).reshape((len(rows), *shape))

        states = stack(self._states, (4,))
        collisions, _, statuses, _, times = (
            [list(column) for column in zip(*self._per_step, strict=True)] or [[]] * 5)
        return Trajectory(
            ego=states[:, :2].copy(), obstacles=stack(self._obstacles, (n, 2)),
            obstacle_radii=np.array(base.obstacle_radii, dtype=float),
            ego_radius=float(base.ego_radius), goal=np.array(base.goal, dtype=float),
            halfspaces=self._halfspaces, statuses=statuses, frames=self._frames,
            collisions=collisions, ego_states=states,
            inputs=stack(self._inputs, (2,)), distances=stack(self._distances, (-1,)),
            swept=stack(self._swept, (-1,)),
            filter_times=np.asarray(times, dtype=float), dt=float(base.dt))

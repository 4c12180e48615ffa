r"""Reactive humans: ORCA (pyrvo) or the social force model (pysocialforce).

Both simulators move ``n`` humans toward their goals for one period ``dt`` at a time,
through their own library:

* :class:`OrcaHumans` — optimal reciprocal collision avoidance (van den Berg et al.,
  2011) in `pyrvo <https://pypi.org/project/pyrvo/>`_, with CrowdNav's parameters
  (neighbour distance 10 m, 10 neighbours, time horizon 5 s, radius ``r + 0.01`` m,
  maximum speed ``v_pref``). Each human's new velocity depends on its own preferred
  velocity (toward its goal, at most ``v_pref``, slowing inside 1 m of it) and on the
  others' current positions and velocities, which is what CrowdNav's per-human ORCA
  computes; one shared simulation gives the same velocities in one call.
* :class:`SocialForceHumans` — the extended social force model (Helbing & Molnár
  1995; Moussaïd et al. 2010) in `pysocialforce
  <https://pypi.org/project/pysocialforce/>`_, with its default forces and the step
  width set to ``dt``.

The robot is *visible* (an agent the humans react to, whose state is overwritten by
the robot's each step) or *invisible* (CrowdNav's main setting: humans ignore it).
Positions in m, velocities in m/s, time in s.
"""

from __future__ import annotations

import contextlib
import logging
import os
import tempfile
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["HUMAN_POLICIES", "HumanSimulator", "OrcaHumans", "SocialForceHumans",
           "make_humans"]

HUMAN_POLICIES = ("orca", "social_force")
"""Names of the human simulators (:func:`make_humans`)."""

ORCA_NEIGHBOUR_DISTANCE = 10.0
"""Centre distance within which ORCA considers another agent, m (CrowdNav's)."""

ORCA_MAX_NEIGHBOURS = 10
"""Most agents ORCA considers (CrowdNav's: everyone in the five-human scene)."""

ORCA_TIME_HORIZON = 5.0
"""Time for which ORCA's velocities are collision free with respect to the others, s."""

ORCA_RADIUS_PADDING = 0.01
"""Added to every radius inside ORCA, m (CrowdNav's ``radius + 0.01``)."""


@dataclass(eq=False)
class HumanSimulator:
    """Moves ``n`` humans toward their goals, one period at a time.

    Parameters
    ----------
    dt
        Period of :meth:`step`, s.
    radius
        Human disc radius, m.
    preferred_speed
        Walking speed a human aims for, m/s.
    robot_radius
        Robot disc radius, m (used when the robot is visible).
    robot_visible
        Whether the humans react to the robot.

    Attributes
    ----------
    positions, velocities, goals
        Per human, ``(n, 2)``, in m, m/s and m (empty before :meth:`reset`).
    """

    dt: float
    radius: float
    preferred_speed: float
    robot_radius: float
    robot_visible: bool
    positions: np.ndarray = field(init=False, default_factory=lambda: np.zeros((0, 2)))
    velocities: np.ndarray = field(init=False, default_factory=lambda: np.zeros((0, 2)))
    goals: np.ndarray = field(init=False, default_factory=lambda: np.zeros((0, 2)))

    def reset(self, positions: np.ndarray, goals: np.ndarray) -> None:
        """Place the humans at rest at ``positions`` (n, 2) with ``goals`` (n, 2)."""
        self.positions = np.array(positions, dtype=float)
        self.velocities = np.zeros_like(self.positions)
        self.goals = np.array(goals, dtype=float)

    def preferred_velocities(self) -> np.ndarray:
        """Toward the goal ``g`` at ``preferred_speed`` ``v``, proportionally slower inside 1 s
        of it: ``(g - p) v / max(||g - p||, v)``, in m/s."""
        to_goal = self.goals - self.positions
        distance = np.hypot(to_goal[:, 0], to_goal[:, 1])
        speed = self.preferred_speed
        return to_goal * (speed / np.maximum(distance, speed))[:, None]

    def step(self, robot_position: np.ndarray, robot_velocity: np.ndarray) -> np.ndarray:
        """Move every human for ``dt``; returns the new positions (n, 2)."""
        raise NotImplementedError


class OrcaHumans(HumanSimulator):
    """Humans driven by ORCA through pyrvo (see the module docstring)."""

    def reset(self, positions: np.ndarray, goals: np.ndarray) -> None:
        import pyrvo

        super().reset(positions, goals)
        params = (ORCA_NEIGHBOUR_DISTANCE, ORCA_MAX_NEIGHBOURS, ORCA_TIME_HORIZON,
                  ORCA_TIME_HORIZON)
        sim = pyrvo.RVOSimulator(self.dt, *params, self.radius + ORCA_RADIUS_PADDING,
                                 self.preferred_speed)
        for p in self.positions:
            sim.add_agent((float(p[0]), float(p[1])), *params,
                          self.radius + ORCA_RADIUS_PADDING, self.preferred_speed, (0.0, 0.0))
        self._robot = None
        if self.robot_visible:
            self._robot = sim.add_agent((0.0, 0.0), *params,
                                        self.robot_radius + ORCA_RADIUS_PADDING,
                                        self.preferred_speed, (0.0, 0.0))
        self._sim = sim

    def step(self, robot_position: np.ndarray, robot_velocity: np.ndarray) -> np.ndarray:
        sim = self._sim
        n = self.positions.shape[0]
        for i, (p, v, w) in enumerate(zip(self.positions.tolist(), self.velocities.tolist(),
                                          self.preferred_velocities().tolist(), strict=True)):
            sim.set_agent_position(i, tuple(p))
            sim.set_agent_velocity(i, tuple(v))
            sim.set_agent_pref_velocity(i, tuple(w))
        if self._robot is not None:
            position, velocity = tuple(robot_position.tolist()), tuple(robot_velocity.tolist())
            sim.set_agent_position(self._robot, position)
            sim.set_agent_velocity(self._robot, velocity)
            sim.set_agent_pref_velocity(self._robot, velocity)
        sim.do_step()
        velocities = [sim.get_agent_velocity(i) for i in range(n)]
        self.velocities = np.array([(float(v.x), float(v.y)) for v in velocities]).reshape(n, 2)
        self.positions = self.positions + self.dt * self.velocities
        return self.positions


@contextlib.contextmanager
def _quiet_import():
    """Import pysocialforce without its side effects on the caller.

    On import it opens ``file.log`` in the working directory and sets the root
    logger to DEBUG with a handler of its own; here the import runs in a temporary
    directory with logging disabled, and the root logger's level and handlers are
    restored afterwards.
    """
    root = logging.getLogger()
    level, handlers = root.level, list(root.handlers)
    disabled = logging.root.manager.disable
    cwd = os.getcwd()
    with tempfile.TemporaryDirectory() as scratch:
        os.chdir(scratch)
        logging.disable(logging.CRITICAL)  # nothing is logged while it imports
        try:
            yield
        finally:
            logging.disable(disabled)
            os.chdir(cwd)
            for handler in list(root.handlers):
                if handler not in handlers:
                    root.removeHandler(handler)
                    handler.close()
            root.setLevel(level)


class SocialForceHumans(HumanSimulator):
    """Humans driven by the social force model through pysocialforce."""

    def reset(self, positions: np.ndarray, goals: np.ndarray) -> None:
        with _quiet_import():
            import pysocialforce

        super().reset(positions, goals)
        self._module = pysocialforce
        self._sim = None

    def _state(self, robot_position: np.ndarray, robot_velocity: np.ndarray) -> np.ndarray:
        rows = [np.hstack([self.positions, self.velocities, self.goals])]
        if self.robot_visible:
            robot = np.hstack([robot_position, robot_velocity,
                               robot_position + robot_velocity * self.dt])
            rows.append(robot[None])
        return np.vstack(rows)

    def step(self, robot_position: np.ndarray, robot_velocity: np.ndarray) -> np.ndarray:
        state = self._state(np.asarray(robot_position, float), np.asarray(robot_velocity, float))
        n = self.positions.shape[0]
        if self._sim is None:  # the library's default forces
            self._sim = self._module.Simulator(state.copy())
            peds = self._sim.peds
            peds.step_width = self.dt
            peds.agent_radius = self.radius
            # Speed cap: 1.3 x the preferred speed (the library's multiplier of the start speed).
            peds.initial_speeds = np.full(state.shape[0], self.preferred_speed)
            peds.max_speeds = peds.max_speed_multiplier * peds.initial_speeds
        else:  # the robot's row is the robot's state, not the model's
            peds = self._sim.peds
            peds.state[:, :6] = state
            peds.ped_states = peds.ped_states[-1:]  # the library keeps every state
        self._sim.step()
        new = self._sim.peds.state
        self.positions = np.array(new[:n, 0:2])
        self.velocities = np.array(new[:n, 2:4])
        return self.positions


def make_humans(policy: str, **kwargs: Any) -> HumanSimulator:
    """The human simulator named ``policy`` (:data:`HUMAN_POLICIES`)."""
    simulators = {"orca": OrcaHumans, "social_force": SocialForceHumans}
    return simulators[policy](**kwargs)

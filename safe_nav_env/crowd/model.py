r"""The crowd as the environment's obstacle model: humans that react, not lanes with noise.

:class:`CrowdModel` is an :class:`~safe_nav_env.obstacles.ObstacleModel` whose motion is
the human simulator's (:mod:`safe_nav_env.crowd.humans`), so the ego's dynamics, the
observation, the reward, the continuous-time collisions and the safety-filter protocol
are the environment's own; no noise law is added to the realised motion.

Predictions (the environment's own sampler, ``predictor="environment"``): the
obstacle model's, with each human's lane the line through its current position along
its current velocity, i.e. the constant-velocity extrapolation plus independent
samples of the prediction law at every look-ahead step,

.. math::

    \hat p^{(j)}_{t+k} = p_t + k T_s v_t + \varepsilon^{(j)}_k,

which uses nothing but the present state (the crowd environment's default). The
constant-velocity Kalman predictor on the observed positions
(:class:`~safe_nav_env.predictors.ConstantVelocityKalman`, ``predictor="kalman"``)
is the alternative whose spread grows with ``k``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from safe_nav_env.crowd.humans import HumanSimulator
from safe_nav_env.noise import NoiseLaw
from safe_nav_env.obstacles import ObstacleModel
from safe_nav_env.scenarios import ObstacleSpec

__all__ = ["CrowdModel"]


class CrowdModel(ObstacleModel):
    """``n`` reactive humans as the environment's obstacle model.

    Parameters
    ----------
    humans
        The simulator that moves them.
    specs
        The humans at rest at their starts (their radii are the discs'), in m.
    goals
        Goal positions, shape ``(n, 2)``, in m.
    dt
        Sampling time, in s.
    robot_state
        Called with no argument, returns the ego state ``[p, v]`` (4,) after its move,
        which a visible robot shows the humans.

    Attributes
    ----------
    positions, velocities, chord_starts, radii
        As :class:`~safe_nav_env.obstacles.ObstacleModel`'s; the velocities are the
        simulator's (m/s).
    """

    def __init__(self, humans: HumanSimulator, specs: Sequence[ObstacleSpec], goals: np.ndarray,
                 dt: float, robot_state: Callable[[], np.ndarray]) -> None:
        self.humans = humans
        self.goals = np.array(goals, dtype=float).reshape(-1, 2)
        self._robot_state = robot_state
        super().__init__(specs, dt)

    def reset(self, rng: np.random.Generator | None) -> None:
        """Put every human at rest at its start (``rng`` is not used: the start is drawn
        with the scenario; ``None`` at construction, where the simulator is not built)."""
        super().reset(None)
        if rng is not None:
            self.humans.reset(self.starts, self.goals)

    def step(self, rng: np.random.Generator, law: NoiseLaw) -> np.ndarray:
        """Move the humans for ``dt`` (the simulator's motion; ``rng`` and ``law`` are not
        used); each lane then runs through the new position along the new velocity."""
        robot = np.asarray(self._robot_state(), dtype=float)
        positions = np.array(self.humans.step(robot[:2], robot[2:4]), dtype=float)
        self.step_count += 1
        self._set_state(positions, np.array(self.humans.velocities, dtype=float), positions)
        return positions

r"""The crowd as the environment's obstacle model: humans that react, not lanes with noise.

:class:`CrowdModel` stands in for :class:`~safe_nav_env.obstacles.ObstacleModel` inside
:class:`~safe_nav_env.env.SafeNavEnv` (same attributes and methods), so the ego's
dynamics, the observation, the reward, the continuous-time collisions and the
safety-filter protocol are the environment's own. The realised motion is the human
simulator's (:mod:`safe_nav_env.crowd.humans`); no noise law is added to it.

Predictions (the environment's own sampler, ``predictor="environment"``): the
constant-velocity extrapolation of each human's current velocity plus independent
samples of the prediction law at every look-ahead step,

.. math::

    \hat p^{(j)}_{t+k} = p_t + k T_s v_t + \varepsilon^{(j)}_k,

which uses nothing but the present state (the crowd environment's default). The
constant-velocity Kalman predictor on the observed positions
(:class:`~safe_nav_env.predictors.ConstantVelocityKalman`, ``predictor="kalman"``)
is the alternative whose spread grows with ``k``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from safe_nav_env.crowd.humans import HumanSimulator
from safe_nav_env.noise import NoiseLaw

__all__ = ["CrowdModel"]


class CrowdModel:
    """``n`` reactive humans in the obstacle-model interface of the environment.

    Parameters
    ----------
    humans
        The simulator that moves them.
    starts, goals
        Start and goal positions, shape ``(n, 2)``, in m.
    radius
        Human radius, in m.
    dt
        Sampling time, in s.
    robot_state
        Called with no argument, returns the ego state ``[p, v]`` (4,) after its move,
        which a visible robot shows the humans.

    Attributes
    ----------
    positions, velocities
        Current positions (m) and velocities (m/s), shape ``(n, 2)``.
    chord_starts
        Positions before the last step (the start after :meth:`reset`), shape ``(n, 2)``.
    radii
        Radii, shape ``(n,)``, in m.
    """

    def __init__(self, humans: HumanSimulator, starts: np.ndarray, goals: np.ndarray,
                 radius: float, dt: float, robot_state: Callable[[], np.ndarray]) -> None:
        self.humans = humans
        self.starts = np.array(starts, dtype=float).reshape(-1, 2)
        self.goals = np.array(goals, dtype=float).reshape(-1, 2)
        self.n = self.starts.shape[0]
        self.dt = float(dt)
        self.initial_velocities = np.zeros((self.n, 2))
        self.radii = np.full(self.n, float(radius))
        self.radii.flags.writeable = False
        self._robot_state = robot_state
        self._at_start()

    def reset(self, rng: np.random.Generator) -> None:
        """Put every human at rest at its start (``rng`` is not used: the start is drawn
        with the scenario)."""
        self.humans.reset(self.starts, self.goals)
        self._at_start()

    def _at_start(self) -> None:
        self.step_count = 0
        self.positions = self.starts.copy()
        self.velocities = self.initial_velocities.copy()
        self.chord_starts = self.positions

    def step(self, rng: np.random.Generator, law: NoiseLaw) -> np.ndarray:
        """Move the humans for ``dt`` (the simulator's motion; ``law`` is not used)."""
        robot = np.asarray(self._robot_state(), dtype=float)
        self.chord_starts = self.positions
        self.positions = np.array(self.humans.step(robot[:2], robot[2:4]), dtype=float)
        self.velocities = np.array(self.humans.velocities, dtype=float)
        self.step_count += 1
        return self.positions

    def predict(self, rng: np.random.Generator, law: NoiseLaw, n_samples: int,
                horizon: int) -> np.ndarray:
        """Constant-velocity samples (see the module docstring), ``(n, N_s, T, 2)`` in m."""
        samples = law.sample(rng, (self.n, n_samples, horizon, 2))
        steps = np.arange(1, horizon + 1, dtype=float)[None, :, None] * self.dt
        nominal = self.positions[:, None, :] + steps * self.velocities[:, None, :]
        samples += nominal[:, None]
        return samples

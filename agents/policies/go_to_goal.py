"""An obstacle-blind go-to-goal controller: the reference that knows nothing of obstacles.

:class:`GoToGoalPolicy` steers the ego straight at its goal, whatever the obstacles do.
Unfiltered it collides whenever an obstacle crosses the straight line; filtered, every
avoidance manoeuvre is the safety filter's. It is the third reference of the stress
suite (:mod:`agents.experiments.stress`), next to the PPO planner, because its
collisions are the filter's alone.

It is a proportional-derivative law with a speed cap, on the observation of
:class:`safe_nav_env.env.SafeNavEnv` (``[p, v, g - p, ...]``):

.. math::

    v_d = \\operatorname{cap}_{v_{max}}\\big(k_p\\,(g - p)\\big), \\qquad
    u = \\operatorname{clip}_{[-a_{max}, a_{max}]}\\big(k_d\\,(v_d - v)\\big),

with ``cap`` scaling a vector down to norm ``v_max``: the ego accelerates (at the input
bound when far from ``v_d``) to a cruise speed towards the goal and slows down
proportionally to the distance on arrival. ``k_p`` in 1/s, ``k_d`` in 1/s, ``v_max``
in m/s, ``a_max`` in m/s² (the environment's bound).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from filters._validation import finite_scalar
from safe_nav_env.constants import MAX_ACCELERATION

__all__ = ["GoToGoalPolicy"]


class GoToGoalPolicy:
    """Obstacle-blind PD controller to the goal, with Stable-Baselines3's ``predict``.

    Parameters
    ----------
    gain
        ``k_p``, in 1/s: the desired velocity per m of distance to the goal (> 0).
    damping
        ``k_d``, in 1/s: the acceleration per m/s of velocity error (> 0; with
        ``T_s k_d < 2`` the discrete velocity loop is stable, default ``0.2 · 3 = 0.6``).
    cruise_speed
        ``v_max``, in m/s (> 0).
    max_acceleration
        ``a_max``, in m/s² per axis (> 0): the environment's input bound.

    Raises
    ------
    InvalidParameterError
        If a parameter is not a finite number > 0.
    """

    def __init__(self, *, gain: float = 1.5, damping: float = 3.0, cruise_speed: float = 3.0,
                 max_acceleration: float = MAX_ACCELERATION) -> None:
        self.gain, self.damping, self.cruise_speed, self.max_acceleration = (
            finite_scalar(name, value, low=0.0, strict=True) for name, value in (
                ("gain", gain), ("damping", damping), ("cruise_speed", cruise_speed),
                ("max_acceleration", max_acceleration)))

    @classmethod
    def from_env(cls, env: Any, **kwargs: Any) -> GoToGoalPolicy:
        """The controller at the input bound of ``env`` (``env.unwrapped.max_acceleration``)."""
        bound = getattr(env.unwrapped, "max_acceleration", MAX_ACCELERATION)
        return cls(max_acceleration=float(bound), **kwargs)

    def __repr__(self) -> str:
        return (f"GoToGoalPolicy(gain={self.gain}, damping={self.damping}, "
                f"cruise_speed={self.cruise_speed}, max_acceleration={self.max_acceleration})")

    def action(self, velocity: np.ndarray, to_goal: np.ndarray) -> np.ndarray:
        """The acceleration (m/s², shape ``(2,)``) given ``v`` (m/s) and ``g - p`` (m)."""
        desired = self.gain * np.asarray(to_goal, dtype=np.float64)
        speed = float(np.hypot(desired[0], desired[1]))
        if speed > self.cruise_speed:
            desired *= self.cruise_speed / speed
        u = self.damping * (desired - np.asarray(velocity, dtype=np.float64))
        return np.clip(u, -self.max_acceleration, self.max_acceleration)

    def predict(self, observation: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:
        """Stable-Baselines3's signature: the float32 action for one observation (or a batch).

        The observation is :class:`~safe_nav_env.env.SafeNavEnv`'s: velocity at
        ``[2:4]``, goal minus position at ``[4:6]``; everything else is ignored.
        """
        obs = np.asarray(observation, dtype=np.float64)
        actions = [self.action(row[2:4], row[4:6]) for row in obs.reshape(-1, obs.shape[-1])]
        return np.asarray(actions, dtype=np.float32).reshape(obs.shape[:-1] + (2,)), None

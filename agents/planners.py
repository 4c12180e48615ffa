"""The paper's obstacle-agnostic MPC reference planner.

Section IV-B of the paper generates the reference trajectory with "an
obstacle-agnostic MPC-based motion planner with a target goal state"; the
authors' code uses a goal-tracking MPC with weights Q = 1, Q_T = 3, R = 1 and
horizon 10. It ignores the obstacles entirely: avoiding them is the safety
filter's job. The planner is the same QP as the safety filter
(:class:`filters.MPCSafetyFilter`) with no halfspaces and the goal state (goal
position, zero velocity) as the reference at every step.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from filters import MPCSafetyFilter
from filters.errors import InvalidArrayError, InvalidParameterError
from filters.protocol import FilterableEnv

OBSERVATION_EGO_STATE = slice(0, 4)
"""Ego state ``[p_x, p_y, v_x, v_y]`` in a ``safe_nav_env`` observation."""
OBSERVATION_GOAL_OFFSET = slice(4, 6)
"""Goal position minus ego position in a ``safe_nav_env`` observation."""


class MPCReferencePlanner:
    """Goal-tracking MPC that ignores obstacles (the paper's reference planner).

    .. math::
        \\min_u \\sum_{t=0}^{T-1} u_t^\\top R u_t
        + \\sum_{t=1}^{T-1} (x_t - x_g)^\\top Q (x_t - x_g)
        + (x_T - x_g)^\\top Q_T (x_T - x_g)

    subject to the ego dynamics and input and arena bounds, with
    :math:`x_g = [g, 0]` the goal position at rest.

    Parameters
    ----------
    dynamics
        ``(A, B, C)`` of the ego.
    input_bounds, position_bounds
        ``(low, high)`` boxes of the input (m/s²) and of the position (m).
    horizon
        Planning horizon in steps.
    Q, Q_terminal, R
        Scalar weights (times identity) or matrices, in the ``x' Q x`` convention.

    It offers Stable-Baselines3's ``predict(observation, deterministic=True)`` so it
    can stand wherever a PPO model does, and the reference-maker signature
    ``planner(env, action, horizon) -> (states, inputs)`` so the safety filter can
    track its whole plan rather than a held action.
    """

    def __init__(
        self,
        dynamics: tuple[np.ndarray, np.ndarray, np.ndarray],
        *,
        input_bounds: tuple[np.ndarray, np.ndarray],
        position_bounds: tuple[np.ndarray, np.ndarray] | None = None,
        horizon: int = 10,
        Q: float | np.ndarray = 1.0,
        Q_terminal: float | np.ndarray = 3.0,
        R: float | np.ndarray = 1.0,
    ) -> None:
        A, B, C = (np.asarray(M, dtype=float) for M in dynamics)
        n, m = B.shape
        if C.shape[0] * 2 != n:
            raise InvalidArrayError(
                f"MPCReferencePlanner expects a state [position, velocity]; C has shape {C.shape}"
                f" and the state has {n} entries"
            )
        self.dynamics = (A, B, C)
        self.horizon = int(horizon)
        self._qp = MPCSafetyFilter(
            A, B, C, horizon=self.horizon,
            Q=_weight("Q", Q, n), Q_terminal=_weight("Q_terminal", Q_terminal, n),
            R=_weight("R", R, m),
            input_bounds=input_bounds, position_bounds=position_bounds, n_obstacles=0,
        )
        self.last_status: str | None = None

    @classmethod
    def from_env(cls, env: Any, **kwargs: Any) -> MPCReferencePlanner:
        """Build the planner from a ``safe_nav_env`` environment (or any wrapper of one)."""
        base: FilterableEnv = env.unwrapped
        kwargs.setdefault("horizon", 10)
        return cls(base.dynamics, input_bounds=base.input_bounds,
                   position_bounds=base.position_bounds, **kwargs)

    def plan(self, state: np.ndarray, goal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Plan from ``state`` toward ``goal`` (at rest).

        Returns
        -------
        states : numpy.ndarray
            Shape (T+1, n), row 0 is ``state``.
        inputs : numpy.ndarray
            Shape (T, m), in m/s².
        """
        state = np.asarray(state, dtype=float)
        goal = np.asarray(goal, dtype=float)
        target = np.concatenate([goal, np.zeros(state.shape[0] - goal.shape[0])])
        reference = np.tile(target, (self.horizon + 1, 1))
        reference[0] = state
        result = self._qp.solve(state, reference)
        self.last_status = str(result.status.value)
        return result.states, result.inputs

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        """First planned input for a ``safe_nav_env`` observation (or a batch of them).

        The observation's first six entries are the ego state and the goal offset.
        """
        observation = np.asarray(observation, dtype=float)
        batch = observation.reshape(-1, observation.shape[-1])
        actions = np.empty((batch.shape[0], self.dynamics[1].shape[1]), dtype=np.float32)
        for k, row in enumerate(batch):
            ego = row[OBSERVATION_EGO_STATE]
            goal = ego[:2] + row[OBSERVATION_GOAL_OFFSET]
            actions[k] = self.plan(ego, goal)[1][0]
        return (actions if observation.ndim > 1 else actions[0]), None

    def __call__(
        self, env: FilterableEnv, action: np.ndarray, horizon: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Reference maker for :class:`filters.SafetyFilterWrapper`: the whole plan."""
        if horizon != self.horizon:
            raise InvalidParameterError(
                f"the filter horizon {horizon} differs from the planner horizon {self.horizon}"
            )
        return self.plan(env.ego_state, env.goal)


def _weight(name: str, value: float | np.ndarray, size: int) -> np.ndarray:
    weight = np.asarray(value, dtype=float)
    if weight.ndim == 0:
        return float(weight) * np.eye(size)
    if weight.shape != (size, size):
        raise InvalidArrayError(f"{name} must be a scalar or shape ({size}, {size}), got "
                                f"{weight.shape}")
    return weight

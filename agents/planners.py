"""The paper's obstacle-agnostic MPC reference planner.

Section IV-B of the paper generates the reference trajectory with "an
obstacle-agnostic MPC-based motion planner with a target goal state"; the
authors' code uses a goal-tracking MPC with weights Q = 1, Q_T = 3, R = 1 and
horizon 10. It ignores the obstacles entirely: avoiding them is the safety
filter's job.

Two weight conventions are offered, chosen with ``convention=`` (the same numbers
mean different costs in each):

``"quadratic"`` (default, this package's convention)
    ``x' Q x``: the weights are the Hessian blocks of the cost, every input
    ``u_0 .. u_{T-1}`` is penalised, and the position stays in the arena. The
    planner is the same QP as the safety filter (:class:`filters.MPCSafetyFilter`)
    with no halfspaces and the goal state as the reference at every step.
``"authors_code"``
    What the authors' ``MPCReferenceTrajectory`` minimises,
    ``sum_squares((x_T - g) Q_T) + sum_{t=1}^{T-1} sum_squares((x_t - g) Q) +
    sum_squares(u_t R)``: the effective (Hessian) weights are ``Q Q'``,
    ``Q_T Q_T'`` and ``R R'`` (1, 9 and 1 for their scalars 1, 3, 1), the first
    input ``u_0`` is not penalised at all, and there is no position bound. With
    their input bound ``|u| <= 100`` this plans an almost unbounded first
    acceleration toward the goal.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from filters import MPCSafetyFilter
from filters._validation import finite_array, integer_at_least
from filters.constants import HORIZON
from filters.errors import InvalidArrayError, InvalidParameterError
from filters.protocol import FilterableEnv

OBSERVATION_EGO_STATE = slice(0, 4)
"""Ego state ``[p_x, p_y, v_x, v_y]`` in a ``safe_nav_env`` observation."""
OBSERVATION_GOAL_OFFSET = slice(4, 6)
"""Goal position minus ego position in a ``safe_nav_env`` observation."""

CONVENTIONS = ("quadratic", "authors_code")
"""Weight conventions of :class:`MPCReferencePlanner` (see the module docstring)."""

AUTHORS_CODE_PLANNER = dict(Q=1.0, Q_terminal=3.0, R=1.0, horizon=10, max_acceleration=100.0)
"""The authors' reference planner (``experiment_setup.py``): weights in the
``"authors_code"`` convention, horizon in steps, input bound in m/s² per axis."""


class MPCReferencePlanner:
    r"""Goal-tracking MPC that ignores obstacles (the paper's reference planner).

    With ``convention="quadratic"``:

    .. math::
        \min_u \sum_{t=0}^{T-1} u_t^\top R u_t
        + \sum_{t=1}^{T-1} (x_t - x_g)^\top Q (x_t - x_g)
        + (x_T - x_g)^\top Q_T (x_T - x_g)

    subject to the ego dynamics, input and arena bounds and the speed limit (the polygon
    inscribed in :math:`\|v_t\| \le v_\max`, as in the safety filter), with
    :math:`x_g = [g, 0]` the goal position at rest. With
    ``convention="authors_code"`` (the authors' code, read as written):

    .. math::
        \min_u \sum_{t=1}^{T-1} \left(\|Q^\top (x_t - x_g)\|^2 + \|R^\top u_t\|^2\right)
        + \|Q_T^\top (x_T - x_g)\|^2

    subject to the dynamics and the input bounds only: ``u_0`` is free and the
    arena is not a constraint. It is solved exactly as a bounded linear least-squares
    problem (unconstrained least squares when that already satisfies the bounds).

    It offers Stable-Baselines3's ``predict(observation, deterministic=True)`` so it
    can stand wherever a PPO model does, and the reference-maker signature
    ``planner(env, action, horizon) -> (states, inputs)`` so the safety filter can
    track its whole plan rather than a held action.

    Parameters
    ----------
    dynamics
        ``(A, B, C)`` of the ego.
    input_bounds, position_bounds
        ``(low, high)`` boxes of the input (m/s²) and of the position (m).
        ``position_bounds`` must be ``None`` with ``convention="authors_code"``.
    horizon
        Planning horizon in steps.
    Q, Q_terminal, R
        Scalar weights (times identity) or matrices, read in ``convention``.
    convention
        ``"quadratic"`` or ``"authors_code"`` (see above).
    max_speed
        Speed limit in m/s kept on every planned step (``"quadratic"`` only; ``inf``,
        the default: none).

    Raises
    ------
    InvalidParameterError
        If ``convention`` is unknown, the horizon is not a positive integer, or
        ``position_bounds`` or a finite ``max_speed`` is given with
        ``convention="authors_code"``.
    InvalidArrayError
        If a weight or bound has the wrong shape or is not finite.
    """

    def __init__(self, dynamics: tuple[np.ndarray, np.ndarray, np.ndarray], *,
                 input_bounds: tuple[np.ndarray, np.ndarray],
                 position_bounds: tuple[np.ndarray, np.ndarray] | None = None,
                 horizon: int = HORIZON, Q: float | np.ndarray = 1.0,
                 Q_terminal: float | np.ndarray = 3.0, R: float | np.ndarray = 1.0,
                 convention: str = "quadratic", max_speed: float = np.inf) -> None:
        if convention not in CONVENTIONS:
            raise InvalidParameterError(
                f"convention must be one of {CONVENTIONS}, got {convention!r}")
        A, B, C = (np.asarray(M, dtype=float) for M in dynamics)
        n, m = B.shape
        if C.shape[0] * 2 != n:
            raise InvalidArrayError(f"MPCReferencePlanner expects a state [position, velocity]; "
                                    f"C has shape {C.shape} and the state has {n} entries")
        self.dynamics = (A, B, C)
        self.horizon = integer_at_least("horizon", horizon)
        self.convention = convention
        self.weights = weights = (_weight("Q", Q, n), _weight("Q_terminal", Q_terminal, n),
                                  _weight("R", R, m))
        """``(Q, Q_terminal, R)`` as given, as matrices, in ``convention``."""
        self.last_status: str | None = None
        if convention == "quadratic":
            self._qp: MPCSafetyFilter | None = MPCSafetyFilter(
                A, B, C, horizon=self.horizon, Q=weights[0], Q_terminal=weights[1],
                R=weights[2], input_bounds=input_bounds, position_bounds=position_bounds,
                n_obstacles=0, max_speed=max_speed,
            )
            return
        if position_bounds is not None or max_speed != np.inf:
            raise InvalidParameterError(
                "position_bounds must be None and max_speed inf with convention='authors_code' "
                "(the authors' planner has neither bound), got "
                f"position_bounds={position_bounds!r}, max_speed={max_speed!r}")
        self._qp = None
        self._build_least_squares(input_bounds)

    @classmethod
    def from_env(cls, env: Any, **kwargs: Any) -> MPCReferencePlanner:
        """Build the planner from a ``safe_nav_env`` environment (or any wrapper of one).

        The input bounds are the environment's; the arena and the speed limit
        (``env.unwrapped.max_speed``) bound the plan in the ``"quadratic"`` convention only.
        """
        base: FilterableEnv = env.unwrapped
        kwargs.setdefault("horizon", 10)
        if kwargs.get("convention", "quadratic") == "quadratic":
            kwargs.setdefault("position_bounds", base.position_bounds)
            kwargs.setdefault("max_speed", float(getattr(base, "max_speed", np.inf)))
        return cls(base.dynamics, input_bounds=base.input_bounds, **kwargs)

    def effective_weights(self) -> dict[str, np.ndarray]:
        """The cost's Hessian weights in the ``x' Q x`` convention, whatever ``convention``.

        Returns
        -------
        dict
            ``"Q"`` (n, n) on the states ``x_1 .. x_{T-1}``, ``"Q_terminal"`` (n, n) on
            ``x_T``, and ``"R"`` (T, m, m): the weight of each input ``u_0 .. u_{T-1}``
            (``R[0]`` is zero in the ``"authors_code"`` convention).
        """
        Q, Q_terminal, R = self.weights
        if self.convention == "quadratic":
            return {"Q": Q.copy(), "Q_terminal": Q_terminal.copy(),
                    "R": np.repeat(R[None], self.horizon, axis=0)}
        per_step = np.repeat((R @ R.T)[None], self.horizon, axis=0)
        per_step[0] = 0.0
        return {"Q": Q @ Q.T, "Q_terminal": Q_terminal @ Q_terminal.T, "R": per_step}

    def _build_least_squares(self, input_bounds: tuple[np.ndarray, np.ndarray]) -> None:
        r"""Condense the authors' cost into ``|| M u + c(x_0, x_g) ||²``.

        With ``x_t = A^t x_0 + \sum_{j<t} A^{t-1-j} B u_j``, the rows of step t are
        ``W_t' (x_t - x_g)`` (``W = Q`` for ``t < T``, ``Q_T`` at ``T``) and
        ``R' u_t`` for ``t = 1 .. T-1``. ``M`` is fixed; ``c`` is affine in
        ``(x_0, x_g)``, stored as the two matrices ``c = G x_0 - H x_g``.
        """
        from scipy.linalg import block_diag

        from filters.mpc.problem import MPCProblem

        A, B, C = self.dynamics
        Q, Q_terminal, R = self.weights
        (n, m), T = B.shape, self.horizon
        problem = MPCProblem(A, B, C, T, R=np.eye(m), objective="first_input",
                             input_bounds=input_bounds)  # checks the bounds too
        self._u_low, self._u_high = (np.tile(bound, T) for bound in problem.input_bounds)
        self._rollout = phi, gamma = problem.rollout
        W = block_diag(*[Q.T] * (T - 1), Q_terminal.T)  # W_t' on the rows of x_t
        zeros = np.zeros(((T - 1) * m, n))
        self._M = np.vstack([W @ gamma, np.kron(np.eye(T)[1:], R.T)])  # R' u_t, t = 1..T-1
        self._G = np.vstack([W @ phi, zeros])
        self._H = np.vstack([W @ np.tile(np.eye(n), (T, 1)), zeros])

    def _plan_least_squares(self, state: np.ndarray, target: np.ndarray) -> np.ndarray:
        c = self._G @ state - self._H @ target
        u, *_ = np.linalg.lstsq(self._M, -c, rcond=None)
        tolerance = 1e-9 * (1.0 + np.abs(self._u_high - self._u_low))
        if np.all(u >= self._u_low - tolerance) and np.all(u <= self._u_high + tolerance):
            self.last_status = "optimal"
            return np.clip(u, self._u_low, self._u_high)
        from scipy.optimize import lsq_linear

        solution = lsq_linear(self._M, -c, bounds=(self._u_low, self._u_high), method="bvls")
        self.last_status = "optimal" if solution.success else "inaccurate"
        return np.clip(solution.x, self._u_low, self._u_high)

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
        if self._qp is None:  # x_1..x_T = Phi x_0 + Gamma u
            (phi, gamma), u = self._rollout, self._plan_least_squares(state, target)
            return (np.vstack([state, (phi @ state + gamma @ u).reshape(self.horizon, -1)]),
                    u.reshape(self.horizon, -1))
        reference = np.tile(target, (self.horizon + 1, 1))
        reference[0] = state
        result = self._qp.solve(state, reference)
        self.last_status = str(result.status.value)
        return result.states, result.inputs

    def predict(self, observation: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:
        """First planned input for a ``safe_nav_env`` observation (or a batch of them).

        The observation's first six entries are the ego state and the goal offset.
        """
        observation = np.asarray(observation, dtype=float)
        batch = observation.reshape(-1, observation.shape[-1])
        actions = np.empty((batch.shape[0], self.dynamics[1].shape[1]), dtype=np.float32)
        for k, row in enumerate(batch):
            ego = row[OBSERVATION_EGO_STATE]
            actions[k] = self.plan(ego, ego[:2] + row[OBSERVATION_GOAL_OFFSET])[1][0]
        return (actions if observation.ndim > 1 else actions[0]), None

    def __call__(
        self, env: FilterableEnv, action: np.ndarray, horizon: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Reference maker for :class:`filters.SafetyFilterWrapper`: the whole plan."""
        if horizon != self.horizon:
            raise InvalidParameterError(
                f"the filter horizon {horizon} differs from the planner horizon {self.horizon}")
        return self.plan(env.ego_state, env.goal)


def _weight(name: str, value: float | np.ndarray, size: int) -> np.ndarray:
    """A scalar weight times the identity, or a finite ``(size, size)`` matrix."""
    weight = finite_array(name, value)
    return float(weight) * np.eye(size) if weight.ndim == 0 else finite_array(
        f"{name} (a scalar or a matrix)", weight, shape=(size, size))

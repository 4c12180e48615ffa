r"""Readable CVXPY formulation of the MPC safety filter (Problem 2), for tests and benchmarks.

This is the reference the fast :class:`filters.mpc.MPCSafetyFilter` is checked
against. It states the paper's Problem 2 (eq. (9), objective eq. (8)) exactly as
written there, with states and inputs as variables:

.. math::

    \min_{u, x} \quad & \sum_{t=0}^{T-1} (u_t - u^r_t)^\top R (u_t - u^r_t)
        + \sum_{t=1}^{T-1} (x_t - x^r_t)^\top Q (x_t - x^r_t)
        + (x_T - x^r_T)^\top Q_T (x_T - x^r_T)
        \ [+ \rho \textstyle\sum_{i,t} s_{i,t}] \\
    \text{s.t.} \quad & x_{t+1} = A x_t + B u_t, \quad
        u_\text{low} \le u_t \le u_\text{high}, \quad
        y_\text{low} \le C x_t \le y_\text{high}, \\
        & a_{i,t}^\top C x_t \le b_{i,t} \ [+ s_{i,t},\ s_{i,t} \ge 0].

The problem is built once with ``cvxpy.Parameter`` objects for :math:`x_0`, the
references, the normals and the offsets (DPP-compliant, so CVXPY caches the
canonicalisation and each solve only refills the parameters), and solved with
Clarabel through CVXPY. :class:`CVXPYSafetyFilter` shares the validation, the
fallback rule (``SHIFTED`` then ``BRAKE``) and the
:class:`~filters.mpc_result.FilterResult` of the fast filter (both derive from
:class:`filters.mpc_base.SafetyFilterBase`), so the two can be compared result
by result. Its ``solve_time`` is the wall time of ``problem.solve`` (CVXPY's parameter
substitution included), which is what a user of CVXPY pays per step.

CVXPY is imported by this module only; ``import filters.mpc`` does not import it.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import cvxpy as cp
import numpy as np

from filters.mpc_base import SOFT_GAP_TOLERANCE, SafetyFilterBase
from filters.mpc_result import _QPAttempt

__all__ = ["CVXPYSafetyFilter"]

_SOLVED = (cp.OPTIMAL, cp.OPTIMAL_INACCURATE)


def _square_root(matrix: np.ndarray) -> np.ndarray:
    """``L`` with ``L.T @ L = matrix`` for a symmetric PSD ``matrix``."""
    eigenvalues, vectors = np.linalg.eigh(matrix)
    return np.sqrt(np.clip(eigenvalues, 0.0, None))[:, None] * vectors.T


class CVXPYSafetyFilter(SafetyFilterBase):
    """Problem 2 in CVXPY, built once with parameters; same API as :class:`MPCSafetyFilter`.

    Parameters
    ----------
    A, B, C, horizon, Q, Q_terminal, R, input_bounds, position_bounds, n_obstacles, soft, \
slack_penalty, brake_gain
        As for :class:`filters.mpc.MPCSafetyFilter`.
    solver_settings
        Keyword arguments passed to ``problem.solve`` for Clarabel (e.g.
        ``{"tol_feas": 1e-9}``). Default: CVXPY's Clarabel defaults, with the duality
        gap tolerance tightened to ``SOFT_GAP_TOLERANCE`` in soft mode as in the fast
        filter.

    Raises
    ------
    InvalidArrayError, InvalidParameterError, InvalidTypeError
        As for :class:`filters.mpc.MPCSafetyFilter`.

    Notes
    -----
    Meant for tests and benchmarks, never for the control loop: a solve costs
    milliseconds of CVXPY overhead. An infeasible or failed solve returns the
    same fallbacks as the fast filter (``SHIFTED``, then ``BRAKE``), with
    ``solver_status`` set to CVXPY's status (e.g. ``"infeasible"``).
    """

    def __init__(
        self,
        A: np.ndarray,
        B: np.ndarray,
        C: np.ndarray,
        *,
        horizon: int = 10,
        Q: np.ndarray,
        Q_terminal: np.ndarray,
        R: np.ndarray,
        input_bounds: tuple[object, object] | None = None,
        position_bounds: tuple[object, object] | None = None,
        n_obstacles: int,
        soft: bool = False,
        slack_penalty: float = 1e6,
        brake_gain: np.ndarray | None = None,
        solver_settings: Mapping[str, Any] | None = None,
    ) -> None:
        super().__init__(
            A, B, C, horizon=horizon, Q=Q, Q_terminal=Q_terminal, R=R,
            input_bounds=input_bounds, position_bounds=position_bounds,
            n_obstacles=n_obstacles, soft=soft, slack_penalty=slack_penalty,
            brake_gain=brake_gain,
        )
        self._solver_kwargs: dict[str, Any] = {}
        if self._soft:  # same accuracy as the fast filter's soft mode
            self._solver_kwargs.update(
                tol_gap_abs=SOFT_GAP_TOLERANCE, tol_gap_rel=SOFT_GAP_TOLERANCE
            )
        self._solver_kwargs.update(solver_settings or {})
        self._build()

    def _build(self) -> None:
        T, n, m, d, K = self._T, self._n, self._m, self._d, self._n_obstacles
        A, B, C = self._A, self._B, self._C
        self._x0 = cp.Parameter(n, name="x0")
        self._x_ref = cp.Parameter((T, n), name="reference_states")  # x^r_1..x^r_T
        self._u_ref = cp.Parameter((T, m), name="reference_inputs")
        self._normals = [cp.Parameter((T, d), name=f"normals_{i}") for i in range(K)]
        self._offsets = cp.Parameter((K, T), name="offsets") if K else None

        u = cp.Variable((T, m), name="u")  # u_0..u_{T-1}
        x = cp.Variable((T, n), name="x")  # x_1..x_T
        self._u = u
        constraints = [x[0] == A @ self._x0 + B @ u[0]]
        if T > 1:
            constraints.append(x[1:].T == A @ x[:-1].T + B @ u[1:].T)

        finite = np.flatnonzero(np.isfinite(self._u_high))
        if finite.size:
            constraints.append(u[:, finite] <= np.tile(self._u_high[finite], (T, 1)))
        finite = np.flatnonzero(np.isfinite(self._u_low))
        if finite.size:
            constraints.append(u[:, finite] >= np.tile(self._u_low[finite], (T, 1)))

        y = x @ C.T  # positions y_1..y_T, (T, d)
        finite = np.flatnonzero(np.isfinite(self._y_high))
        if finite.size:
            constraints.append(y[:, finite] <= np.tile(self._y_high[finite], (T, 1)))
        finite = np.flatnonzero(np.isfinite(self._y_low))
        if finite.size:
            constraints.append(y[:, finite] >= np.tile(self._y_low[finite], (T, 1)))

        self._slack = cp.Variable((K, T), nonneg=True, name="slack") if (self._soft and K) else None
        for i in range(K):
            lhs = cp.sum(cp.multiply(self._normals[i], y), axis=1)  # a_it . y_t, (T,)
            rhs = self._offsets[i]
            if self._slack is not None:
                rhs = rhs + self._slack[i]
            constraints.append(lhs <= rhs)

        cost = cp.sum_squares((u - self._u_ref) @ _square_root(self._R).T)
        if T > 1:
            cost += cp.sum_squares((x[:-1] - self._x_ref[:-1]) @ _square_root(self._Q).T)
        cost += cp.sum_squares(_square_root(self._Q_terminal) @ (x[-1] - self._x_ref[-1]))
        if self._slack is not None:
            cost += self._slack_penalty * cp.sum(self._slack)
        self._problem = cp.Problem(cp.Minimize(cost), constraints)
        if not self._problem.is_dpp():  # pragma: no cover - formulation bug
            raise RuntimeError("the CVXPY safety filter must be DPP")

    def _solve_qp(
        self, x0: np.ndarray, ref_states: np.ndarray, ref_inputs: np.ndarray,
        normals: np.ndarray, offsets: np.ndarray,
    ) -> _QPAttempt:
        self._x0.value = x0
        self._x_ref.value = ref_states
        self._u_ref.value = ref_inputs
        for i, parameter in enumerate(self._normals):
            parameter.value = normals[i]
        if self._offsets is not None:
            self._offsets.value = offsets
        begin = time.perf_counter()
        try:
            self._problem.solve(solver=cp.CLARABEL, **self._solver_kwargs)
        except (cp.error.SolverError, ValueError, ArithmeticError) as exc:
            return _QPAttempt(
                None, None, f"exception: {exc!r}", 0, time.perf_counter() - begin, False
            )
        solve_time = time.perf_counter() - begin
        status = str(self._problem.status)
        stats = self._problem.solver_stats
        iterations = int(stats.num_iters) if stats and stats.num_iters is not None else 0
        solved = status in _SOLVED and self._u.value is not None
        inputs = np.array(self._u.value) if solved else None
        slack = None
        if self._soft and solved:
            slack = (
                np.array(self._slack.value)
                if self._slack is not None
                else np.zeros((0, self._T))
            )
        objective = float(self._problem.value) if solved else float("nan")
        return _QPAttempt(inputs, slack, status, iterations, solve_time, solved, objective)

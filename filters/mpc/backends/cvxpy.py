r"""CVXPY back end: the same QP as :mod:`filters.mpc.backends.clarabel`, written as read.

The reference the fast back end is tested against: states and inputs as variables,
the cost and the rows of :class:`~filters.mpc.MPCProblem` spelled out, built once with
``cvxpy.Parameter`` objects (DPP, so CVXPY caches the canonicalisation and each solve
only refills the parameters), solved with Clarabel through CVXPY. Never in the control
loop: a solve costs milliseconds of CVXPY overhead.

This module imports CVXPY; ``import filters`` does not import it. The filter that uses it,
:class:`filters.CVXPYSafetyFilter`, is in :mod:`filters.mpc.cvxpy_filter`.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import cvxpy as cp
import numpy as np

from filters.mpc.backends.clarabel import SOFT_GAP_TOLERANCE
from filters.mpc.problem import MPCProblem
from filters.mpc.result import QPSolution, StepData

__all__ = ["CVXPYBackend"]

_SOLVED = (cp.OPTIMAL, cp.OPTIMAL_INACCURATE)


def _square_root(matrix: np.ndarray) -> np.ndarray:
    """``L`` with ``L.T @ L = matrix`` for a symmetric PSD ``matrix``."""
    eigenvalues, vectors = np.linalg.eigh(matrix)
    return np.sqrt(np.clip(eigenvalues, 0.0, None))[:, None] * vectors.T


class CVXPYBackend:
    """The QP of one :class:`~filters.mpc.MPCProblem` in CVXPY with Parameters.

    Parameters
    ----------
    problem
        What to build.
    solver_settings
        Keyword arguments for ``problem.solve`` (Clarabel's settings, e.g.
        ``{"tol_feas": 1e-9}``). Soft QPs get the gap tolerances of the fast back end.
    """

    name = "cvxpy"

    def __init__(self, problem: MPCProblem, *,
                 solver_settings: Mapping[str, Any] | None = None) -> None:
        self.problem = p = problem
        self._kwargs: dict[str, Any] = dict(tol_gap_abs=SOFT_GAP_TOLERANCE,
                                            tol_gap_rel=SOFT_GAP_TOLERANCE) if p.soft_rows else {}
        self._kwargs.update(solver_settings or {})
        T, n, m, d, K = p.horizon, p.n, p.m, p.d, p.n_obstacles
        A, B, C = p.A, p.B, p.C
        self._x0 = cp.Parameter(n, name="x0")
        self._x_ref = cp.Parameter((T, n), name="reference_states")  # x^r_1..x^r_T
        self._u_ref = cp.Parameter((T, m), name="reference_inputs")
        self._normals = [cp.Parameter((T, d), name=f"normals_{i}") for i in range(K)]
        self._offsets = cp.Parameter((K, T), name="offsets") if K else None

        self._u = u = cp.Variable((T, m), name="u")  # u_0..u_{T-1}
        x = cp.Variable((T, n), name="x")  # x_1..x_T
        constraints = [x[0] == A @ self._x0 + B @ u[0]]
        if T > 1:
            constraints.append(x[1:].T == A @ x[:-1].T + B @ u[1:].T)

        self._bound_slack = bound_slack = []  # slacks of the arena and terminal rows

        def bounded(lhs: cp.Expression, rhs: Any, soft: bool) -> cp.Constraint:
            if not soft:
                return lhs <= rhs
            bound_slack.append(cp.Variable(lhs.shape, nonneg=True))
            return lhs <= rhs + bound_slack[-1]

        y = x @ C.T  # positions y_1..y_T, (T, d)
        for values, (low, high), soft in ((u, p.input_bounds, False),  # the input box: hard
                                          (y, p.position_bounds, p.soft_bounds)):
            for bound, sign in ((high, 1.0), (low, -1.0)):
                finite = np.flatnonzero(np.isfinite(bound))
                if finite.size:
                    constraints.append(bounded(sign * values[:, finite],
                                               sign * np.tile(bound[finite], (T, 1)), soft))
        G, g = p.terminal_rows
        if G.shape[0]:
            constraints.append(bounded(G @ x[-1], g, p.soft_bounds))
        S, s = p.speed_rows  # the speed polygon on v_1..v_T, always hard
        if S.shape[0]:
            constraints.append(x @ S.T <= np.tile(s, (T, 1)))

        self._hs_slack = slack = (
            cp.Variable((K, T), nonneg=True, name="slack") if (p.soft_halfspaces and K) else None)
        for i in range(K):  # a_it . y_t <= b_it (+ s_it), (T,)
            constraints.append(cp.sum(cp.multiply(self._normals[i], y), axis=1)
                               <= self._offsets[i] + (0.0 if slack is None else slack[i]))
        cost = 0
        for t in range(T):
            cost += cp.sum_squares(_square_root(p.input_weights[t]) @ (u[t] - self._u_ref[t]))
            if p.has_state_cost:
                cost += cp.sum_squares(_square_root(p.state_weights[t]) @ (x[t] - self._x_ref[t]))
        for penalised in bound_slack + ([slack] if slack is not None else []):
            cost += p.slack_penalty * cp.sum(penalised)
        self._problem = cp.Problem(cp.Minimize(cost), constraints)
        if not self._problem.is_dpp():  # pragma: no cover - formulation bug
            raise RuntimeError("the CVXPY safety-filter QP must be DPP")

    def solve(self, step: StepData) -> QPSolution:
        """Fill the parameters and solve; never raises on a failed solve."""
        p = self.problem
        self._x0.value = step.x0
        self._x_ref.value = step.ref_states
        self._u_ref.value = step.ref_inputs
        for i, parameter in enumerate(self._normals):
            parameter.value = step.normals[i]
        if self._offsets is not None:
            self._offsets.value = step.offsets
        begin = time.perf_counter()
        try:
            self._problem.solve(solver=cp.CLARABEL, **self._kwargs)
        except (cp.error.SolverError, ValueError, ArithmeticError) as exc:
            return QPSolution(False, f"exception: {exc!r}", solve_time=time.perf_counter() - begin)
        solve_time = time.perf_counter() - begin
        status = str(self._problem.status)
        stats = self._problem.solver_stats
        iterations = int(stats.num_iters) if stats and stats.num_iters is not None else 0
        if status not in _SOLVED or self._u.value is None:
            return QPSolution(False, status, iterations=iterations, solve_time=solve_time)
        hs_slack = bound_slack = None
        if p.soft_halfspaces:
            hs_slack = np.zeros((0, p.horizon)) if self._hs_slack is None else np.array(
                self._hs_slack.value)
        if p.soft_bounds:
            bound_slack = np.concatenate([np.zeros(0)]
                                         + [np.ravel(s.value) for s in self._bound_slack])
        return QPSolution(True, status, np.array(self._u.value), hs_slack, bound_slack, iterations,
                          solve_time)

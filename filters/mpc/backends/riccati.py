r"""Riccati back end: the soft QP by a structured interior-point method (compiled).

The recovery QP (every halfspace, arena and terminal row soft, the exact L1 penalty;
the input box hard) is always feasible, and at long horizons it is the filter's
costliest QP: a strongly infeasible step violates hundreds of rows, which an
active-set method adds one by one. A general sparse interior-point solver (PIQP,
Clarabel) takes about twenty iterations, but each factorises the whole KKT system with
a slack variable per row. This back end keeps the stage structure instead
(:mod:`filters.mpc._riccati_kernels`): the iterates satisfy the dynamics by roll-out,
every row's slack, dual and complementarity are eliminated row by row into a rank-one
weight on its step's state, and the Newton step is an LQ problem solved by a Riccati
recursion over the ``T`` steps. Its work per iteration is linear in the horizon and in
the rows, with no symbolic factorisation and no sparse data structures: on the scaling
grid's recovery QPs it is several times faster than PIQP on the same QP (``safe-nav
bench --scaling``).

Only QPs whose every row is soft (``soft_rows == {"halfspaces", "bounds"}``, or a
problem without the rows that are hard) are accepted: a QP with hard rows can be
infeasible, and this method has no infeasibility certificate.

The same QP as the other back ends, in the same units; the answer agrees with theirs
to the solvers' tolerances (tests against the CVXPY reference at T = 10 to 80).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from filters.errors import InvalidParameterError, InvalidTypeError
from filters.mpc.problem import MPCProblem
from filters.mpc.result import QPSolution, StepData

__all__ = ["MAX_ITERATIONS", "TOLERANCE", "RiccatiBackend", "every_row_soft"]

#: Relative accuracy of the residuals and of the duality gap (Clarabel's soft QPs use a
#: gap tolerance of 1e-10 too).
TOLERANCE = 1e-10
#: Iterations before the solve reports ``"MaxIterations"``; the scaling grid's recovery
#: QPs took 14-24 (median per point), at most 41.
MAX_ITERATIONS = 100


def every_row_soft(problem: MPCProblem) -> bool:
    """Whether every halfspace, arena and terminal row of ``problem`` carries a slack."""
    has_bound_rows = (bool(np.isfinite(problem.position_bounds[0]).any())
                      or bool(np.isfinite(problem.position_bounds[1]).any())
                      or problem.terminal_set is not None)
    return (problem.soft_halfspaces or not problem.n_obstacles) and (
        problem.soft_bounds or not has_bound_rows)


class RiccatiBackend:
    """The filter's all-soft QP, solved by the compiled Riccati interior-point method.

    Parameters
    ----------
    problem
        The problem; every row it has must be soft.
    solver_settings
        ``{"tolerance": float > 0, "max_iterations": int >= 1}`` to override
        :data:`TOLERANCE` and :data:`MAX_ITERATIONS`.

    Raises
    ------
    InvalidParameterError
        If the problem has hard halfspace, arena or terminal rows, or on a bad setting.
    InvalidTypeError
        If ``solver_settings`` is not a mapping.
    """

    name = "riccati"

    def __init__(
        self, problem: MPCProblem, *, solver_settings: Mapping[str, Any] | None = None
    ) -> None:
        from filters.mpc import _riccati_kernels  # numba: imported on first use

        self._kernels = _riccati_kernels
        k = _riccati_kernels
        self._status = {k.SOLVED: "Solved", k.ALMOST_SOLVED: "AlmostSolved",
                        k.MAX_ITERATIONS: "MaxIterations", k.NUMERICAL: "NumericalError"}
        self._answered = (k.SOLVED, k.ALMOST_SOLVED)
        if not every_row_soft(problem):
            raise InvalidParameterError(
                "the riccati back end solves QPs whose every row is soft (soft_rows "
                f"{{'halfspaces', 'bounds'}}), got soft_rows {sorted(problem.soft_rows)}")
        self.problem = problem
        self.tolerance, self.max_iterations = _settings(solver_settings)
        self._build()

    def _build(self) -> None:
        p = self.problem
        T, n, K = p.horizon, p.n, p.n_obstacles
        C = p.C
        y_low, y_high = p.position_bounds
        # The arena and terminal rows, in the other back ends' order: upper faces by step
        # and axis, lower faces, terminal rows.
        normals, steps, offsets = [], [], []
        for bound, sign in ((y_high, 1.0), (y_low, -1.0)):
            finite = np.flatnonzero(np.isfinite(bound))
            for t in range(1, T + 1):
                normals.append(sign * C[finite])
                steps.append(np.full(len(finite), t))
                offsets.append(sign * bound[finite])
        if p.terminal_set is not None:
            G, g = p.terminal_set
            normals.append(G)
            steps.append(np.full(len(g), T))
            offsets.append(g)
        bound_a = np.vstack(normals) if normals else np.zeros((0, n))
        self._n_bounds = len(bound_a)
        rows = K * T + self._n_bounds
        self._a = np.zeros((rows, n))
        self._a[K * T:] = bound_a
        self._step = np.empty(rows, dtype=np.int64)
        self._step[:K * T] = np.tile(np.arange(1, T + 1), K)
        self._step[K * T:] = np.concatenate(steps) if steps else np.zeros(0, dtype=np.int64)
        self._b = np.zeros(rows)
        self._b[K * T:] = np.concatenate(offsets) if offsets else np.zeros(0)
        self._A, self._B = np.ascontiguousarray(p.A), np.ascontiguousarray(p.B)
        self._R2 = np.ascontiguousarray(2.0 * p.input_weights)
        self._Q2 = np.ascontiguousarray(2.0 * p.state_weights)
        self._low, self._high = (np.ascontiguousarray(v, dtype=float) for v in p.input_bounds)
        # Tuples whose lengths are n and m: numba compiles (and caches) the kernel for
        # these sizes, so its small matrix loops have constant trip counts.
        self._n_token, self._m_token = (0,) * n, (0,) * p.m
        self._inputs = np.empty((T, p.m))
        self._slacks = np.empty(rows)

    def reset(self) -> None:
        """A new episode (nothing is carried from step to step)."""

    def solve(self, step: StepData) -> QPSolution:
        """Write the step's rows and solve; never raises on a failed solve."""
        p = self.problem
        T, K = p.horizon, p.n_obstacles
        begin = time.perf_counter()
        try:
            if K:
                self._a[:K * T] = (step.normals.reshape(K * T, p.d) @ p.C)
                self._b[:K * T] = step.offsets.reshape(-1)
            code, iterations = self._kernels.solve_soft_qp(
                self._A, self._B, self._R2, self._Q2, np.ascontiguousarray(step.x0, float),
                np.ascontiguousarray(step.ref_inputs, float),
                np.ascontiguousarray(step.ref_states, float), self._low, self._high,
                self._a, self._step, self._b, p.slack_penalty, self.tolerance,
                self.max_iterations, self._inputs, self._slacks, self._n_token, self._m_token)
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as exc:  # a numba or shape error: a status, not a crash
            return QPSolution(False, f"exception: {exc!r}")
        solve_time = time.perf_counter() - begin
        status = self._status[int(code)]
        if code not in self._answered or not np.isfinite(self._inputs).all():
            if code in self._answered:  # the kernel's checks should make this unreachable
                status = "NumericalError"
            return QPSolution(False, status, iterations=int(iterations), solve_time=solve_time)
        hs_slack = self._slacks[:K * T].reshape(K, T).copy() if p.soft_halfspaces else None
        bound_slack = self._slacks[K * T:].copy() if p.soft_bounds else None
        return QPSolution(True, status, self._inputs.copy(), hs_slack, bound_slack,
                          int(iterations), solve_time)


def _settings(overrides: Mapping[str, Any] | None) -> tuple[float, int]:
    """``(tolerance, max_iterations)`` from the defaults and ``overrides``."""
    if overrides is None:
        return TOLERANCE, MAX_ITERATIONS
    if not isinstance(overrides, Mapping):
        raise InvalidTypeError(f"solver_settings must be a mapping, got {overrides!r}")
    unknown = set(overrides) - {"tolerance", "max_iterations"}
    if unknown:
        raise InvalidParameterError(
            f"unknown riccati setting(s) {sorted(unknown)}; known: max_iterations, tolerance")
    tolerance = overrides.get("tolerance", TOLERANCE)
    iterations = overrides.get("max_iterations", MAX_ITERATIONS)
    if isinstance(tolerance, bool) or not isinstance(tolerance, (int, float, np.floating)) or not (
            0.0 < float(tolerance) < 1.0):
        raise InvalidParameterError(f"tolerance must be a number in (0, 1), got {tolerance!r}")
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or (
            iterations < 1):
        raise InvalidParameterError(
            f"max_iterations must be an integer >= 1, got {iterations!r}")
    return float(tolerance), int(iterations)

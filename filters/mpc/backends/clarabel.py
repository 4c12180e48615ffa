r"""Clarabel back end: the sparse multiple-shooting QP of an :class:`~filters.mpc.MPCProblem`.

Built once, updated per step (qpmpc's "build once, update per step"):

* **Variables** (deviation coordinates) :math:`w_t = u_t - u^r_t`, :math:`e_t = x_t -
  x^r_t` and the slacks of the soft rows, :math:`z = (w_0..w_{T-1}, e_1..e_T, s_h, s_b)`;
  the dynamics are equality rows. The cost is :math:`\sum w^\top R_t w + \sum e^\top Q_t
  e + \rho \sum s` with no quadratic-linear cross term, so ``P`` and ``q`` never
  change and the solver's relative gap tolerance applies to the cost itself (in
  :math:`(u, x)` it would see the cost minus the often 100x larger constant
  :math:`\sum x^{r\top} Q x^r`).
* **Rows**, in Clarabel's form :math:`A z + s = b`: dynamics (zero cone), then the input
  box, the arena, the terminal rows, the speed polygon, the halfspaces, and
  :math:`-s \le 0` (nonnegative cone). Per step only ``b`` and the halfspace entries
  :math:`a_{i,t}^\top C` of ``A`` change, written with ``DefaultSolver.update`` (partial
  ``A`` update), so the KKT pattern and its symbolic factorisation are reused. This
  needs presolve off and the structural zeros kept. Every solve, the first included,
  writes its data by ``update``: a used solver returns what a fresh one returns.
* **Settings** (measured on recorded crossing instances against a 1e-12 solve): no
  equilibration for hard QPs (it would be computed once from placeholder data; off is
  faster and as accurate), on for soft ones (the exact penalty needs it), with the gap
  tolerances tightened to ``SOFT_GAP_TOLERANCE`` (the penalty dominates the objective);
  no iterative refinement; ``max_step_fraction`` 0.995. Override with ``solver_settings``.
* Clarabel is an interior-point method without warm start.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import clarabel
import numpy as np
import scipy.sparse as sp

from filters.errors import InvalidParameterError, InvalidTypeError
from filters.mpc._linalg import matvec_operator
from filters.mpc.condensed import vecdot
from filters.mpc.problem import MPCProblem
from filters.mpc.result import QPSolution, StepData

__all__ = ["SOFT_GAP_TOLERANCE", "ClarabelBackend", "clarabel_settings"]

#: Duality-gap tolerance (absolute and relative) of QPs with soft rows: the penalty term
#: dominates the objective, so the default 1e-8 would resolve the inputs only to ~5e-2.
SOFT_GAP_TOLERANCE = 1e-10

_SOLVED = ("Solved", "AlmostSolved")


def clarabel_settings(overrides: Mapping[str, Any] | None, *, soft: bool
                      ) -> clarabel.DefaultSettings:
    """Clarabel settings of the filter's QPs, with the user's ``overrides`` applied.

    Raises
    ------
    InvalidTypeError
        If ``overrides`` is not a mapping.
    InvalidParameterError
        On an unknown setting, an invalid value, or presolve / zero dropping turned on
        (they forbid the per-step data updates).
    """
    settings = clarabel.DefaultSettings()
    if overrides is not None and not isinstance(overrides, Mapping):
        raise InvalidTypeError(
            f"solver_settings must be a mapping of Clarabel settings, got {overrides!r}")
    # presolve off and structural zeros kept: required for the data updates
    ours = dict(verbose=False, presolve_enable=False, chordal_decomposition_enable=False,
                input_sparse_dropzeros=False, iterative_refinement_enable=False,
                equilibrate_enable=soft, max_step_fraction=0.995, direct_solve_method="qdldl",
                max_threads=1)
    if soft:
        ours.update(tol_gap_abs=SOFT_GAP_TOLERANCE, tol_gap_rel=SOFT_GAP_TOLERANCE)
    for key, value in {**ours, **(overrides or {})}.items():  # the user's override ours
        if not hasattr(settings, key):
            raise InvalidParameterError(f"solver_settings: unknown Clarabel setting {key!r}")
        if key in ("presolve_enable", "input_sparse_dropzeros") and value:
            raise InvalidParameterError(f"solver_settings: {key}=True is not supported, it "
                                        "forbids the per-step data updates the filter relies on")
        try:
            setattr(settings, key, value)
        except (TypeError, ValueError) as exc:
            raise InvalidParameterError(
                f"solver_settings: invalid value {value!r} for {key!r}") from exc
    return settings


def _csc_with_positions(rows: list[np.ndarray], cols: list[np.ndarray], vals: list[np.ndarray],
                        shape: tuple[int, int]) -> tuple[sp.csc_matrix, np.ndarray]:
    """CSC matrix of the entries (structural zeros kept), and where each entry landed."""
    rows_all, cols_all = (np.concatenate(part).astype(np.int64) for part in (rows, cols))
    ids = np.arange(1, len(rows_all) + 1, dtype=np.float64)  # never zero: nothing dropped
    pattern = sp.csc_matrix((ids, (rows_all, cols_all)), shape=shape)
    pattern.sort_indices()
    if pattern.nnz != len(rows_all):  # pragma: no cover - construction bug
        raise RuntimeError("duplicate entries in the constraint pattern")
    entry = pattern.data.astype(np.int64) - 1  # CSC position -> entry index
    values = np.concatenate(vals).astype(np.float64)[entry]
    matrix = sp.csc_matrix((values, pattern.indices.copy(), pattern.indptr.copy()), shape=shape)
    position = np.empty(len(entry), dtype=np.int64)
    position[entry] = np.arange(len(entry))
    return matrix, position


class ClarabelBackend:
    """The QP of one :class:`~filters.mpc.MPCProblem`, as a Clarabel solver built once.

    Parameters
    ----------
    problem
        What to build (its ``soft_rows`` say which rows carry slacks).
    solver_settings
        Clarabel settings to override (see :func:`clarabel_settings`).
    """

    name = "clarabel"

    def __init__(self, problem: MPCProblem, *,
                 solver_settings: Mapping[str, Any] | None = None) -> None:
        self.problem = p = problem
        self._settings = clarabel_settings(solver_settings, soft=bool(problem.soft_rows))
        T, n, m, d, K = p.horizon, p.n, p.m, p.d, p.n_obstacles
        A, B, C = p.A, p.B, p.C
        nu, nx = T * m, T * n
        u_low, u_high = p.input_bounds
        y_low, y_high = p.position_bounds
        G, g = p.terminal_rows
        # The rows before the halfspaces, M_w w + M_e e (= or <=) c + H0 x0 in the deviations
        # w, e: the dynamics (the equalities), the input box, the arena and terminal rows
        # ("bounds": soft in recovery), the speed polygon. With u = w + u^r and x = e + x^r,
        # their right-hand side is W v, v = [x0; u^r; x^r; 1], W = [H0, -M_w, -M_e, c].
        def stages(block: np.ndarray, k: int = 0) -> sp.csr_matrix:
            """``block`` on block diagonal ``k`` over the T stages (rows t, columns t + k)."""
            return sp.kron(sp.eye(T, k=k), block, format="csr")

        def box(matrix: np.ndarray, low: np.ndarray, high: np.ndarray) -> list[tuple]:
            """``low <= matrix z_t <= high`` at every stage, the finite sides only."""
            return [(sign * stages(matrix[finite]), np.tile(sign * bound[finite], T))
                    for bound, sign in ((high, 1.0), (low, -1.0))
                    for finite in [np.flatnonzero(np.isfinite(bound))]]

        S, s = p.speed_rows  # the speed polygon, always hard
        terminal = sp.hstack([sp.csr_matrix((G.shape[0], nx - n)), G])  # G x_T <= g
        bounds = [*box(C, y_low, y_high), (terminal, g)]
        parts = [([-stages(B), stages(np.eye(n)) - stages(A, -1)], np.zeros(nx))]  # dynamics
        parts += [([block, None], c) for block, c in box(np.eye(m), u_low, u_high)]
        start = sum(len(c) for _, c in parts)  # the bounds' rows come next
        bound_rows = list(range(start, start + sum(len(c) for _, c in bounds)))
        parts += [([None, block], c) for block, c in [*bounds, (stages(S), np.tile(s, T))]]
        M = sp.bmat([blocks for blocks, _ in parts], format="coo")
        M.eliminate_zeros()
        row, n_equalities = M.shape[0], nx
        const = np.concatenate([c for _, c in parts])
        W = np.hstack([np.zeros((row, n)), -M.toarray(), const[:, None]])
        W[:n, :n] = A  # A x0 on the right-hand side of the first dynamics rows
        rows, cols, vals = [M.row], [M.col], [M.data]  # the entries of the constraint matrix
        hs_row0, hs_first = row, M.nnz

        # Halfspaces, row hs_row0 + i T + (t - 1): (a_it' C) x_t <= b_it. The pattern covers
        # every column C touches; the placeholder e'|C| (e a unit vector) keeps the rows
        # unit-scale for equilibration; every solve writes the real values.
        touched = np.flatnonzero(np.any(C != 0.0, axis=0))
        placeholder = (np.full(d, 1.0 / np.sqrt(d)) @ np.abs(C))[touched]
        hs_rows = np.arange(K * T)[:, None]  # i T + (t - 1)
        rows.append(np.repeat(row + hs_rows[:, 0], len(touched)))
        cols.append((nu + hs_rows % T * n + touched).reshape(-1))
        vals.append(np.tile(placeholder, K * T))
        hs_index = (hs_rows * n + touched).reshape(-1)  # entries of (a_it' C)[touched], row by row
        row += K * T

        # Slacks: -s on each soft row, and -s <= 0.
        soft_rows = list(range(hs_row0, hs_row0 + K * T)) if p.soft_halfspaces else []
        n_hs_slack = len(soft_rows)
        soft_rows += bound_rows if p.soft_bounds else []
        ns, slack0 = len(soft_rows), nu + nx
        slack_cols = slack0 + np.arange(ns)
        rows += [np.array(soft_rows, dtype=np.int64), row + np.arange(ns)]
        cols += [slack_cols, slack_cols]
        vals += [-np.ones(ns), -np.ones(ns)]
        row += ns
        nv = nu + nx + ns
        constraint, position = _csc_with_positions(rows, cols, vals, (row, nv))
        cones = [clarabel.ZeroConeT(n_equalities)]
        if row > n_equalities:
            cones.append(clarabel.NonnegativeConeT(row - n_equalities))
        blocks = [2.0 * Rt for Rt in p.input_weights] + [2.0 * Qt for Qt in p.state_weights]
        P = sp.triu(sp.block_diag(blocks + ([sp.csc_matrix((ns, ns))] if ns else []),
                                  format="csc"), format="csc")
        P.sort_indices()
        q = np.zeros(nv)
        q[slack0:] = p.slack_penalty
        positions_map = np.zeros((T * d, W.shape[1]))  # reference positions C x^r_t, same v
        positions_map[:, n + nu : n + nu + nx] = np.kron(np.eye(T), C)
        self._W_full = matvec_operator(np.vstack([W, positions_map]))
        self._hs_row0, self._n_hs_slack, self._slack_b = hs_row0, n_hs_slack, [0.0] * ns
        self._hs_positions = position[hs_first : hs_first + hs_index.size].tolist()
        self._hs_index = hs_index
        self._nu, self._nx, self._nv = nu, nx, nv
        b0 = np.concatenate([W[:, -1], np.ones(K * T), np.zeros(ns)])
        self.solver = clarabel.DefaultSolver(P, q, constraint, b0, cones, self._settings)
        if not self.solver.is_data_update_allowed():  # pragma: no cover - settings checked
            raise InvalidParameterError(
                "solver_settings disable Clarabel's data updates; keep presolve off")

    def solve(self, step: StepData) -> QPSolution:
        """Write the step's data into the solver and solve; never raises on a failed solve."""
        p = self.problem
        T, m, d = p.horizon, p.m, p.d
        fixed = self._W_full @ np.concatenate(
            (step.x0, step.ref_inputs.reshape(-1), step.ref_states.reshape(-1), (1.0,)))
        hs0, normals = self._hs_row0, step.normals
        b = fixed[:hs0].tolist()
        if normals.shape[0]:
            b += (step.offsets - vecdot(normals, fixed[hs0:].reshape(T, d))).reshape(-1).tolist()
            a_values = (normals.reshape(-1, d) @ p.C).reshape(-1)[self._hs_index].tolist()
        b += self._slack_b
        try:
            self.solver.update(b=b, **({"A": (self._hs_positions, a_values)}
                                       if normals.shape[0] else {}))
            begin = time.perf_counter()
            solution = self.solver.solve()
            solve_time = time.perf_counter() - begin
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as exc:  # pyo3 panics derive from BaseException
            return QPSolution(False, f"exception: {exc!r}")
        status, iterations, z = str(solution.status), int(solution.iterations), solution.x
        if status not in _SOLVED or len(z) != self._nv:
            return QPSolution(False, status, iterations=iterations, solve_time=solve_time)
        nu, nx = self._nu, self._nx
        inputs = np.array(z[:nu]).reshape(T, m) + step.ref_inputs
        hs_slack = bound_slack = None
        if self._slack_b:
            slacks = np.array(z[nu + nx :])
            if p.soft_halfspaces:
                hs_slack = slacks[: self._n_hs_slack].reshape(p.n_obstacles, T)
            if p.soft_bounds:
                bound_slack = slacks[self._n_hs_slack :]
        return QPSolution(True, status, inputs, hs_slack, bound_slack, iterations, solve_time)

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
from filters.mpc.problem import MPCProblem
from filters.mpc.result import QPSolution, StepData

__all__ = ["SOFT_GAP_TOLERANCE", "ClarabelBackend", "clarabel_settings"]

#: Duality-gap tolerance (absolute and relative) of QPs with soft rows: the penalty term
#: dominates the objective, so the default 1e-8 would resolve the inputs only to ~5e-2.
SOFT_GAP_TOLERANCE = 1e-10

_SOLVED = ("Solved", "AlmostSolved")

#: dot products over the last axis, broadcast (np.vecdot on NumPy >= 2).
_vecdot = getattr(np, "vecdot", None) or (lambda a, b: np.einsum("...d,...d->...", a, b))


def clarabel_settings(
    overrides: Mapping[str, Any] | None, *, soft: bool
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
    settings.verbose = False
    settings.presolve_enable = False  # required for data updates
    settings.chordal_decomposition_enable = False
    settings.input_sparse_dropzeros = False  # keep the structural zeros
    settings.iterative_refinement_enable = False
    settings.equilibrate_enable = soft
    if soft:
        settings.tol_gap_abs = settings.tol_gap_rel = SOFT_GAP_TOLERANCE
    settings.max_step_fraction = 0.995
    settings.direct_solve_method = "qdldl"
    settings.max_threads = 1
    if overrides is None:
        return settings
    if not isinstance(overrides, Mapping):
        raise InvalidTypeError(
            f"solver_settings must be a mapping of Clarabel settings, got {overrides!r}"
        )
    for key, value in overrides.items():
        if not hasattr(settings, key):
            raise InvalidParameterError(f"solver_settings: unknown Clarabel setting {key!r}")
        if key in ("presolve_enable", "input_sparse_dropzeros") and value:
            raise InvalidParameterError(
                f"solver_settings: {key}=True is not supported, it forbids the "
                "per-step data updates the filter relies on"
            )
        try:
            setattr(settings, key, value)
        except (TypeError, ValueError) as exc:
            raise InvalidParameterError(
                f"solver_settings: invalid value {value!r} for {key!r}"
            ) from exc
    return settings


def _csc_with_positions(
    rows: list[np.ndarray], cols: list[np.ndarray], vals: list[np.ndarray],
    shape: tuple[int, int],
) -> tuple[sp.csc_matrix, np.ndarray]:
    """CSC matrix of the entries (structural zeros kept), and where each entry landed."""
    rows_all = np.concatenate(rows).astype(np.int64)
    cols_all = np.concatenate(cols).astype(np.int64)
    vals_all = np.concatenate(vals).astype(np.float64)
    ids = np.arange(1, len(rows_all) + 1, dtype=np.float64)  # never zero: nothing dropped
    pattern = sp.csc_matrix((ids, (rows_all, cols_all)), shape=shape)
    pattern.sort_indices()
    if pattern.nnz != len(rows_all):  # pragma: no cover - construction bug
        raise RuntimeError("duplicate entries in the constraint pattern")
    entry = pattern.data.astype(np.int64) - 1  # CSC position -> entry index
    matrix = sp.csc_matrix(
        (vals_all[entry], pattern.indices.copy(), pattern.indptr.copy()), shape=shape
    )
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

    def __init__(
        self, problem: MPCProblem, *, solver_settings: Mapping[str, Any] | None = None
    ) -> None:
        self.problem = problem
        self._settings = clarabel_settings(solver_settings, soft=bool(problem.soft_rows))
        self._build()

    def _build(self) -> None:
        p = self.problem
        T, n, m, d, K = p.horizon, p.n, p.m, p.d, p.n_obstacles
        A, B, C = p.A, p.B, p.C
        nu, nx = T * m, T * n
        u_low, u_high = p.input_bounds
        y_low, y_high = p.position_bounds
        G, g = p.terminal_set if p.terminal_set is not None else (np.zeros((0, n)), np.zeros(0))
        rows: list[np.ndarray] = []
        cols: list[np.ndarray] = []
        vals: list[np.ndarray] = []
        # W maps v = [x0; u^r; x^r; 1] to the right-hand side of the rows before the
        # halfspaces: b = b_const + H0 x0 - G_u u^r - G_x x^r (deviation coordinates).
        W_rows: list[np.ndarray] = []
        width = n + nu + nx + 1
        row = 0

        def x_col(t: int) -> int:  # column of x_t (e_t), t = 1..T
            return nu + (t - 1) * n

        def add(r0: int, c0: int, block: np.ndarray) -> None:
            r, c = np.nonzero(block)
            rows.append(r + r0)
            cols.append(c + c0)
            vals.append(block[r, c])

        def rhs(coef_u: dict[int, np.ndarray], coef_x: dict[int, np.ndarray],
                const: np.ndarray, x0_coef: np.ndarray | None = None) -> None:
            """Right-hand side rows: const + x0_coef x0 - sum G_u u^r_t - sum G_x x^r_t."""
            block = np.zeros((len(const), width))
            block[:, -1] = const
            if x0_coef is not None:
                block[:, :n] = x0_coef
            for t, coef in coef_u.items():
                block[:, n + t * m : n + (t + 1) * m] -= coef
            for t, coef in coef_x.items():  # x_t, t = 1..T
                block[:, n + nu + (t - 1) * n : n + nu + t * n] -= coef
            W_rows.append(block)

        # Dynamics x_{t+1} - A x_t - B u_t = 0 (A x0 on the right for t = 0).
        for t in range(T):
            add(row, x_col(t + 1), np.eye(n))
            add(row, t * m, -B)
            coef_x = {t + 1: np.eye(n)}
            if t > 0:
                add(row, x_col(t), -A)
                coef_x[t] = -A
            rhs({t: -B}, coef_x, np.zeros(n), A if t == 0 else None)
            row += n
        n_equalities = row

        # Input box (always hard).
        for bound, sign in ((u_high, 1.0), (u_low, -1.0)):
            finite = np.flatnonzero(np.isfinite(bound))
            for t in range(T):
                sel = sign * np.eye(m)[finite]
                add(row, t * m, sel)
                rhs({t: sel}, {}, sign * bound[finite])
                row += len(finite)

        # Arena, then terminal rows: the "bounds", soft in the recovery QP.
        bound_rows = []  # (row, block on x_t, t)
        for bound, sign in ((y_high, 1.0), (y_low, -1.0)):
            finite = np.flatnonzero(np.isfinite(bound))
            for t in range(1, T + 1):
                sel = sign * C[finite]
                add(row, x_col(t), sel)
                rhs({}, {t: sel}, sign * bound[finite])
                bound_rows.extend(range(row, row + len(finite)))
                row += len(finite)
        self._n_arena_rows = len(bound_rows)
        if G.shape[0]:
            add(row, x_col(T), G)
            rhs({}, {T: G}, g)
            bound_rows.extend(range(row, row + G.shape[0]))
            row += G.shape[0]
        S, s = p.speed_rows  # the speed polygon, always hard
        for t in range(1, T + 1) if S.shape[0] else ():
            add(row, x_col(t), S)
            rhs({}, {t: S}, s)
            row += S.shape[0]
        hs_row0 = row

        # Halfspaces, row hs_row0 + i T + (t - 1): (a_it' C) x_t <= b_it. The pattern covers
        # every column C touches; the placeholder e'|C| (e a unit vector) keeps the rows
        # unit-scale for equilibration; every solve writes the real values.
        touched = np.flatnonzero(np.any(C != 0.0, axis=0))
        placeholder = (np.full(d, 1.0 / np.sqrt(d)) @ np.abs(C))[touched]
        hs_first = sum(len(r) for r in rows)
        hs_index = []
        for i in range(K):
            for t in range(1, T + 1):
                rows.append(np.full(len(touched), row))
                cols.append(x_col(t) + touched)
                vals.append(placeholder)
                hs_index.append((i * T + (t - 1)) * n + touched)
                row += 1
        hs_last = sum(len(r) for r in rows)

        # Slacks: -s on each soft row, and -s <= 0.
        soft_rows: list[int] = []
        if p.soft_halfspaces:
            soft_rows.extend(range(hs_row0, hs_row0 + K * T))
        n_hs_slack = len(soft_rows)
        if p.soft_bounds:
            soft_rows.extend(bound_rows)
        ns = len(soft_rows)
        slack0 = nu + nx
        for k, r in enumerate(soft_rows):
            rows.append(np.array([r]))
            cols.append(np.array([slack0 + k]))
            vals.append(np.array([-1.0]))
        if ns:
            rows.append(row + np.arange(ns))
            cols.append(slack0 + np.arange(ns))
            vals.append(-np.ones(ns))
            row += ns
        nv = nu + nx + ns
        constraint, position = _csc_with_positions(rows, cols, vals, (row, nv))
        cones = [clarabel.ZeroConeT(n_equalities)]
        if row > n_equalities:
            cones.append(clarabel.NonnegativeConeT(row - n_equalities))

        blocks = [2.0 * Rt for Rt in p.input_weights] + [2.0 * Qt for Qt in p.state_weights]
        if ns:
            blocks.append(sp.csc_matrix((ns, ns)))
        P = sp.triu(sp.block_diag(blocks, format="csc"), format="csc")
        P.sort_indices()
        q = np.zeros(nv)
        q[slack0:] = p.slack_penalty

        self._W = np.vstack(W_rows) if W_rows else np.zeros((0, width))
        # Reference positions C x^r_t for the halfspace rows, from the same v.
        self._positions_map = np.zeros((T * d, width))
        self._positions_map[:, n + nu : n + nu + nx] = np.kron(np.eye(T), C)
        self._W_full = matvec_operator(np.vstack([self._W, self._positions_map]))
        self._hs_row0 = hs_row0
        self._hs_positions = position[hs_first:hs_last].tolist() if K else []
        self._hs_index = np.concatenate(hs_index) if hs_index else np.zeros(0, dtype=np.int64)
        self._hs_direct = len(touched) == d and np.array_equal(C[:, touched], np.eye(d))
        self._slack_b = [0.0] * ns
        self._n_hs_slack = n_hs_slack
        self._nu, self._nx, self._nv = nu, nx, nv
        b0 = np.concatenate([self._W[:, -1], np.ones(K * T), np.zeros(ns)])
        self.solver = clarabel.DefaultSolver(P, q, constraint, b0, cones, self._settings)
        if not self.solver.is_data_update_allowed():  # pragma: no cover - settings checked
            raise InvalidParameterError(
                "solver_settings disable Clarabel's data updates; keep presolve off"
            )

    @property
    def n_variables(self) -> int:
        """Length of the decision vector (inputs, states, slacks)."""
        return self._nv

    def solve(self, step: StepData) -> QPSolution:
        """Write the step's data into the solver and solve; never raises on a failed solve."""
        p = self.problem
        T, m, d = p.horizon, p.m, p.d
        v = np.concatenate(
            (step.x0, step.ref_inputs.reshape(-1), step.ref_states.reshape(-1), (1.0,))
        )
        fixed = self._W_full @ v
        hs0 = self._hs_row0
        b = fixed[:hs0].tolist()
        normals = step.normals
        if normals.shape[0]:
            positions = fixed[hs0:].reshape(T, d)
            b += (step.offsets - _vecdot(normals, positions)).reshape(-1).tolist()
            if self._hs_direct:  # C = [I 0]: the entries of a' C are those of a
                a_values = normals.reshape(-1).tolist()
            else:
                a_values = (normals.reshape(-1, d) @ p.C).reshape(-1)[self._hs_index].tolist()
        b += self._slack_b
        try:
            if normals.shape[0]:
                self.solver.update(b=b, A=(self._hs_positions, a_values))
            else:
                self.solver.update(b=b)
            begin = time.perf_counter()
            solution = self.solver.solve()
            solve_time = time.perf_counter() - begin
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as exc:  # pyo3 panics derive from BaseException
            return QPSolution(False, f"exception: {exc!r}")
        status = str(solution.status)
        iterations = int(solution.iterations)
        z = solution.x
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

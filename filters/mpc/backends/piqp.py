r"""PIQP back end: the sparse QP of an :class:`~filters.mpc.MPCProblem` in PIQP.

PIQP (Schwan, Jiang, Kuhn and Jones, IEEE CDC 2023) is a proximal interior-point QP
solver in C++ with a sparse LDL' of its KKT system. The QP is the one of
:mod:`filters.mpc.backends.clarabel`, in the same deviation coordinates
:math:`w_t = u_t - u^r_t`, :math:`e_t = x_t - x^r_t` and slacks of the soft rows, so the
cost matrix and vector never change; PIQP's form separates what Clarabel stacks:

* the dynamics as equality rows :math:`A_\text{eq} z = b`;
* the arena, terminal and halfspace rows as :math:`G z \le h_u` (a soft row carries
  :math:`-s`);
* the input box and :math:`s \ge 0` as variable bounds :math:`x_l \le z \le x_u`.

Built once; per step only :math:`b`, :math:`h_u`, the bounds and the halfspace
entries :math:`a_{i,t}^\top C` of :math:`G` change (``update``, same sparsity pattern,
so the symbolic factorisation is reused). ``backend="auto"`` uses it for the QPs with
soft rows of long horizons, where an active-set method is slow (many violated rows)
and it is faster than Clarabel on the same QP (see :func:`filters.mpc.filter.auto_backend`).

Settings: one thread, PIQP's sparse LDL' of the KKT system; QPs with soft rows tighten
the duality-gap tolerances to :data:`SOFT_GAP_TOLERANCE`; hard QPs loosen the
primal-infeasibility tolerance to :data:`HARD_PRIMAL_INFEASIBILITY_TOLERANCE`. Override
with ``solver_settings``.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import numpy as np
import piqp
import scipy.sparse as sp

from filters.errors import InvalidParameterError, InvalidTypeError
from filters.mpc._linalg import matvec_operator
from filters.mpc.problem import MPCProblem
from filters.mpc.result import QPSolution, StepData

__all__ = [
    "HARD_PRIMAL_INFEASIBILITY_TOLERANCE", "SOFT_GAP_TOLERANCE", "PIQPBackend", "piqp_settings",
]

#: Duality-gap tolerances (absolute and relative) of QPs with soft rows, as Clarabel's
#: (:data:`filters.mpc.backends.clarabel.SOFT_GAP_TOLERANCE`): the penalty dominates.
SOFT_GAP_TOLERANCE = 1e-10

#: Primal-infeasibility tolerance (``eps_primal_inf``) of hard QPs; PIQP's default is
#: 1e-4. PIQP declares a QP primal infeasible when its infeasibility certificate meets
#: this tolerance; for hard QPs far from feasible (a long reference that leaves the
#: arena, halfspaces that cut off every reachable position) the default took two to three
#: times the iterations of a solve at long horizons. Checked on hard QPs whose
#: halfspace offsets sit 10 µm to 1 cm on either side of the feasibility boundary
#: (bisected with Clarabel at 1e-12): the same status as Clarabel's. Soft QPs are always
#: feasible and keep the default.
HARD_PRIMAL_INFEASIBILITY_TOLERANCE = 3e-4

_vecdot = getattr(np, "vecdot", None) or (lambda a, b: np.einsum("...d,...d->...", a, b))


def piqp_settings(solver: piqp.SparseSolver, overrides: Mapping[str, Any] | None,
                  *, soft: bool) -> None:
    """Apply the filter's PIQP settings, then the user's ``overrides``, to ``solver``.

    Raises
    ------
    InvalidTypeError
        If ``overrides`` is not a mapping.
    InvalidParameterError
        On an unknown setting or a value PIQP refuses.
    """
    settings = solver.settings
    settings.verbose = False
    settings.num_threads = 1
    settings.kkt_solver = piqp.sparse_ldlt
    if soft:
        settings.eps_duality_gap_abs = settings.eps_duality_gap_rel = SOFT_GAP_TOLERANCE
    else:
        settings.eps_primal_inf = HARD_PRIMAL_INFEASIBILITY_TOLERANCE
    if overrides is None:
        return
    if not isinstance(overrides, Mapping):
        raise InvalidTypeError(
            f"solver_settings must be a mapping of PIQP settings, got {overrides!r}")
    for key, value in overrides.items():
        if key.startswith("_") or not hasattr(settings, key):
            raise InvalidParameterError(f"solver_settings: unknown PIQP setting {key!r}")
        try:
            setattr(settings, key, value)
        except (TypeError, ValueError) as exc:
            raise InvalidParameterError(
                f"solver_settings: invalid value {value!r} for {key!r}") from exc


class PIQPBackend:
    """The sparse QP of one :class:`~filters.mpc.MPCProblem`, as a PIQP solver built once.

    Parameters
    ----------
    problem
        What to build (its ``soft_rows`` say which rows carry slacks).
    solver_settings
        PIQP settings to override (attributes of ``piqp.SparseSolver().settings``).
    """

    name = "piqp"

    def __init__(
        self, problem: MPCProblem, *, solver_settings: Mapping[str, Any] | None = None
    ) -> None:
        self.problem = problem
        self.solver = piqp.SparseSolver()
        piqp_settings(self.solver, solver_settings, soft=bool(problem.soft_rows))
        self._build()

    def _build(self) -> None:
        p = self.problem
        T, n, m, d, K = p.horizon, p.n, p.m, p.d, p.n_obstacles
        A, B, C = p.A, p.B, p.C
        nu, nx = T * m, T * n
        y_low, y_high = p.position_bounds
        G, g = p.terminal_set if p.terminal_set is not None else (np.zeros((0, n)), np.zeros(0))
        n_hs_slack = K * T if p.soft_halfspaces else 0

        def x_col(t: int) -> int:  # column of e_t, t = 1..T
            return nu + (t - 1) * n

        # Dynamics e_{t+1} - A e_t - B w_t = A x^r_t + B u^r_t - x^r_{t+1} (x^r_0 = x0).
        eq = sp.lil_matrix((nx, nu + nx))
        for t in range(T):
            eq[t * n:(t + 1) * n, x_col(t + 1):x_col(t + 1) + n] = np.eye(n)
            eq[t * n:(t + 1) * n, t * m:(t + 1) * m] = -B
            if t > 0:
                eq[t * n:(t + 1) * n, x_col(t):x_col(t) + n] = -A
        # Bound rows (the filter's order): upper arena faces by step and axis, lower
        # faces, terminal rows; right-hand side bound - (row) x^r.
        rows, rhs = [], []
        for bound, sign in ((y_high, 1.0), (y_low, -1.0)):
            finite = np.flatnonzero(np.isfinite(bound))
            for t in range(1, T + 1):
                block = np.zeros((len(finite), nu + nx))
                block[:, x_col(t):x_col(t) + n] = sign * C[finite]
                rows.append(block)
                rhs.append(sign * bound[finite])
        if G.shape[0]:
            block = np.zeros((G.shape[0], nu + nx))
            block[:, x_col(T):x_col(T) + n] = G
            rows.append(block)
            rhs.append(g)
        bound_rows = np.vstack(rows) if rows else np.zeros((0, nu + nx))
        n_bounds = len(bound_rows)
        n_b_slack = n_bounds if p.soft_bounds else 0
        # Halfspace rows, hs_row0 + i T + (t - 1): (a_it' C) e_t; the pattern covers every
        # column C touches (placeholder values; every solve writes the real ones).
        touched = np.flatnonzero(np.any(C != 0.0, axis=0))
        hs = np.zeros((K * T, nu + nx))
        for i in range(K):
            for t in range(1, T + 1):
                hs[i * T + t - 1, x_col(t) + touched] = 1.0
        nv = nu + nx + n_hs_slack + n_b_slack
        ineq = np.zeros((n_bounds + K * T, nv))
        ineq[:n_bounds, : nu + nx] = bound_rows
        ineq[n_bounds:, : nu + nx] = hs
        if n_b_slack:
            ineq[:n_bounds, nu + nx + n_hs_slack:] = -np.eye(n_bounds)
        if n_hs_slack:
            ineq[n_bounds:, nu + nx : nu + nx + n_hs_slack] = -np.eye(K * T)
        self._G = sp.csc_matrix(ineq)
        self._G.sort_indices()
        # Where each halfspace entry sits in G.data (row i T + t - 1, column x_col(t) + c).
        G_csc = self._G
        position = []
        for i in range(K):
            for t in range(1, T + 1):
                r = n_bounds + i * T + t - 1
                for col in x_col(t) + touched:
                    start, end = G_csc.indptr[col], G_csc.indptr[col + 1]
                    position.append(start + int(np.searchsorted(G_csc.indices[start:end], r)))
        self._hs_positions = np.array(position, dtype=np.int64)
        self._hs_index = ((np.arange(K * T)[:, None] * n) + touched[None]).reshape(-1)
        self._touched, self._hs_direct = touched, (
            len(touched) == d and np.array_equal(C[:, touched], np.eye(d)))

        eq_full = sp.hstack([sp.csc_matrix(eq), sp.csc_matrix((nx, nv - nu - nx))], "csc")
        blocks = [2.0 * Rt for Rt in p.input_weights] + [2.0 * Qt for Qt in p.state_weights]
        if nv > nu + nx:
            blocks.append(sp.csc_matrix((nv - nu - nx, nv - nu - nx)))
        P = sp.triu(sp.block_diag(blocks, format="csc"), format="csc")
        c = np.zeros(nv)
        c[nu + nx:] = p.slack_penalty
        # Right-hand sides from v = [x0; u^r; x^r]: b = Wb v, bound h_u = hb - Wh v.
        width = n + nu + nx
        Wb = np.zeros((nx, width))
        Wb[:n, :n] = A  # A x0 in the first block
        for t in range(T):
            Wb[t * n:(t + 1) * n, n + t * m:n + (t + 1) * m] = B
            Wb[t * n:(t + 1) * n, n + nu + t * n:n + nu + (t + 1) * n] = -np.eye(n)
            if t > 0:
                Wb[t * n:(t + 1) * n, n + nu + (t - 1) * n:n + nu + t * n] = A
        Wh = np.zeros((n_bounds, width))
        Wh[:, n + nu:] = bound_rows[:, nu:]
        self._W = matvec_operator(np.vstack([Wb, Wh, np.kron(np.eye(T), C) @ np.hstack(
            [np.zeros((nx, n + nu)), np.eye(nx)])]))
        self._hb = np.concatenate(rhs) if rhs else np.zeros(0)
        self._x_l, self._x_u = np.full(nv, -np.inf), np.full(nv, np.inf)
        self._x_l[nu + nx:] = 0.0
        u_low, u_high = p.input_bounds
        self._u_low, self._u_high = np.tile(u_low, T), np.tile(u_high, T)
        self._P, self._c, self._Aeq = P, c, eq_full
        self._sizes = (T, n, m, d, K, nu, nx, n_bounds, n_hs_slack, n_b_slack, nv)
        self._v = np.empty(width)
        self._ready = False

    def solve(self, step: StepData) -> QPSolution:
        """Write the step's data into the solver and solve; never raises on a failed solve."""
        T, n, m, d, K, nu, nx, n_bounds, n_hs_slack, n_b_slack, nv = self._sizes
        p = self.problem
        try:
            v = np.concatenate((step.x0, step.ref_inputs.reshape(-1),
                                step.ref_states.reshape(-1)), out=self._v)
            mapped = self._W @ v
            b = mapped[:nx]
            h_u = np.empty(n_bounds + K * T)
            h_u[:n_bounds] = self._hb - mapped[nx:nx + n_bounds]
            if K:
                positions = mapped[nx + n_bounds:].reshape(T, d)
                h_u[n_bounds:] = (step.offsets - _vecdot(step.normals, positions)).reshape(-1)
                if self._hs_direct:
                    values = step.normals.reshape(-1)
                else:
                    values = (step.normals.reshape(-1, d) @ p.C).reshape(-1)[self._hs_index]
                self._G.data[self._hs_positions] = values
            x_l, x_u = self._x_l, self._x_u
            u_ref = step.ref_inputs.reshape(-1)
            np.subtract(self._u_low, u_ref, out=x_l[:nu])
            np.subtract(self._u_high, u_ref, out=x_u[:nu])
            h_l = np.full(len(h_u), -np.inf)
            begin = time.perf_counter()
            if not self._ready:
                self.solver.setup(self._P, self._c, self._Aeq, b, self._G, h_l, h_u, x_l, x_u)
                self._ready = True
            else:
                self.solver.update(b=b, G=self._G, h_u=h_u, x_l=x_l, x_u=x_u)
            status = self.solver.solve()
            solve_time = time.perf_counter() - begin
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as exc:  # pybind11 errors, a bad update
            self._ready = False
            return QPSolution(False, f"exception: {exc!r}")
        result = self.solver.result
        iterations = int(result.info.iter)
        if status != piqp.PIQP_SOLVED:
            name = {piqp.PIQP_PRIMAL_INFEASIBLE: "PrimalInfeasible",
                    piqp.PIQP_MAX_ITER_REACHED: "MaxIterations"}.get(status, str(status))
            return QPSolution(False, name, iterations=iterations, solve_time=solve_time)
        z = np.asarray(result.x)
        inputs = z[:nu].reshape(T, m) + step.ref_inputs
        hs_slack = bound_slack = None
        if p.soft_halfspaces:
            hs_slack = z[nu + nx:nu + nx + n_hs_slack].reshape(K, T).copy()
        if p.soft_bounds:
            bound_slack = z[nu + nx + n_hs_slack:].copy()
        return QPSolution(True, "Solved", inputs, hs_slack, bound_slack, iterations, solve_time)

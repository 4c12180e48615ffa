r"""The MPC safety filter of the paper (Problem 2), solved with Clarabel directly.

Given the current ego state :math:`x_0`, a reference trajectory
:math:`x^r_1, \dots, x^r_T` (and optionally reference inputs
:math:`u^r_0, \dots, u^r_{T-1}`) and the safe halfspaces of every obstacle at
every predicted step, the filter solves the quadratic program of the paper's
Problem 2 (eq. (9), objective eq. (8)):

.. math::

    \min_{u, x} \quad & \sum_{t=0}^{T-1} (u_t - u^r_t)^\top R (u_t - u^r_t)
        + \sum_{t=1}^{T-1} (x_t - x^r_t)^\top Q (x_t - x^r_t)
        + (x_T - x^r_T)^\top Q_T (x_T - x^r_T) \\
    \text{s.t.} \quad & x_{t+1} = A x_t + B u_t, \quad t = 0, \dots, T-1, \\
        & u_\text{low} \le u_t \le u_\text{high}, \quad t = 0, \dots, T-1, \\
        & y_\text{low} \le C x_t \le y_\text{high}, \quad t = 1, \dots, T, \\
        & a_{i,t}^\top C x_t \le b_{i,t}, \quad i = 1, \dots, k,\ t = 1, \dots, T.

With :math:`u^r = 0` (the default) the input term is the paper's
:math:`u^\top R u`. The safe side of every halfspace is
``normals[i, t-1] @ (C x_t) <= offsets[i, t-1]``.

Design (following qpmpc's "build once, update per step")
---------------------------------------------------------
* **Three paths per step, one answer.** (1) With ``reference_inputs`` and
  ``skip_feasible_reference``: the minimiser of the cost (8) without
  constraints, in closed form; if it meets every constraint it is the optimum
  and no QP is solved. (2) With ``lazy_constraints`` (default): a small
  *condensed* QP with only the rows that may be active, its answer checked
  exactly against the rows left out, solved again with the missed rows if any
  (:meth:`MPCSafetyFilter._solve_lazy`). (3) The full *sparse* QP described
  below: with ``lazy_constraints=False``, after two misses, or when every row is
  kept. All three return Problem 2's minimiser (to the solver tolerances); the
  tests compare them with each other and with CVXPY.
* **Sparse, not condensed, for the full QP.** The decision vector holds the
  inputs and the states, :math:`(u_0, \dots, u_{T-1}, x_1, \dots, x_T[, s])`, and
  the dynamics are equality rows. Measured on the target size (T = 10, n = 4,
  m = 2, three obstacles) with Clarabel 0.11: the sparse form (KKT system of
  size 210) needs fewer interior-point iterations than the condensed one (KKT
  size 130, but a dense constraint block): about 6 vs 9 without equilibration,
  8 vs 11.5 with, and each of its iterations is no dearer (about 35 us here).
  With few rows the balance turns: the condensed QP in :math:`\delta = u -
  u^\circ` (deviation from the unconstrained minimiser, so again no linear
  term) has a KKT system of 20 + the rows kept, and took 0.16-0.18 ms where the
  sparse QP with the same rows took 0.29-0.33 ms (one obstacle, or one arena
  face kept; same iterations, answers equal to 1e-7).
* **Deviation coordinates.** The variables are the deviations
  :math:`w_t = u_t - u^r_t` and :math:`e_t = x_t - x^r_t` from the reference, so the
  cost is :math:`\sum w^\top R w + \sum e^\top Q e` with *no linear term*, and
  Clarabel's objective equals the filter's cost (8). In :math:`(u, x)` the solver
  would see the cost minus the constant :math:`\sum x^{r\top} Q x^r`, often 100
  times larger than the cost, and its relative gap tolerance would be that much
  looser on the cost (measured: input errors up to 6e-4 instead of 5e-6).
* **Fixed sparsity pattern.** :math:`P`, ``q`` and the constraint matrix are
  assembled once as CSC data. Per step only ``b`` (references, ``x0``, bounds
  and offsets shifted by the reference) and the entries of the halfspace rows of
  the constraint matrix (:math:`a_{i,t}^\top C`) change. Each
  :meth:`MPCSafetyFilter.solve` writes them with ``clarabel.DefaultSolver.update``
  (``A`` as a partial ``(indices, values)`` update of the halfspace entries, about
  25 us), so the KKT structure and its symbolic factorisation are reused. This
  needs Clarabel's presolve off (it forbids data updates), and the halfspace
  entries are stored structurally even when their value is zero.
* **Unused obstacle rows.** The QP always has ``n_obstacles * T`` halfspace
  rows. When fewer obstacles are given, the missing rows are written as
  :math:`0^\top x \le 1`, a constraint that always holds with slack 1. Infinite
  offsets are not used: with presolve off Clarabel would carry an infinite slack
  (presolve, which drops rows with :math:`|b| > 10^{20}`, cannot be combined with
  data updates).
* **Same data path for every solve.** The filter is built with placeholder data
  (unit-norm halfspace rows, ``x0 = 0``) and *every* solve, the first included,
  writes its data by ``update``; so a filter that solved a hundred problems
  returns exactly what a fresh filter returns on the same problem (tested).
* **Solver settings, measured** on 150-600 recorded crossing instances against a
  solve at tolerance 1e-12 (see :mod:`filters.benchmarks.filter_qp`):
  in hard mode, *no equilibration* (Clarabel would equilibrate once, from the
  placeholder data, and keep that scaling across updates) takes about 7
  instead of 8.5 iterations, about 20 % less time, with the same or better
  accuracy (relative input error <= 1e-4, typically 1e-7) for weights scaled by
  1e-3 .. 1e3; soft mode keeps equilibration on, because its large exact
  penalty (default 1e6 per m) fails without it. *No iterative refinement*
  saves about 40 % of the solver time; the stopping tolerances, not the
  linear solves, limit the accuracy. A *maximum step fraction* of 0.995
  (Clarabel: 0.99) saves about 0.4 iteration and gave max input errors of 5e-6
  instead of 4e-5. All can be changed through ``solver_settings``, e.g.
  ``{"equilibrate_enable": True, "iterative_refinement_enable": True}``.
* Clarabel's "AlmostSolved" answers (reduced tolerances) are accepted only if the
  rolled-out trajectory meets every constraint to ``FEASIBILITY_TOLERANCE``.
  Measured again and left as they are (500 crossing steps, against the 1e-12
  solve): ``direct_solve_method="faer"`` is 5 % slower than QDLDL here;
  gap tolerances of 1e-7 (1e-6) save 0.5 (0.9) iterations but give input errors
  up to 3e-4 (2e-3) instead of 5e-6; ``max_step_fraction=0.999`` saves 0.75
  iteration but gives errors up to 3e-5; ``tol_feas=1e-7``, ``tol_ktratio``
  and switching off static or dynamic regularisation change nothing measurable.
* **Python around the solver.** Each small NumPy call costs 1-3 us here, about
  50 of them made up half the step, so the step is counted in calls: the
  right-hand side is one product with a matrix built once (``W [x0; u^r; x^r;
  1]``, and ``lazy_map`` for the condensed QP), the roll-out, positions and box
  rows of the final check are one more (:meth:`SafetyFilterBase._evaluate`),
  halfspace dot products use ``np.vecdot`` (half the time of ``einsum``),
  finiteness is one reduction per array, and Clarabel's ``update`` gets Python
  lists (converted about twice as fast as arrays).
* Clarabel is an interior-point method and has no warm start; nothing is lost
  by not offering one.

Infeasibility (the paper's Remark after Problem 2)
--------------------------------------------------
A solve never raises because the QP is infeasible or the solver fails; it
returns a :class:`FilterResult` whose :class:`FilterStatus` says what was
applied:

* ``OPTIMAL``: the QP was solved; the plan is stored.
* ``SOFT`` (soft mode only): solved with some halfspace violated (slack > 0);
  a soft-mode solve with zero slack is ``OPTIMAL``.
* ``SHIFTED``: the QP failed; the inputs are the last stored plan shifted by the
  number of consecutive failures :math:`j` (:math:`u^*_j, \dots, u^*_{T-1}`), as the
  paper prescribes, padded with braking inputs to the horizon length.
* ``BRAKE``: no stored plan is left (:math:`j \ge T`, or no plan yet): the
  documented last resort, braking as hard as the input bounds allow.

Soft mode replaces each halfspace row by :math:`a_{i,t}^\top C x_t - s_{i,t} \le
b_{i,t}`, :math:`s_{i,t} \ge 0`, and adds :math:`\rho \sum_{i,t} s_{i,t}` to the cost
(an exact L1 penalty). The input and position bounds stay hard.

Module layout
-------------
This module holds the Clarabel back end: :class:`MPCSafetyFilter`, the
assembly of its sparse and condensed QPs, its solver settings and the
lazy-constraint machinery. The solver-independent parts live in
:mod:`filters.mpc_result` (:class:`FilterStatus`, :class:`FilterResult`),
:mod:`filters.mpc_checks` (input validation, :func:`parse_halfspaces`) and
:mod:`filters.mpc_base` (:class:`SafetyFilterBase`: fallback, feasibility check,
result assembly, shared tolerances); their public names are re-exported here.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import clarabel
import numpy as np
import scipy.sparse as sp

from filters.errors import InvalidParameterError, InvalidTypeError
from filters.mpc_base import DISABLED_OFFSET, SOFT_GAP_TOLERANCE, SafetyFilterBase, _vecdot
from filters.mpc_base import FEASIBILITY_TOLERANCE as FEASIBILITY_TOLERANCE
from filters.mpc_base import SLACK_TOLERANCE as SLACK_TOLERANCE
from filters.mpc_checks import parse_halfspaces as parse_halfspaces
from filters.mpc_result import FilterResult, FilterStatus, _QPAttempt

__all__ = ["FilterResult", "FilterStatus", "MPCSafetyFilter"]

# Names that lived here before the split stay importable from filters.mpc: the
# ``X as X`` imports above are explicit re-exports, and the base class keeps its
# former private name as an alias.
_SafetyFilterBase = SafetyFilterBase

_SOLVED = ("Solved", "AlmostSolved")
_INFEASIBLE = ("PrimalInfeasible", "AlmostPrimalInfeasible")
#: With ``lazy_constraints``, the input box (each face of the position box) is first
#: left out of the QP when the unconstrained minimiser keeps at least this fraction
#: of the box width (per axis) from it, and an obstacle's halfspaces when it keeps
#: at least ``HALFSPACE_MARGIN`` (row units: m for unit normals) from them at every
#: step; see MPCSafetyFilter._solve_lazy. Measured on 1000 crossing benchmark steps
#: with 0.1 and 0.5 m: 2 % of the steps needed a second QP, 0.1 % a third.
BOX_MARGIN = 0.1
HALFSPACE_MARGIN = 0.5

_ONE = np.ones(1)


class _Assembly(NamedTuple):
    """Constraint data of one QP structure (see :meth:`MPCSafetyFilter._assemble`)."""

    constraint: sp.csc_matrix
    b: np.ndarray  # constant part of the right-hand side
    cones: list
    hs_row0: int  # first halfspace row
    hs_positions: np.ndarray  # CSC positions of the halfspace entries a_it' C
    hs_flat: np.ndarray  # their flat indices into normals @ C, shape (K, T, n)
    hs_direct: bool  # whether those entries are the normals themselves, in order


@dataclass
class _Structure:
    """One Clarabel QP (the full one, or a condensed one) and how to write its data."""

    solver: Any  # clarabel.DefaultSolver
    hs_positions: list  # CSC positions of the halfspace entries, as a list
    hs_flat: np.ndarray  # their flat indices into the per-step coefficient array
    slack_rows_b: list  # right-hand side of its soft-mode rows -s <= 0


def _csc_with_positions(
    rows: list[np.ndarray], cols: list[np.ndarray], vals: list[np.ndarray],
    shape: tuple[int, int],
) -> tuple[sp.csc_matrix, np.ndarray]:
    """CSC matrix of the entries, and where each entry (in input order) landed in it.

    Structural zeros are kept (Clarabel's data updates need the pattern).
    """
    rows_all = np.concatenate(rows).astype(np.int64) if rows else np.zeros(0, np.int64)
    cols_all = np.concatenate(cols).astype(np.int64) if cols else np.zeros(0, np.int64)
    vals_all = np.concatenate(vals) if vals else np.zeros(0)
    # Build the pattern with entry ids as values (never zero, so nothing is
    # dropped), then read where each entry landed in the CSC data array.
    ids = np.arange(1, len(rows_all) + 1, dtype=np.float64)
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


def _solver_settings(
    overrides: Mapping[str, Any] | None, *, soft: bool
) -> clarabel.DefaultSettings:
    """Clarabel settings of the filter, with the user's ``overrides`` applied."""
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.presolve_enable = False  # required for data updates
    settings.chordal_decomposition_enable = False
    settings.input_sparse_dropzeros = False  # keep the structural zeros
    settings.iterative_refinement_enable = False  # see the module docstring
    settings.equilibrate_enable = soft  # see the module docstring
    if soft:  # the penalty dominates the objective; see SOFT_GAP_TOLERANCE
        settings.tol_gap_abs = settings.tol_gap_rel = SOFT_GAP_TOLERANCE
    settings.max_step_fraction = 0.995  # see the module docstring
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


# --------------------------------------------------------------------------- Clarabel
class MPCSafetyFilter(SafetyFilterBase):
    r"""MPC safety filter (the paper's Problem 2) as a Clarabel QP built once.

    Parameters
    ----------
    A, B, C
        Dynamics :math:`x_{t+1} = A x_t + B u_t` and position :math:`y_t = C x_t`,
        shapes ``(n, n)``, ``(n, m)``, ``(d, n)``. For the ego double integrator
        of the paper, ``A = [[I, Ts I], [0, I]]``, ``B = [[Ts²/2 I], [Ts I]]``,
        ``C = [I, 0]`` with ``Ts = 0.2`` s.
    horizon
        Number of steps ``T`` (the paper uses 10).
    Q, Q_terminal
        Symmetric positive semidefinite state weights for steps ``1..T-1`` and
        for step ``T``, shape ``(n, n)``. Weights mean :math:`x^\top Q x`.
    R
        Symmetric positive definite input weight, shape ``(m, m)``. Definiteness
        makes the QP strictly convex, so the filtered input is unique (the paper
        allows semidefinite R; a singular R would make the answer depend on the
        solver's path).
    input_bounds
        ``(low, high)`` of the input box :math:`\mathcal{U}`, each a number or an
        array of shape ``(m,)`` (e.g. m/s²); ``-inf``/``+inf`` entries leave that side
        free. ``None``: unbounded.
    position_bounds
        ``(low, high)`` of the position box :math:`\mathcal{Y}` (the arena, in m),
        each a number or shape ``(d,)``. ``None``: unbounded.
    n_obstacles
        Number of halfspace rows per step the QP is built with. Calls may pass
        fewer; the unused rows are disabled.
    soft
        Soften the halfspace rows with nonnegative slacks (see below). Input and
        position bounds stay hard.
    slack_penalty
        :math:`\rho > 0`, cost per m of halfspace violation in soft mode. The L1
        penalty is *exact* (unlike a quadratic one): when the hard problem is
        feasible and :math:`\rho` exceeds the largest Lagrange multiplier
        :math:`\|\lambda^*\|_\infty` of its halfspace rows, the soft solution equals
        the hard one with zero slack; when it is infeasible and :math:`\rho` exceeds
        the multipliers of the minimal-violation problem (a Hoffman-type bound
        times the cost gradient), the slacks achieve the *minimal* total (L1)
        violation and the cost is minimised among those solutions. On strongly
        infeasible crossing instances with the paper's weights (violations of
        several m) ``rho = 1e4`` left up to 0.14 m of avoidable violation and
        ``1e5`` up to 1e-3 m; ``1e6`` (the default) and ``1e7`` gave the minimal
        violation to 1e-8 m. Soft mode therefore keeps Clarabel's equilibration on,
        which these large penalties need.
    brake_gain
        Gain :math:`K`, shape ``(m, n)``, of the last-resort braking input
        :math:`u = \mathrm{clip}(-K x, u_\text{low}, u_\text{high})`. Default: derived
        from the model so that the next "velocity" (the part of the state ``C``
        does not see) is as close to zero as possible; for the double integrator
        this is :math:`u = \mathrm{clip}(-v / T_s)`, braking as hard as the bounds
        allow (see :meth:`_braking_gain`). Pass it for other models.
    solver_settings
        Clarabel settings to override, e.g. ``{"tol_feas": 1e-9}``. Presolve
        cannot be enabled (it forbids data updates).
    skip_feasible_reference
        When :meth:`solve` is given ``reference_inputs``, first compute the
        minimiser of the cost (8) *without* constraints (closed form, one
        matrix-vector product); if it meets every constraint exactly it is the
        unique optimum of Problem 2 and is returned without solving a QP
        (``iterations`` 0, ``solve_time`` 0, ``solver_status`` "unconstrained
        optimum feasible (no QP needed)"). A safe reference whose inputs generate
        its states from ``x0`` then passes through unchanged (to rounding). Calls
        without ``reference_inputs`` always solve the QP. Default ``True``.
    lazy_constraints
        Solve a small condensed QP first, without the rows the unconstrained
        minimiser keeps a margin from (boxes, far obstacles), check its answer
        against them exactly, and add the missed rows only when needed; the
        answer is the full QP's (see :meth:`_solve_lazy`). Condensing multiplies
        the dynamics out: for long horizons or unstable ``A`` its conditioning
        grows, and ``False`` (always the full sparse QP) is the safer choice.
        Default ``True``.

    Raises
    ------
    InvalidArrayError
        If a matrix has the wrong shape or a NaN/infinite entry.
    InvalidParameterError
        If ``horizon < 1``, ``n_obstacles < 0``, a weight is not symmetric, ``Q`` or
        ``Q_terminal`` is not PSD, ``R`` is not PD, a lower bound exceeds its upper
        bound, ``slack_penalty <= 0``, or a solver setting is unknown or invalid.
    InvalidTypeError
        If an argument has the wrong type (non-integer ``horizon``, bounds that are
        not a pair, a non-bool ``soft``, ``skip_feasible_reference`` or
        ``lazy_constraints``, ...).

    Examples
    --------
    >>> import numpy as np
    >>> Ts = 0.2
    >>> I, Z = np.eye(2), np.zeros((2, 2))
    >>> A = np.block([[I, Ts * I], [Z, I]]); B = np.vstack([Ts**2 / 2 * I, Ts * I])
    >>> C = np.hstack([I, Z])
    >>> mpc = MPCSafetyFilter(A, B, C, Q=4 * np.eye(4), Q_terminal=25 * np.eye(4),
    ...                       R=np.eye(2), input_bounds=(-5, 5),
    ...                       position_bounds=(-5, 5), n_obstacles=1)
    >>> x0 = np.array([0.0, 0.0, 1.5, 0.0])
    >>> reference = np.array([[1.5 * Ts * t, 0, 1.5, 0] for t in range(11)])
    >>> wall = (np.tile([1.0, 0.0], (1, 10, 1)), np.full((1, 10), 2.0))  # x <= 2 m
    >>> result = mpc.solve(x0, reference, wall)
    >>> result.status.value, bool(np.all(result.states[:, 0] <= 2 + 1e-6))
    ('optimal', True)
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
        skip_feasible_reference: bool = True,
        lazy_constraints: bool = True,
    ) -> None:
        super().__init__(
            A, B, C, horizon=horizon, Q=Q, Q_terminal=Q_terminal, R=R,
            input_bounds=input_bounds, position_bounds=position_bounds,
            n_obstacles=n_obstacles, soft=soft, slack_penalty=slack_penalty,
            brake_gain=brake_gain,
        )
        if not isinstance(skip_feasible_reference, (bool, np.bool_)):
            raise InvalidTypeError(
                f"skip_feasible_reference must be a bool, got {skip_feasible_reference!r}"
            )
        self._skip_feasible_reference = bool(skip_feasible_reference)
        if not isinstance(lazy_constraints, (bool, np.bool_)):
            raise InvalidTypeError(f"lazy_constraints must be a bool, got {lazy_constraints!r}")
        self._lazy_constraints = bool(lazy_constraints)
        self._settings = _solver_settings(solver_settings, soft=self._soft)
        self._build()

    # ------------------------------------------------------------------ build once
    def _assemble(self) -> _Assembly:
        r"""Constraint matrix, constant right-hand side and cones of the full QP.

        Variables ``z = (u_0..u_{T-1}, x_1..x_T, s)``, solved for as deviations
        from the reference (see :meth:`_solve_full`; the matrix is the same, only
        ``b`` shifts); rows: dynamics (zero cone), then input box, position box,
        halfspaces and (soft) ``-s <= 0``, all in the nonnegative cone (Clarabel's
        form is :math:`A z + s = b`, :math:`s \in K`). The right-hand side built here
        is the constant part; :meth:`_solve_full` writes the rest at every step.
        """
        T, n, m, d, K = self._T, self._n, self._m, self._d, self._n_obstacles
        nu, nx, ns = self._nu, self._nx, self._ns
        nv = nu + nx + ns

        def u_col(t: int) -> int:
            return t * m

        def x_col(t: int) -> int:  # x_t for t = 1..T
            return nu + (t - 1) * n

        rows: list[np.ndarray] = []
        cols: list[np.ndarray] = []
        vals: list[np.ndarray] = []
        b: list[np.ndarray] = []
        row = 0

        def add_block(r0: int, c0: int, block: np.ndarray) -> None:
            r, c = np.nonzero(block)
            rows.append(r + r0)
            cols.append(c + c0)
            vals.append(block[r, c])

        # Dynamics: x_{t+1} - A x_t - B u_t = 0 (A x0 on the right for t = 0).
        for t in range(T):
            add_block(row + t * n, x_col(t + 1), np.eye(n))
            add_block(row + t * n, u_col(t), -self._B)
            if t > 0:
                add_block(row + t * n, x_col(t), -self._A)
        b.append(np.zeros(nx))
        row += nx
        n_equalities = row

        # Input box: u_t[j] <= high[j], -u_t[j] <= -low[j] (finite sides only).
        for bound, sign in ((self._u_high, 1.0), (self._u_low, -1.0)):
            finite = np.flatnonzero(np.isfinite(bound))
            for t in range(T):
                count = len(finite)
                rows.append(row + np.arange(count))
                cols.append(u_col(t) + finite)
                vals.append(np.full(count, sign))
                b.append(sign * bound[finite])
                row += count

        # Position box: C[j] x_t <= high[j], -C[j] x_t <= -low[j].
        for bound, sign in ((self._y_high, 1.0), (self._y_low, -1.0)):
            finite = np.flatnonzero(np.isfinite(bound))
            for t in range(1, T + 1):
                add_block(row, x_col(t), sign * self._C[finite])
                b.append(sign * bound[finite])
                row += len(finite)

        # Halfspaces, row i*T + (t-1): (a_it' C) x_t [- s_it] <= b_it. The pattern
        # covers every column C can touch; the placeholder value e' |C| (e a unit
        # vector) gives the rows unit-scale norms for Clarabel's equilibration.
        hs_row0 = row
        touched = np.flatnonzero(np.any(self._C != 0.0, axis=0))
        placeholder = (np.full(d, 1.0 / np.sqrt(d)) @ np.abs(self._C))[touched]
        hs_first = sum(len(r) for r in rows)
        hs_i, hs_t, hs_j = [], [], []
        for i in range(K):
            for t in range(1, T + 1):
                count = len(touched)
                rows.append(np.full(count, row))
                cols.append(x_col(t) + touched)
                vals.append(placeholder)
                hs_i.append(np.full(count, i))
                hs_t.append(np.full(count, t - 1))
                hs_j.append(touched)
                if self._soft:
                    rows.append(np.array([row]))
                    cols.append(np.array([nu + nx + i * T + (t - 1)]))
                    vals.append(np.array([-1.0]))
                    hs_i.append(np.array([-1]))
                    hs_t.append(np.array([-1]))
                    hs_j.append(np.array([-1]))
                row += 1
        b.append(np.full(K * T, DISABLED_OFFSET))
        hs_last = sum(len(r) for r in rows)

        if self._soft:  # -s <= 0
            rows.append(row + np.arange(ns))
            cols.append(nu + nx + np.arange(ns))
            vals.append(-np.ones(ns))
            b.append(np.zeros(ns))
            row += ns

        constraint, position = _csc_with_positions(rows, cols, vals, (row, nv))
        hs_i_all = np.concatenate(hs_i) if hs_i else np.zeros(0, dtype=np.int64)
        hs_t_all = np.concatenate(hs_t) if hs_t else np.zeros(0, dtype=np.int64)
        hs_j_all = np.concatenate(hs_j) if hs_j else np.zeros(0, dtype=np.int64)
        keep = hs_i_all >= 0
        cones = [clarabel.ZeroConeT(n_equalities)]
        if row > n_equalities:
            cones.append(clarabel.NonnegativeConeT(row - n_equalities))
        return _Assembly(
            constraint=constraint,
            b=np.concatenate(b),
            cones=cones,
            hs_row0=hs_row0,
            hs_positions=position[np.arange(hs_first, hs_last)[keep]],
            # flat index into (normals @ C) of shape (K, T, n)
            hs_flat=(hs_i_all[keep] * T + hs_t_all[keep]) * n + hs_j_all[keep],
            # When C restricted to the columns it touches is the identity (C = [I 0]
            # for the ego), the halfspace entries are the normals themselves, in order.
            hs_direct=len(touched) == d and np.array_equal(self._C[:, touched], np.eye(d)),
        )

    def _build(self) -> None:
        r"""Build the full QP (sparse, solved by :meth:`_solve_full`) and the maps of
        the condensed QPs with rows left out (built on first use by :meth:`_condensed`).

        Cost of the full QP: :math:`\tfrac12 z^\top P z + q^\top z` with :math:`P = 2\,
        \mathrm{blkdiag}(R, \dots, Q, \dots, Q_T, 0)` and ``q`` zero but for the
        slack penalty (deviation coordinates, see :meth:`_solve_full`).
        """
        T, n, m, d, K = self._T, self._n, self._m, self._d, self._n_obstacles
        nu, nx = T * m, T * n
        self._nu, self._nx = nu, nx
        self._ns = K * T if self._soft else 0

        full = self._assemble()
        hs0 = full.hs_row0
        self._hs_flat, self._hs_direct = full.hs_flat, full.hs_direct
        self._hs_row0 = hs0
        # Rows before the halfspaces do not depend on the normals: their right-hand
        # side in deviation coordinates is b_const + W [x0; u^r; x^r] with
        # W = [[A; 0], -G] (G: those rows of the constraint matrix), one product.
        # W also appends the reference positions C x^r_t (for the halfspace rows) and,
        # in its last column, the constant part: [b_fixed; y^r] = W [x0; u^r; x^r; 1].
        W = np.zeros((hs0 + T * d, n + nu + nx + 1))
        W[:n, :n] = self._A
        W[:hs0, n : n + nu + nx] = -full.constraint[:hs0, : nu + nx].toarray()
        W[:hs0, -1] = full.b[:hs0]
        W[hs0:, n + nu : n + nu + nx] = np.kron(np.eye(T), self._C)
        self._W = W

        blocks = [2.0 * self._R] * T + [2.0 * Qt for Qt in self._Q_stack]
        if self._ns:
            blocks.append(sp.csc_matrix((self._ns, self._ns)))
        P = sp.triu(sp.block_diag(blocks, format="csc"), format="csc")
        P.sort_indices()
        q = np.zeros(nu + nx + self._ns)  # constant: deviation coordinates
        q[nu + nx :] = self._slack_penalty
        self._full = _Structure(
            solver=self._new_solver(P, q, full.constraint, full.b, full.cones),
            hs_positions=full.hs_positions.tolist(),  # update() converts lists fast
            hs_flat=full.hs_flat,
            slack_rows_b=[0.0] * self._ns,
        )
        self._condensed_qps: dict[tuple, _Structure] = {}
        self._injected_solver: Any = None
        self._shape = (full.constraint.shape[0], nu + nx + self._ns)
        self._build_condensed_maps()

    def _new_solver(
        self, P: sp.csc_matrix, q: np.ndarray, A: sp.csc_matrix, b: np.ndarray, cones: list
    ) -> Any:
        solver = clarabel.DefaultSolver(P, q, A, b, cones, self._settings)
        if not solver.is_data_update_allowed():  # pragma: no cover - settings checked
            raise InvalidParameterError(
                "solver_settings disable Clarabel's data updates; keep presolve off"
            )
        return solver

    def _build_condensed_maps(self) -> None:
        r"""Affine maps of ``v = [x0; u^r; x^r; 1]`` used by :meth:`_solve_lazy`.

        One product ``lazy_map @ v`` gives the unconstrained minimiser
        :math:`u^\circ` (see :meth:`_unconstrained_optimum`), its positions
        :math:`C x^\circ_t`, its slack in every input-box row and in every
        position-box face at every step; ``v' lazy_cost v`` is its cost (8).
        """
        T, n, m, d = self._T, self._n, self._m, self._d
        nu, nx = self._nu, self._nx
        width = n + nu + nx + 1
        x0_cols, ur_cols, xr_cols = slice(0, n), slice(n, n + nu), slice(n + nu, n + nu + nx)
        phi, gamma, gain = self._free_steps, self._forced_steps, self._gain
        u_opt = np.zeros((nu, width))  # u° = u^r + gain (x^r - Phi x0 - Gamma u^r)
        u_opt[:, x0_cols] = -gain @ phi
        u_opt[:, ur_cols] = np.eye(nu) - gain @ gamma
        u_opt[:, xr_cols] = gain
        c_block = np.kron(np.eye(T), self._C)
        positions = c_block @ gamma @ u_opt  # C x°_t, t = 1..T
        positions[:, x0_cols] += c_block @ phi
        one = np.zeros(width)
        one[-1] = 1.0
        # Input-box slack in the full QP's row order: high[j] - u_t[j], u_t[j] - low[j].
        input_rows = []
        for bound, sign in ((self._u_high, 1.0), (self._u_low, -1.0)):
            finite = np.flatnonzero(np.isfinite(bound))
            for t in range(T):
                for j in finite:
                    input_rows.append(sign * bound[j] * one - sign * u_opt[t * m + j])
        # Position-box face slack, face by face (upper faces, then lower, by axis),
        # t = 1..T within a face.
        face_rows = []
        self._face_axes: list[tuple[float, int]] = []
        for bound, sign in ((self._y_high, 1.0), (self._y_low, -1.0)):
            for j in np.flatnonzero(np.isfinite(bound)):
                self._face_axes.append((sign, int(j)))
                for t in range(T):
                    face_rows.append(sign * bound[j] * one - sign * positions[t * d + j])
        n_input, n_faces = len(input_rows), len(face_rows) // T
        self._lazy_map = np.vstack(
            [u_opt, positions]
            + [np.array(input_rows).reshape(n_input, width), np.array(face_rows).reshape(-1, width)]
        )
        self._lazy_split = (nu, nu + T * d, nu + T * d + n_input)
        self._n_input_rows, self._n_faces = n_input, n_faces
        # Cost (8) of u°: |u° - u^r|^2_Rbar + |x° - x^r|^2_Qbar, a quadratic form in v.
        du = u_opt.copy()
        du[:, ur_cols] -= np.eye(nu)
        dx = gamma @ u_opt
        dx[:, x0_cols] += phi
        dx[:, xr_cols] -= np.eye(nx)
        r_block = np.kron(np.eye(T), self._R)
        self._lazy_cost = du.T @ r_block @ du + dx.T @ self._Q_block @ dx
        # Margins for leaving a box out (see _solve_lazy), in the rows' units.
        scale = []
        for low, high in ((self._u_low, self._u_high), (self._y_low, self._y_high)):
            with np.errstate(invalid="ignore"):
                size = high - low
            scale.append(np.where(  # box width per axis, else the finite bound (at least 1)
                np.isfinite(size), size,
                np.maximum(1.0, np.where(np.isfinite(low), np.abs(low), np.abs(high))),
            ))
        u_scale, y_scale = scale
        self._input_margin = BOX_MARGIN * np.concatenate([
            np.tile(u_scale[np.isfinite(self._u_high)], T),
            np.tile(u_scale[np.isfinite(self._u_low)], T),
        ])
        self._face_margin = BOX_MARGIN * np.array([y_scale[j] for _, j in self._face_axes])
        # Condensed QP data: positions C x_t = C x°_t + (C Gamma)_t delta.
        self._c_gamma = (c_block @ gamma).reshape(T, d, nu)
        hessian = r_block + gamma.T @ self._Q_block @ gamma
        self._condensed_hessian = 0.5 * (hessian + hessian.T)
        self._full_key = (True, (True,) * n_faces, self._n_obstacles)

    def _condensed(self, key: tuple) -> _Structure:
        r"""The condensed QP with the rows flagged in ``key`` (built on first use).

        ``key = (input box, flags of the position-box faces, number of obstacles)``.
        Variables :math:`\delta = u - u^\circ` (and the slacks in soft mode); cost
        :math:`\delta^\top H \delta` (:math:`H = \bar R + \Gamma^\top \bar Q \Gamma`:
        the cost (8) is :math:`J(u^\circ) + \delta^\top H \delta`, no linear term);
        rows: the halfspaces of the first ``key[2]`` obstacle slots,
        :math:`a_{it}^\top (C\Gamma)_t \delta [- s_{it}] \le b_{it} - a_{it}^\top C
        x^\circ_t`, then the input box, then the flagged faces, then (soft)
        :math:`-s \le 0`.
        """
        structure = self._condensed_qps.get(key)
        if structure is not None:
            return structure
        with_input, faces, k = key
        T, m, nu = self._T, self._m, self._nu
        ns = k * T if self._soft else 0
        rows: list[np.ndarray] = []
        cols: list[np.ndarray] = []
        vals: list[np.ndarray] = []
        row = 0
        hs_index, hs_entry = [], []  # the a_it' (C Gamma)_t entries: value index, entry
        entries = 0
        for i in range(k):
            for t in range(T):
                touched = np.flatnonzero(np.any(self._c_gamma[t] != 0.0, axis=0))
                rows.append(np.full(len(touched), row))
                cols.append(touched)
                vals.append(np.ones(len(touched)))  # placeholder, written by update
                hs_index.append((i * T + t) * nu + touched)
                hs_entry.append(entries + np.arange(len(touched)))
                entries += len(touched)
                if self._soft:
                    rows.append(np.array([row]))
                    cols.append(np.array([nu + i * T + t]))
                    vals.append(np.array([-1.0]))
                    entries += 1
                row += 1
        if with_input:
            for bound, sign in ((self._u_high, 1.0), (self._u_low, -1.0)):
                finite = np.flatnonzero(np.isfinite(bound))
                for t in range(T):
                    rows.append(row + np.arange(len(finite)))
                    cols.append(t * m + finite)
                    vals.append(np.full(len(finite), sign))
                    row += len(finite)
        for (sign, j), chosen in zip(self._face_axes, faces, strict=True):
            for t in range(T) if chosen else ():
                touched = np.flatnonzero(self._c_gamma[t, j] != 0.0)
                rows.append(np.full(len(touched), row))
                cols.append(touched)
                vals.append(sign * self._c_gamma[t, j, touched])
                row += 1
        if ns:
            rows.append(row + np.arange(ns))
            cols.append(nu + np.arange(ns))
            vals.append(-np.ones(ns))
            row += ns
        constraint, position = _csc_with_positions(rows, cols, vals, (row, nu + ns))
        blocks = [sp.csc_matrix(2.0 * self._condensed_hessian)]
        if ns:
            blocks.append(sp.csc_matrix((ns, ns)))
        P = sp.triu(sp.block_diag(blocks, format="csc"), format="csc")
        P.sort_indices()
        q = np.zeros(nu + ns)
        q[nu:] = self._slack_penalty
        cones = [clarabel.NonnegativeConeT(row)] if row else []
        hs_flat = np.concatenate(hs_index) if hs_index else np.zeros(0, dtype=np.int64)
        hs_entries = np.concatenate(hs_entry) if hs_entry else np.zeros(0, dtype=np.int64)
        solver = self._new_solver(P, q, constraint, np.ones(row), cones)
        structure = _Structure(
            solver=self._injected_solver or solver,
            hs_positions=position[hs_entries].tolist(),
            hs_flat=hs_flat,
            slack_rows_b=[0.0] * ns,
        )
        self._condensed_qps[key] = structure
        return structure

    def _key(self, with_input: bool, faces: np.ndarray, n_halfspaces: int) -> tuple:
        """Structure key; an input box without rows counts as included."""
        return (
            bool(with_input or not self._n_input_rows), tuple(faces.tolist()), n_halfspaces
        )

    @property
    def _solver(self) -> Any:
        """The Clarabel solver of the full QP (assigning one replaces every QP's solver)."""
        return self._full.solver

    @_solver.setter
    def _solver(self, solver: Any) -> None:  # fault injection in tests
        self._injected_solver = solver
        self._full.solver = solver
        for structure in self._condensed_qps.values():
            structure.solver = solver

    @property
    def last_qp_solves(self) -> int:
        """Clarabel calls made by the last :meth:`solve` (see :meth:`_solve_lazy`).

        0 if no QP was needed (``skip_feasible_reference``), 1 if the first QP
        answered, more if a QP with rows left out had to be solved again.
        """
        return self._qp_solves

    # ------------------------------------------------------------------ update and solve
    def _unconstrained_optimum(
        self, x0: np.ndarray, ref_states: np.ndarray, ref_inputs: np.ndarray,
        normals: np.ndarray, offsets: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """As in the base class, from the product :meth:`_solve_lazy` needs anyway.

        ``lazy_map @ v`` gives the minimiser and its slack in every box row; it is
        kept for :meth:`_solve_lazy` when a QP is needed (measured: the base
        version, then the QP, cost about 40 us more per step). The answer is
        checked exactly on its roll-out, as in the base class.
        """
        v = np.concatenate((x0, ref_inputs.reshape(-1), ref_states.reshape(-1), _ONE))
        big = self._lazy_map @ v
        self._step_cache = (v, big)
        T, nu, d = self._T, self._nu, self._d
        _, end_positions, _ = self._lazy_split
        if not np.minimum.reduce(big[end_positions:], initial=0.0) >= 0.0:  # box rows
            return None
        if normals.shape[0] and not np.minimum.reduce(
            offsets - _vecdot(normals, big[nu:end_positions].reshape(T, d)), axis=None
        ) >= 0.0:
            return None
        inputs = big[:nu]
        if not (np.all(inputs >= self._u_low_all) and np.all(inputs <= self._u_high_all)):
            return None
        states, halfspace, box, _ = self._evaluate(x0, inputs, normals, offsets)
        if not (box <= 0.0 and np.maximum.reduce(halfspace, axis=None, initial=-np.inf) <= 0.0):
            return None
        return inputs.reshape(T, self._m), states

    def _solve_qp(
        self, x0: np.ndarray, ref_states: np.ndarray, ref_inputs: np.ndarray,
        normals: np.ndarray, offsets: np.ndarray, include: tuple | None = None,
    ) -> _QPAttempt:
        """Problem 2 for the (padded) data: lazily (:meth:`_solve_lazy`) or in full."""
        if self._step_cache is not None:
            v, big = self._step_cache
        else:
            v = np.concatenate((x0, ref_inputs.reshape(-1), ref_states.reshape(-1), _ONE))
            big = None
        if not self._lazy_constraints or (include is not None and self._qp_solves >= 2):
            return self._solve_full(v, ref_inputs, normals, offsets)  # after two misses: all
        return self._solve_lazy(v, ref_inputs, normals, offsets, include, big)

    def _solve_full(
        self, v: np.ndarray, ref_inputs: np.ndarray, normals: np.ndarray,
        offsets: np.ndarray, iterations: int = 0, solve_time: float = 0.0,
    ) -> _QPAttempt:
        r"""The full QP, in deviation coordinates :math:`w = u - u^r`, :math:`e = x - x^r`.

        The cost (8) becomes :math:`\sum w_t^\top R w_t + \sum e_t^\top Q_t e_t`
        with no linear term, so ``q`` never changes and Clarabel's objective *is*
        the filter's cost. (With ``u``, ``x`` as variables the objective is the cost
        minus the constant :math:`\sum x^{r\top} Q x^r`, often 100x larger than the
        cost itself, and the relative gap tolerance would then be 100x looser on
        the cost: measured input errors up to 6e-4 instead of 5e-6.) Only ``b``
        (references, ``x0``, offsets) and the halfspace entries of ``A`` change.
        ``iterations`` and ``solve_time`` of earlier calls are added to the answer's.
        """
        T, nu, nx, hs0 = self._T, self._nu, self._nx, self._hs_row0
        structure = self._full
        # Rows before the halfspaces, then the reference positions y^r_t = C x^r_t.
        fixed = self._W @ v
        b = fixed[:hs0].tolist()
        if normals.shape[0]:  # a_it' C x^r_t = a_it . y^r_t
            positions = fixed[hs0:].reshape(T, self._d)
            b += (offsets - _vecdot(normals, positions)).reshape(-1).tolist()
        b += structure.slack_rows_b
        if self._hs_direct:  # the entries of a_it' C are those of a_it
            a_values = normals.reshape(-1).tolist()
        else:
            a_values = (normals.reshape(-1, self._d) @ self._C).reshape(-1)[
                structure.hs_flat
            ].tolist()
        self._qp_solves += 1
        try:
            structure.solver.update(b=b, A=(structure.hs_positions, a_values))
            begin = time.perf_counter()
            solution = structure.solver.solve()
            solve_time += time.perf_counter() - begin
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as exc:  # pyo3 panics derive from BaseException
            return _QPAttempt(None, None, f"exception: {exc!r}", iterations, solve_time, False)
        status = str(solution.status)
        z = solution.x  # a list; only the inputs (and slacks) are converted
        inputs = slack = None
        if len(z) == self._shape[1]:
            inputs = np.array(z[:nu]).reshape(T, self._m) + ref_inputs
            if self._soft:
                slack = np.array(z[nu + nx :]).reshape(self._n_obstacles, T)
        return _QPAttempt(
            inputs, slack, status, iterations + int(solution.iterations), solve_time,
            status in _SOLVED,
            float(solution.obj_val),  # the cost (8) itself, in deviation coordinates
        )

    def _solve_lazy(
        self, v: np.ndarray, ref_inputs: np.ndarray, normals: np.ndarray,
        offsets: np.ndarray, include: tuple | None, big: np.ndarray | None = None,
    ) -> _QPAttempt:
        r"""Solve a condensed QP with the rows that matter; :meth:`solve` checks the rest.

        **Why.** Most rows are far from active: the arena and the input box almost
        always, and every halfspace of an obstacle that the plan passes at a
        distance. Clarabel's time grows with the size of the KKT system: 210 for
        the full sparse QP (T = 10, three obstacles), 20 + the rows kept for the
        condensed QP in :math:`\delta = u - u^\circ`. Measured on the crossing
        benchmark: one obstacle's rows kept, about 0.18 ms instead of 0.29 ms;
        nothing kept (the unconstrained minimiser), about 0.02 ms.

        **How.** One product gives the unconstrained minimiser :math:`u^\circ` of
        the cost (8), its positions, and its slack in every box row; the rows
        kept are those of the input box if :math:`u^\circ` comes within
        ``BOX_MARGIN`` of the box width of it, of each position-box face it comes
        within ``BOX_MARGIN`` of, and of each obstacle whose halfspaces it comes
        within ``HALFSPACE_MARGIN`` of at some step (``include`` overrides this on
        a second call). The answer goes back with what was left out
        (``_QPAttempt.relaxed``), and :meth:`solve` checks the roll-out against
        those rows: if it meets them all *exactly* (no tolerance), it meets the
        full problem's optimality conditions with zero multipliers on them, so it
        is the full QP's answer to the same solver tolerances. Otherwise
        :meth:`solve` calls again with the violated rows added (``iterations``
        and ``solve_time`` add up; :attr:`last_qp_solves` counts the calls), and
        after two misses the full QP decides. A relaxed QP that is infeasible
        proves the full one infeasible; any other failure of a relaxed QP is
        retried on the full QP.
        """
        T, nu, d, K = self._T, self._nu, self._d, self._n_obstacles
        if big is None:
            big = self._lazy_map @ v
        _, end_positions, end_inputs = self._lazy_split
        u_opt = big[:nu]
        hs_slack = offsets - _vecdot(normals, big[nu:end_positions].reshape(T, d))
        input_slack = big[end_positions:end_inputs]
        face_slack = big[end_inputs:].reshape(self._n_faces, T)
        if include is None:
            with_input = bool(self._n_input_rows) and not np.minimum.reduce(
                input_slack - self._input_margin
            ) >= 0.0
            faces = np.minimum.reduce(face_slack, axis=1) < self._face_margin
            near = np.minimum.reduce(hs_slack, axis=1) < HALFSPACE_MARGIN
        else:
            with_input, faces, near = include
        key = self._key(with_input, faces, int(np.count_nonzero(near)))
        if key == self._full_key:
            return self._solve_full(v, ref_inputs, normals, offsets)
        structure = self._condensed(key)
        k = key[2]
        if k == K:
            selected, kept_slack = normals, hs_slack
        else:
            order = near.nonzero()[0]
            selected, kept_slack = normals[order], hs_slack[order]
        b = kept_slack.reshape(-1).tolist()
        if self._n_input_rows and key[0]:
            b += input_slack.tolist()
        if faces.any():
            b += face_slack[faces].reshape(-1).tolist()
        b += structure.slack_rows_b
        coefficients = np.matmul(selected[:, :, None, :], self._c_gamma).reshape(-1)
        self._qp_solves += 1
        try:
            structure.solver.update(
                b=b, A=(structure.hs_positions, coefficients[structure.hs_flat].tolist())
            )
            begin = time.perf_counter()
            solution = structure.solver.solve()
            solve_time = time.perf_counter() - begin
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException:  # pyo3 panics derive from BaseException: the full QP decides
            return self._solve_full(v, ref_inputs, normals, offsets)
        status = str(solution.status)
        iterations = int(solution.iterations)
        if status not in _SOLVED and status not in _INFEASIBLE:  # numerical trouble
            return self._solve_full(v, ref_inputs, normals, offsets, iterations, solve_time)
        z = solution.x
        inputs = slack = None
        if len(z) == nu + len(structure.slack_rows_b):
            inputs = (u_opt + np.array(z[:nu])).reshape(T, self._m)
            if self._soft:  # left-out rows: zero slack (if they hold, as solve checks)
                slack = np.zeros((K, T))
                slack[near] = np.array(z[nu:]).reshape(k, T)
        # cost (8) = J(u°) + delta' H delta (+ rho sum(s): Clarabel's objective)
        objective = float(v @ (self._lazy_cost @ v)) + float(solution.obj_val)
        return _QPAttempt(
            inputs, slack, status, iterations, solve_time, status in _SOLVED, objective,
            (key[0], faces, near),
        )

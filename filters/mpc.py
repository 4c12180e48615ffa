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
  rows of the final check are one more (:meth:`_SafetyFilterBase._evaluate`),
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
"""

from __future__ import annotations

import math
import numbers
import time
from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum
from typing import Any, NamedTuple

import clarabel
import numpy as np
import scipy.linalg
import scipy.sparse as sp

from filters._validation import finite_array, scalar_in_range
from filters.errors import InvalidArrayError, InvalidParameterError, InvalidTypeError

__all__ = ["FilterResult", "FilterStatus", "MPCSafetyFilter"]

#: Offset written in unused halfspace rows: the row reads ``0 @ x <= 1``.
DISABLED_OFFSET = 1.0
#: Largest constraint violation (in the constraint's units: m for positions and
#: halfspaces, input units for the input box) accepted from a "solved" QP.
FEASIBILITY_TOLERANCE = 1e-6
#: Soft-mode slacks at or below this value (in m) count as zero.
SLACK_TOLERANCE = 1e-6
#: Duality-gap tolerance (absolute and relative) of soft mode. The penalty
#: term (rho = 1e6 per m) dominates the objective when some halfspace must be
#: violated, so Clarabel's default 1e-8 resolves the quadratic cost, hence the
#: inputs, only to about 5e-2; 1e-10 gives about 2e-4 for about one more iteration.
SOFT_GAP_TOLERANCE = 1e-10

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


class FilterStatus(str, Enum):
    """What the safety filter returned, and which fallback (if any) was used."""

    OPTIMAL = "optimal"
    """Problem 2 was solved; the inputs are its minimiser."""
    SOFT = "soft"
    """Soft mode: solved, but some halfspace is violated (``slack > 0``)."""
    SHIFTED = "shifted"
    """The QP failed; the last optimal plan, shifted, was used (paper's Remark)."""
    BRAKE = "brake"
    """The QP failed and no stored plan was left: braking inputs."""


@dataclass(frozen=True)
class FilterResult:
    """Result of one safety-filter step, in the spirit of qpsolvers' ``Solution``.

    Attributes
    ----------
    status
        What was returned (see :class:`FilterStatus`).
    inputs
        Input sequence :math:`u_0, \\dots, u_{T-1}`, shape ``(T, m)`` (e.g. m/s²).
        ``inputs[0]`` is the input to apply now.
    states
        States :math:`x_0, \\dots, x_T` rolled out from the actual ``x0`` with
        ``inputs``, shape ``(T + 1, n)``.
    solve_time
        Wall time of the QP solver call, in s.
    total_time
        Wall time of the whole :meth:`MPCSafetyFilter.solve` call (validation,
        data update, solver, roll-out), in s.
    slack
        Soft mode: halfspace violations :math:`s_{i,t} \\ge 0` in m, shape
        ``(k, T)`` for the ``k`` halfspace rows given (entries
        ``<= SLACK_TOLERANCE`` are reported as 0). On a fallback it is the
        violation :math:`\\max(0, a^\\top C x_t - b)` of the returned trajectory.
        ``None`` in hard mode.
    solver_status
        The solver's own status (Clarabel's ``SolverStatus`` name, or the CVXPY
        status), or a short description of why a solution was rejected
        (exception, NaN, constraint violation).
    iterations
        Interior-point iterations of the solver call (0 if it did not run).
    objective
        When solved, the optimal value reported by the solver: the cost (8)
        (plus :math:`\\rho \\sum s` in soft mode). On a fallback, the cost (8) of
        the returned trajectory.
    consecutive_failures
        Number of failed solves in a row, this one included (0 on success). On
        ``SHIFTED`` it is the shift applied to the stored plan.
    """

    status: FilterStatus
    inputs: np.ndarray
    states: np.ndarray
    solve_time: float
    total_time: float
    slack: np.ndarray | None
    solver_status: str
    iterations: int
    objective: float
    consecutive_failures: int = 0

    @property
    def first_input(self) -> np.ndarray:
        """The input to apply now, ``inputs[0]``, shape ``(m,)``."""
        return self.inputs[0]

    @property
    def solved(self) -> bool:
        """Whether the QP was solved (``OPTIMAL`` or ``SOFT``)."""
        return self.status in (FilterStatus.OPTIMAL, FilterStatus.SOFT)

    @property
    def fallback(self) -> bool:
        """Whether a fallback (``SHIFTED`` or ``BRAKE``) was returned."""
        return not self.solved


class _QPAttempt(NamedTuple):
    """What a QP back end reports to :class:`_SafetyFilterBase`."""

    inputs: np.ndarray | None  # (T, m) if the solver claims a solution
    slack: np.ndarray | None  # (n_obstacles, T) in soft mode
    solver_status: str
    iterations: int
    solve_time: float
    solved: bool  # the solver's status says "solved"
    objective: float = float("nan")  # the solver's optimal value: cost (8) [+ rho sum(s)]
    # Rows the QP left out (MPCSafetyFilter, lazy constraints): (input box included,
    # position-box faces included (bool per finite face), obstacles included (K,)
    # bool); None: the full QP.
    relaxed: tuple[bool, np.ndarray, np.ndarray] | None = None


#: What :meth:`_SafetyFilterBase.solve` reports when the unconstrained minimiser
#: meets every constraint, so that no QP is solved (``iterations`` 0, ``solve_time`` 0).
_NO_QP = _QPAttempt(
    None, None, "unconstrained optimum feasible (no QP needed)", 0, 0.0, True, 0.0
)


_ONE = np.ones(1)
#: Dot products over the last axis, broadcast: (k, T, d) with (T, d) -> (k, T). The
#: gufunc np.vecdot (NumPy >= 2) takes about half the time of the equivalent einsum.
_vecdot = getattr(np, "vecdot", None) or (lambda a, b: np.einsum("...d,...d->...", a, b))


def _all_finite(array: np.ndarray) -> bool:
    """``np.isfinite(array).all()``, with a one-reduction fast path (see :func:`_finite`)."""
    return math.isfinite(np.add.reduce(array, axis=None)) or bool(np.isfinite(array).all())


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


# --------------------------------------------------------------------------- validation
def _finite(name: str, value: object, shape: tuple[int, ...]) -> np.ndarray:
    """Fast path of :func:`finite_array` for the per-step arrays (same errors).

    A float64 array of the right shape is accepted when its sum is finite: one
    reduction (about 1 us) instead of ``np.isfinite(a).all()`` (two passes and
    a temporary, about 3 us). A sum that overflows, or any NaN/inf, takes the
    full check below, which raises only if an entry is really not finite.
    """
    if type(value) is np.ndarray and value.dtype == np.float64 and value.shape == shape:
        if math.isfinite(np.add.reduce(value, axis=None)):
            return value
        array = value
    elif isinstance(value, np.ndarray) and value.dtype == np.float64:
        array = value
    else:
        try:
            array = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            return finite_array(name, value, shape=shape)  # raises with the message
    if array.shape == shape and np.isfinite(array).all():
        return array
    return finite_array(name, value, shape=shape)  # raises with the message


def _integer(name: str, value: object, *, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise InvalidTypeError(f"{name} must be an integer, got {value!r}")
    if int(value) < low:
        raise InvalidParameterError(f"{name} must be >= {low}, got {value!r}")
    return int(value)


def _weight(name: str, value: object, size: int, *, definite: bool) -> np.ndarray:
    matrix = finite_array(name, value, shape=(size, size))
    scale = max(1.0, float(np.max(np.abs(matrix))))
    if not np.allclose(matrix, matrix.T, rtol=0.0, atol=1e-10 * scale):
        raise InvalidParameterError(
            f"{name} must be symmetric, got max |{name} - {name}.T| = "
            f"{np.max(np.abs(matrix - matrix.T)):.3g}; pass ({name} + {name}.T) / 2"
        )
    matrix = 0.5 * (matrix + matrix.T)
    smallest = float(np.linalg.eigvalsh(matrix)[0]) if size else 0.0
    if definite and smallest <= 1e-12 * scale:
        raise InvalidParameterError(
            f"{name} must be positive definite (it keeps the QP strictly convex and "
            f"the filtered input unique), got smallest eigenvalue {smallest:.3g}"
        )
    if not definite and smallest < -1e-10 * scale:
        raise InvalidParameterError(
            f"{name} must be positive semidefinite, got smallest eigenvalue {smallest:.3g}"
        )
    return matrix


def _box(name: str, value: object, size: int) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` broadcast to ``(size,)``; ``None`` means unbounded."""
    if value is None:
        return np.full(size, -np.inf), np.full(size, np.inf)
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
        raise InvalidTypeError(f"{name} must be None or a pair (low, high), got {value!r}")
    sides = []
    for side, raw in zip(("low", "high"), value, strict=True):
        try:
            array = np.asarray(raw, dtype=np.float64)
            array = np.array(np.broadcast_to(array, (size,)))
        except (TypeError, ValueError) as exc:
            raise InvalidArrayError(
                f"{name} {side} must be a number or an array of shape ({size},), got {raw!r}"
            ) from exc
        if np.any(np.isnan(array)):
            raise InvalidArrayError(f"{name} {side} must not contain NaN, got {array}")
        sides.append(array)
    low, high = sides
    if np.any(low == np.inf) or np.any(high == -np.inf):
        raise InvalidParameterError(
            f"{name} must have low < +inf and high > -inf, got low={low}, high={high}"
        )
    if np.any(low > high):
        index = int(np.argmax(low > high))
        raise InvalidParameterError(
            f"{name} lower bound exceeds upper bound at index {index}: "
            f"{low[index]} > {high[index]}"
        )
    return low, high


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


def parse_halfspaces(
    halfspaces: object, horizon: int, dim: int, n_obstacles: int
) -> tuple[np.ndarray, np.ndarray]:
    """Validate halfspaces given as an object, a pair, or ``None``.

    Parameters
    ----------
    halfspaces
        ``None`` (no obstacle), a pair ``(normals, offsets)``, or any object with
        ``.normals`` of shape ``(k, T, d)`` and ``.offsets`` of shape ``(k, T)``.
    horizon, dim, n_obstacles
        ``T``, ``d`` and the largest ``k`` accepted.

    Returns
    -------
    normals, offsets
        Finite arrays of shapes ``(k, T, d)`` and ``(k, T)``.

    Raises
    ------
    InvalidTypeError
        If ``halfspaces`` is none of the accepted forms.
    InvalidArrayError
        On a wrong shape, NaN or infinite entries, or ``k > n_obstacles``.
    """
    if halfspaces is None:
        return np.zeros((0, horizon, dim)), np.zeros((0, horizon))
    if hasattr(halfspaces, "normals") and hasattr(halfspaces, "offsets"):
        raw_normals, raw_offsets = halfspaces.normals, halfspaces.offsets
    elif isinstance(halfspaces, (tuple, list)) and len(halfspaces) == 2:
        raw_normals, raw_offsets = halfspaces
    else:
        raise InvalidTypeError(
            "halfspaces must be None, a pair (normals, offsets) or an object with "
            f".normals and .offsets, got {type(halfspaces).__name__}"
        )
    try:
        normals = np.asarray(raw_normals, dtype=np.float64)
    except (TypeError, ValueError):
        normals = None
    if normals is None or normals.ndim != 3:  # let finite_array raise the message
        normals = finite_array("halfspaces.normals", raw_normals, shape=(None, horizon, dim))
    normals = _finite("halfspaces.normals", normals, (normals.shape[0], horizon, dim))
    offsets = _finite("halfspaces.offsets", raw_offsets, (normals.shape[0], horizon))
    if normals.shape[0] > n_obstacles:
        raise InvalidArrayError(
            f"halfspaces has {normals.shape[0]} obstacle rows but the filter was built "
            f"for n_obstacles={n_obstacles}; build it with a larger n_obstacles"
        )
    return normals, offsets


# --------------------------------------------------------------------------- base class
class _SafetyFilterBase:
    """Validation, fallback and result assembly shared by the QP back ends.

    Subclasses implement :meth:`_solve_qp`.
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
    ) -> None:
        A = finite_array("A", A, ndim=2)
        n = A.shape[0]
        A = finite_array("A", A, shape=(n, n))
        B = finite_array("B", B, ndim=2)
        B = finite_array("B", B, shape=(n, None))
        C = finite_array("C", C, ndim=2)
        C = finite_array("C", C, shape=(None, n))
        m, d = B.shape[1], C.shape[0]
        if n == 0 or m == 0 or d == 0:
            raise InvalidArrayError(
                f"A, B and C must be non-empty, got shapes {A.shape}, {B.shape}, {C.shape}"
            )
        self._A, self._B, self._C = A, B, C
        self._n, self._m, self._d = n, m, d
        self._T = _integer("horizon", horizon, low=1)
        self._n_obstacles = _integer("n_obstacles", n_obstacles, low=0)
        self._Q = _weight("Q", Q, n, definite=False)
        self._Q_terminal = _weight("Q_terminal", Q_terminal, n, definite=False)
        self._R = _weight("R", R, m, definite=True)
        self._u_low, self._u_high = _box("input_bounds", input_bounds, m)
        self._y_low, self._y_high = _box("position_bounds", position_bounds, d)
        if not isinstance(soft, (bool, np.bool_)):
            raise InvalidTypeError(f"soft must be a bool, got {soft!r}")
        self._soft = bool(soft)
        self._slack_penalty = scalar_in_range(
            "slack_penalty", slack_penalty, low=0.0, low_inclusive=False, high=np.inf,
            high_inclusive=False,
        )
        # Q_t for t = 1..T, stacked, and the block-diagonal weights of the cost (8).
        T = self._T
        self._Q_stack = np.concatenate(
            [np.broadcast_to(self._Q, (T - 1, n, n)), self._Q_terminal[None]]
        )
        self._Q_block = scipy.linalg.block_diag(*self._Q_stack)  # (T n, T n)
        # Roll-out x_t = A^t x0 + sum_{j<t} A^{t-1-j} B u_j, stacked for t = 0..T.
        powers = [np.eye(n)]
        for _ in range(T):
            powers.append(self._A @ powers[-1])
        self._free = np.concatenate(powers)  # ((T+1) n, n)
        forced = np.zeros(((T + 1) * n, T * m))
        for t in range(1, T + 1):
            for j in range(t):
                forced[t * n : (t + 1) * n, j * m : (j + 1) * m] = powers[t - 1 - j] @ self._B
        self._forced = forced  # ((T+1) n, T m)
        # Unconstrained minimiser of the cost (8) over u (the states eliminated):
        # u = u^r + gain (x^r - Phi x0 - Gamma u^r), with Phi, Gamma the roll-out
        # rows of steps 1..T and gain = (Rbar + Gamma' Qbar Gamma)^-1 Gamma' Qbar,
        # Rbar = blkdiag(R), Qbar = blkdiag(Q.., Q_T). See _unconstrained_optimum.
        gamma = forced[n:]
        hessian = np.kron(np.eye(T), self._R) + gamma.T @ self._Q_block @ gamma
        self._gain = scipy.linalg.solve(hessian, gamma.T @ self._Q_block, assume_a="pos")
        self._free_steps = np.ascontiguousarray(self._free[n:])  # Phi, (T n, n)
        self._forced_steps = np.ascontiguousarray(gamma)  # Gamma, (T n, T m)
        self._u_low_all = np.tile(self._u_low, T)  # (T m,)
        # Position box in one product: [C; -C] x_t <= [y_high; -y_low] (inf: never binds).
        self._box_map = np.ascontiguousarray(np.vstack([C, -C]).T)  # (n, 2d)
        self._box_bounds = np.concatenate([self._y_high, -self._y_low])
        # [x_0..x_T; C x_1..C x_T; -C x_1..-C x_T] = evaluation_map @ [x0; u]: the
        # roll-out, the positions and the box rows in one product (see _evaluate).
        rollout = np.hstack([self._free, forced])  # ((T+1) n, n + T m)
        positions = np.kron(np.eye(T), C) @ rollout[n:]  # (T d, n + T m)
        self._evaluation_map = np.vstack([rollout, positions, -positions])
        self._box_bounds_all = np.concatenate(
            [np.tile(self._y_high, T), np.tile(-self._y_low, T)]
        )
        # Faces of the position box with a finite bound, in the QP's row order
        # (upper faces, then lower faces, by axis): their index into the (2, d)
        # array of per-face violations (see _face_violations).
        self._face_index = np.concatenate([
            np.flatnonzero(np.isfinite(self._y_high)), d + np.flatnonzero(np.isfinite(self._y_low))
        ])
        self._u_high_all = np.tile(self._u_high, T)
        self._skip_feasible_reference = False  # MPCSafetyFilter turns it on
        self._qp_solves = 0  # Clarabel calls in the last solve (MPCSafetyFilter)
        self._step_cache: Any = None  # per-step data a subclass reuses within one solve
        if brake_gain is None:
            self._brake_gain = self._braking_gain()
        else:
            self._brake_gain = finite_array("brake_gain", brake_gain, shape=(m, n))
        self._zero_inputs = np.zeros((T, m))
        self._zero_inputs.setflags(write=False)
        self._plan: np.ndarray | None = None
        self._failures = 0

    # ------------------------------------------------------------------ properties
    @property
    def horizon(self) -> int:
        """Prediction horizon ``T`` (number of steps)."""
        return self._T

    @property
    def n_obstacles(self) -> int:
        """Largest number of obstacles (halfspace rows per step) the QP holds."""
        return self._n_obstacles

    @property
    def soft(self) -> bool:
        """Whether halfspace rows are softened with an L1-penalised slack."""
        return self._soft

    @property
    def slack_penalty(self) -> float:
        """Weight :math:`\\rho` of the L1 slack penalty (soft mode), per m of violation."""
        return self._slack_penalty

    @property
    def input_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(low, high)`` of the input box, each shape ``(m,)`` (±inf: unbounded)."""
        return self._u_low.copy(), self._u_high.copy()

    @property
    def position_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(low, high)`` of the position box, each shape ``(d,)`` (±inf: unbounded)."""
        return self._y_low.copy(), self._y_high.copy()

    @property
    def last_plan(self) -> np.ndarray | None:
        """Copy of the stored last solved plan ``(T, m)``, or ``None``."""
        return None if self._plan is None else self._plan.copy()

    def reset(self) -> None:
        """Forget the stored plan and the failure count (call at episode start)."""
        self._plan = None
        self._failures = 0

    # ------------------------------------------------------------------ braking
    def _braking_gain(self) -> np.ndarray:
        r"""Gain :math:`K` of the braking input :math:`u = \mathrm{clip}(-K x)`.

        The "velocity" is the part of the state that the output map ``C`` does
        not see, :math:`v = N^\top x` with :math:`N` an orthonormal basis of
        :math:`\ker C`. Braking picks the input that brings the next velocity
        closest to zero, :math:`u = -(N^\top B)^+ N^\top A x`, clipped to the input
        box. For the double integrator (:math:`C = [I\ 0]`, ``B = [Ts²/2 I; Ts I]``)
        this is :math:`u = \mathrm{clip}(-v / T_s)`: the velocity is cancelled in one
        step if the bounds allow, else as fast as they allow, axis by axis. If ``C``
        sees the whole state there is no velocity and braking is the input
        closest to zero.
        """
        basis = scipy.linalg.null_space(self._C)
        if basis.shape[1] == 0:
            return np.zeros((self._m, self._n))
        return np.linalg.pinv(basis.T @ self._B, rcond=1e-10) @ (basis.T @ self._A)

    def braking_input(self, x: np.ndarray) -> np.ndarray:
        """Braking input at state ``x``, shape ``(m,)`` (see :meth:`_braking_gain`)."""
        return np.clip(-self._brake_gain @ x, self._u_low, self._u_high)

    # ------------------------------------------------------------------ helpers
    def _brake_from(self, x0: np.ndarray, prefix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Apply ``prefix`` then brake until the horizon; return inputs and states."""
        inputs = np.empty((self._T, self._m))
        states = np.empty((self._T + 1, self._n))
        states[0] = x0
        for t in range(self._T):
            inputs[t] = prefix[t] if t < len(prefix) else self.braking_input(states[t])
            states[t + 1] = self._A @ states[t] + self._B @ inputs[t]
        return inputs, states

    def _cost(
        self, inputs: np.ndarray, states: np.ndarray, ref_states: np.ndarray,
        ref_inputs: np.ndarray,
    ) -> float:
        du = inputs - ref_inputs
        dx = (states[1:] - ref_states).ravel()
        return float(np.sum((du @ self._R) * du) + dx @ (self._Q_block @ dx))

    def _violations(
        self, states: np.ndarray, normals: np.ndarray, offsets: np.ndarray
    ) -> tuple[np.ndarray, float]:
        """Halfspace violations ``(k, T)`` and the largest position-box violation."""
        signed = states[1:] @ self._box_map  # (T, 2d): [C x_t, -C x_t]
        box = float((signed - self._box_bounds).max())
        halfspace = np.einsum("ktd,td->kt", normals, signed[:, : self._d]) - offsets
        return halfspace, box

    def _evaluate(
        self, x0: np.ndarray, inputs: np.ndarray, normals: np.ndarray, offsets: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
        """Roll-out ``(T + 1, n)``, halfspace violations ``(k, T)``, largest box violation.

        The fourth value is the box violation of every row, shape ``(2, T, d)``
        (upper faces, then lower faces; ``-inf`` for an infinite bound).

        Same numbers as rolling out and calling :meth:`_violations` (to rounding),
        in five NumPy calls instead of about ten: each small NumPy call costs 1-3 us
        here, more than its arithmetic.
        """
        T, n, d = self._T, self._n, self._d
        out = self._evaluation_map @ np.concatenate((x0, inputs.reshape(-1)))
        split = (T + 1) * n
        excess = out[split:] - self._box_bounds_all
        box = float(np.maximum.reduce(excess))
        halfspace = _vecdot(normals, out[split : split + T * d].reshape(T, d)) - offsets
        return out[:split].reshape(T + 1, n), halfspace, box, excess.reshape(2, T, d)

    def _face_violations(self, excess: np.ndarray) -> np.ndarray:
        """Largest violation of each finite face of the position box, in row order."""
        return np.maximum.reduce(excess, axis=1).reshape(-1)[self._face_index]

    def _missed_rows(
        self, relaxed: tuple[bool, np.ndarray, np.ndarray], raw_inputs: np.ndarray,
        inputs: np.ndarray, halfspace: np.ndarray, box: float, excess: np.ndarray,
    ) -> tuple[bool, np.ndarray, np.ndarray] | None:
        """Rows to add to a QP that left some out, or ``None`` if it missed none.

        ``relaxed`` says what the QP included (input box, position-box faces,
        obstacles); ``raw_inputs`` is its answer, ``inputs`` the same clipped to the
        input box (they differ exactly where the input box is violated);
        ``halfspace``, ``box`` and ``excess`` the violations of the roll-out (see
        :meth:`_evaluate`). A left-out row counts as missed if it is violated at
        all (no tolerance; NaN counts too).
        """
        with_input, faces, near = relaxed
        input_hit = not with_input and bool((raw_inputs != inputs).any())
        face_hit = None
        if not box <= 0.0 and not faces.all():
            face_hit = ~faces & ~(self._face_violations(excess) <= 0.0)
        k = halfspace.shape[0]
        hit = None
        if k and not near[:k].all():
            far_hit = ~near[:k]
            far_hit &= ~(np.maximum.reduce(halfspace, axis=1) <= 0.0)
            if far_hit.any():
                hit = near.copy()
                hit[:k] |= far_hit
        if input_hit or hit is not None or (face_hit is not None and face_hit.any()):
            return (
                with_input or input_hit,
                faces if face_hit is None else faces | face_hit,
                near if hit is None else hit,
            )
        return None

    def _unconstrained_optimum(
        self, x0: np.ndarray, ref_states: np.ndarray, ref_inputs: np.ndarray,
        normals: np.ndarray, offsets: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray] | None:
        r"""The minimiser of the cost (8) without constraints, if it meets them all.

        With the states eliminated the cost is the strictly convex quadratic
        (``R`` is positive definite) :math:`\|u - u^r\|^2_{\bar R} + \|\Phi x_0 +
        \Gamma u - x^r\|^2_{\bar Q}`, minimised without constraints by
        :math:`u^\circ = u^r + (\bar R + \Gamma^\top \bar Q \Gamma)^{-1}
        \Gamma^\top \bar Q (x^r - \Phi x_0 - \Gamma u^r)` (one matrix-vector
        product with a gain computed at construction). If :math:`u^\circ` and its
        roll-out meet every constraint (input box, position box, every
        halfspace, with zero tolerance) it is *the* optimum of Problem 2: no
        feasible point has a lower cost, and the minimiser is unique. A reference
        whose inputs generate its states from ``x0`` gives a zero residual, hence
        :math:`u^\circ = u^r` (to rounding) with cost 0: a safe, consistent
        reference passes through unchanged, without the interior-point bias.

        Returns ``(inputs (T, m), states (T + 1, n))`` or ``None`` (some
        constraint is violated, or a NaN appeared: the QP decides then).
        """
        u_ref = ref_inputs.reshape(-1)
        residual = ref_states.reshape(-1) - self._free_steps @ x0
        residual -= self._forced_steps @ u_ref
        inputs = u_ref + self._gain @ residual
        if not (np.all(inputs >= self._u_low_all) and np.all(inputs <= self._u_high_all)):
            return None  # (also for NaN)
        states, halfspace, box, _ = self._evaluate(x0, inputs, normals, offsets)
        if not (box <= 0.0 and np.maximum.reduce(halfspace, axis=None, initial=-np.inf) <= 0.0):
            return None
        return inputs.reshape(self._T, self._m), states

    # ------------------------------------------------------------------ the step
    def solve(
        self,
        x0: np.ndarray,
        reference_states: np.ndarray,
        halfspaces: object = None,
        *,
        reference_inputs: np.ndarray | None = None,
    ) -> FilterResult:
        r"""Filter a reference trajectory: solve Problem 2, or fall back.

        Parameters
        ----------
        x0
            Current state :math:`x_0`, shape ``(n,)`` (m and m/s for the ego).
        reference_states
            Reference trajectory, shape ``(T + 1, n)``. Row 0 is the reference at
            the current time and is ignored (the plan starts from ``x0``); rows
            ``1..T`` are :math:`x^r_1, \dots, x^r_T`.
        halfspaces
            Safe halfspaces, safe side ``normals[i, t-1] @ (C x_t) <= offsets[i, t-1]``:
            an object with ``.normals`` ``(k, T, d)`` and ``.offsets`` ``(k, T)`` (as
            returned by :func:`filters.safe_halfspaces`), a pair ``(normals, offsets)``,
            or ``None`` for no obstacle. ``k`` may be smaller than ``n_obstacles``;
            the unused rows are disabled.
        reference_inputs
            Reference inputs :math:`u^r_0, \dots, u^r_{T-1}`, shape ``(T, m)``.
            Default zeros (the paper's :math:`u^\top R u`). With inputs that generate
            ``reference_states`` from ``x0`` and respect every constraint, the
            reference passes through unchanged: exactly (to rounding) with
            ``skip_feasible_reference`` (the default), else up to the
            interior-point bias away from nearly active rows, which shrinks with
            the margin to the nearest row: measured below 1e-7 (in input units)
            at 1 mm, 1e-9 at 10 cm.

        Returns
        -------
        FilterResult
            Never a failure: an infeasible or failed QP gives ``SHIFTED`` or
            ``BRAKE`` (see the module docstring).

        Raises
        ------
        InvalidArrayError
            If an argument has the wrong shape or a NaN/infinite entry, or if more
            than ``n_obstacles`` halfspace rows are given.
        InvalidTypeError
            If ``halfspaces`` has an unsupported type.
        """
        start = time.perf_counter()
        T, n, m = self._T, self._n, self._m
        x0 = _finite("x0", x0, (n,))
        ref_states = _finite("reference_states", reference_states, (T + 1, n))[1:]
        if reference_inputs is None:
            ref_inputs = self._zero_inputs
        else:
            ref_inputs = _finite("reference_inputs", reference_inputs, (T, m))
        normals, offsets = parse_halfspaces(halfspaces, T, self._d, self._n_obstacles)
        k = normals.shape[0]
        self._qp_solves = 0
        self._step_cache = None
        if self._skip_feasible_reference and reference_inputs is not None:
            optimum = self._unconstrained_optimum(x0, ref_states, ref_inputs, normals, offsets)
            if optimum is not None:
                inputs, states = optimum
                self._plan = inputs
                self._failures = 0
                return self._result(
                    FilterStatus.OPTIMAL, inputs, states,
                    np.zeros((k, T)) if self._soft else None, _NO_QP, _NO_QP.solver_status,
                    self._cost(inputs, states, ref_states, ref_inputs), start,
                )
        if k == self._n_obstacles:
            padded_normals, padded_offsets = normals, offsets
        else:  # unused rows read 0 @ y <= DISABLED_OFFSET
            padded_normals = np.zeros((self._n_obstacles, T, self._d))
            padded_offsets = np.full((self._n_obstacles, T), DISABLED_OFFSET)
            padded_normals[:k] = normals
            padded_offsets[:k] = offsets

        attempt = self._solve_qp(x0, ref_states, ref_inputs, padded_normals, padded_offsets)
        while True:  # more than once only if a QP with rows left out missed one
            solver_status = attempt.solver_status
            inputs = attempt.inputs
            usable = attempt.solved and inputs is not None and _all_finite(inputs)
            if not usable:
                break
            raw_inputs = inputs
            inputs = np.minimum(np.maximum(inputs, self._u_low), self._u_high)  # IPM: ~1e-9 out
            states, halfspace, box, excess = self._evaluate(x0, inputs, normals, offsets)
            if attempt.relaxed is None:
                break
            include = self._missed_rows(
                attempt.relaxed, raw_inputs, inputs, halfspace, box, excess
            )
            if include is None:
                break
            again = self._solve_qp(
                x0, ref_states, ref_inputs, padded_normals, padded_offsets, include=include
            )
            attempt = again._replace(
                iterations=attempt.iterations + again.iterations,
                solve_time=attempt.solve_time + again.solve_time,
            )
        if usable:
            slack = None
            if self._soft:
                raw = attempt.slack[:k] if attempt.slack is not None else np.zeros((k, T))
                slack = np.where(raw > SLACK_TOLERANCE, raw, 0.0)
                halfspace = halfspace - np.maximum(raw, 0.0)
            worst = max(box, float(np.maximum.reduce(halfspace, axis=None))) if k else box
            if worst <= FEASIBILITY_TOLERANCE:  # False for NaN too
                self._plan = inputs  # read-only from here on (see _result)
                self._failures = 0
                status = FilterStatus.OPTIMAL
                if self._soft and slack is not None and slack.any():
                    status = FilterStatus.SOFT
                objective = attempt.objective
                if not math.isfinite(objective):
                    objective = self._cost(inputs, states, ref_states, ref_inputs)
                    if slack is not None:
                        objective += self._slack_penalty * float(slack.sum())
                return self._result(
                    status, inputs, states, slack, attempt, solver_status, objective, start
                )
            solver_status = (
                f"{solver_status} (rejected: constraint violation {worst:.3g} > "
                f"{FEASIBILITY_TOLERANCE:g})"
            )
        elif attempt.solved:
            solver_status = f"{solver_status} (rejected: non-finite solution)"

        # Fallback: the paper's shifted plan, then braking.
        self._failures += 1
        shift = self._failures
        if self._plan is not None and shift <= T - 1:
            status = FilterStatus.SHIFTED
            inputs, states = self._brake_from(x0, self._plan[shift:])
        else:
            status = FilterStatus.BRAKE
            inputs, states = self._brake_from(x0, np.zeros((0, m)))
        slack = None
        if self._soft:
            halfspace, _ = self._violations(states, normals, offsets)
            slack = np.maximum(halfspace, 0.0)
            slack = np.where(slack > SLACK_TOLERANCE, slack, 0.0)
        objective = self._cost(inputs, states, ref_states, ref_inputs)
        return self._result(
            status, inputs, states, slack, attempt, solver_status, objective, start
        )

    def _result(
        self, status: FilterStatus, inputs: np.ndarray, states: np.ndarray,
        slack: np.ndarray | None, attempt: _QPAttempt, solver_status: str,
        objective: float, start: float,
    ) -> FilterResult:
        for array in (inputs, states, slack):
            if array is not None:
                array.setflags(write=False)
        return FilterResult(
            status=status,
            inputs=inputs,
            states=states,
            solve_time=attempt.solve_time,
            total_time=time.perf_counter() - start,
            slack=slack,
            solver_status=solver_status,
            iterations=attempt.iterations,
            objective=objective,
            consecutive_failures=self._failures,
        )

    def _solve_qp(
        self, x0: np.ndarray, ref_states: np.ndarray, ref_inputs: np.ndarray,
        normals: np.ndarray, offsets: np.ndarray, include: tuple | None = None,
    ) -> _QPAttempt:  # pragma: no cover - abstract
        """Solve Problem 2 for the (padded) data; ``include``: see MPCSafetyFilter."""
        raise NotImplementedError


# --------------------------------------------------------------------------- Clarabel
class MPCSafetyFilter(_SafetyFilterBase):
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

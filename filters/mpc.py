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
* **Sparse, not condensed.** The decision vector holds the inputs and the
  states, :math:`(u_0, \dots, u_{T-1}, x_1, \dots, x_T[, s])`, and the dynamics
  are equality rows. Measured on the target size (T = 10, n = 4, m = 2, three
  obstacles) with Clarabel 0.11: the sparse form (KKT system of size 210) needs
  fewer interior-point iterations than the condensed one (KKT size 130, but a
  dense constraint block): about 6 vs 9 without equilibration, 8 vs 11.5 with,
  and each of its iterations is no dearer (about 35 us here).
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


# --------------------------------------------------------------------------- validation
def _finite(name: str, value: object, shape: tuple[int, ...]) -> np.ndarray:
    """Fast path of :func:`finite_array` for the per-step arrays (same errors)."""
    if isinstance(value, np.ndarray) and value.dtype == np.float64:
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
    def _rollout(self, x0: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """States ``(T + 1, n)`` from ``x0`` under ``inputs`` (exact dynamics)."""
        states = self._free @ x0 + self._forced @ inputs.ravel()
        return states.reshape(self._T + 1, self._n)

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
        positions = states[1:] @ self._C.T  # (T, d)
        halfspace = (normals * positions).sum(axis=-1) - offsets
        box = max((self._y_low - positions).max(), (positions - self._y_high).max())
        return halfspace, float(box)

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
            reference passes through unchanged, up to the interior-point bias away
            from nearly active rows, which shrinks with the margin to the nearest
            row: measured below 1e-7 (in input units) at 1 mm, 1e-9 at 10 cm.

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
        if k == self._n_obstacles:
            padded_normals, padded_offsets = normals, offsets
        else:  # unused rows read 0 @ y <= DISABLED_OFFSET
            padded_normals = np.zeros((self._n_obstacles, T, self._d))
            padded_offsets = np.full((self._n_obstacles, T), DISABLED_OFFSET)
            padded_normals[:k] = normals
            padded_offsets[:k] = offsets

        attempt = self._solve_qp(x0, ref_states, ref_inputs, padded_normals, padded_offsets)
        solver_status = attempt.solver_status
        inputs = attempt.inputs
        if attempt.solved and inputs is not None and np.isfinite(inputs).all():
            inputs = np.minimum(np.maximum(inputs, self._u_low), self._u_high)  # IPM: ~1e-9 out
            states = self._rollout(x0, inputs)
            halfspace, box = self._violations(states, normals, offsets)
            slack = None
            if self._soft:
                raw = attempt.slack[:k] if attempt.slack is not None else np.zeros((k, T))
                slack = np.where(raw > SLACK_TOLERANCE, raw, 0.0)
                halfspace = halfspace - np.maximum(raw, 0.0)
            worst = max(box, halfspace.max()) if k else box
            if worst <= FEASIBILITY_TOLERANCE:  # False for NaN too
                self._plan = inputs.copy()
                self._failures = 0
                status = FilterStatus.OPTIMAL
                if self._soft and slack is not None and slack.any():
                    status = FilterStatus.SOFT
                objective = attempt.objective
                if not np.isfinite(objective):
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
        normals: np.ndarray, offsets: np.ndarray,
    ) -> _QPAttempt:  # pragma: no cover - abstract
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
        not a pair, ...).

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
    ) -> None:
        super().__init__(
            A, B, C, horizon=horizon, Q=Q, Q_terminal=Q_terminal, R=R,
            input_bounds=input_bounds, position_bounds=position_bounds,
            n_obstacles=n_obstacles, soft=soft, slack_penalty=slack_penalty,
            brake_gain=brake_gain,
        )
        self._settings = _solver_settings(solver_settings, soft=self._soft)
        self._build()

    # ------------------------------------------------------------------ build once
    def _build(self) -> None:
        r"""Assemble :math:`P, q, A, b` and the cones with a fixed sparsity pattern.

        Variables ``z = (u_0..u_{T-1}, x_1..x_T, s)``, solved for as deviations
        from the reference (see :meth:`_solve_qp`; the matrix is the same, only
        ``b`` shifts); rows: dynamics (zero cone), then input box, position box,
        halfspaces and (soft) ``-s <= 0``, all in the nonnegative cone (Clarabel's
        form is :math:`A z + s = b`, :math:`s \in K`). The right-hand side built here
        is the constant part; :meth:`_solve_qp` writes the rest at every step.
        """
        T, n, m, d, K = self._T, self._n, self._m, self._d, self._n_obstacles
        nu, nx = T * m, T * n
        ns = K * T if self._soft else 0
        nv = nu + nx + ns
        self._nu, self._nx, self._ns = nu, nx, ns

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
        self._hs_row0 = row
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
        n_rows = row

        rows_all = np.concatenate(rows).astype(np.int64)
        cols_all = np.concatenate(cols).astype(np.int64)
        vals_all = np.concatenate(vals)
        # Build the CSC pattern with entry ids as values (never zero, so nothing is
        # dropped), then read where each entry landed in the CSC data array.
        ids = np.arange(1, len(rows_all) + 1, dtype=np.float64)
        pattern = sp.csc_matrix((ids, (rows_all, cols_all)), shape=(n_rows, nv))
        pattern.sort_indices()
        if pattern.nnz != len(rows_all):  # pragma: no cover - construction bug
            raise RuntimeError("duplicate entries in the constraint pattern")
        entry = pattern.data.astype(np.int64) - 1  # CSC position -> entry index
        constraint = sp.csc_matrix(
            (vals_all[entry], pattern.indices.copy(), pattern.indptr.copy()),
            shape=(n_rows, nv),
        )
        # Halfspace entries (without the soft -1): CSC positions and (i, t, j) of a_it' C.
        position = np.empty(len(entry), dtype=np.int64)
        position[entry] = np.arange(len(entry))
        hs_i_all = np.concatenate(hs_i) if hs_i else np.zeros(0, dtype=np.int64)
        hs_t_all = np.concatenate(hs_t) if hs_t else np.zeros(0, dtype=np.int64)
        hs_j_all = np.concatenate(hs_j) if hs_j else np.zeros(0, dtype=np.int64)
        keep = hs_i_all >= 0
        self._hs_positions = position[np.arange(hs_first, hs_last)[keep]]
        # flat index into (normals @ C) of shape (K, T, n)
        self._hs_flat = (hs_i_all[keep] * T + hs_t_all[keep]) * n + hs_j_all[keep]

        # Cost: 1/2 z' P z + q' z with P = 2 blkdiag(R.., Q.., Q_T, 0).
        blocks = [2.0 * self._R] * T + [2.0 * Qt for Qt in self._Q_stack]
        if ns:
            blocks.append(sp.csc_matrix((ns, ns)))
        P = sp.triu(sp.block_diag(blocks, format="csc"), format="csc")
        P.sort_indices()
        q = np.zeros(nv)  # constant: deviation coordinates, see _solve_qp
        q[nu + nx :] = self._slack_penalty
        self._b_const = np.concatenate(b)  # bounds; 0 for dynamics; 1 for halfspaces
        self._b = self._b_const.copy()
        # Rows before the halfspaces do not depend on the normals: their right-hand
        # side in deviation coordinates is b_const - G [u^r; x^r] (+ A x0).
        self._G_fixed = constraint[: self._hs_row0, : nu + nx].toarray()
        self._reference = np.zeros(nu + nx)
        cones = [clarabel.ZeroConeT(n_equalities)]
        if n_rows > n_equalities:
            cones.append(clarabel.NonnegativeConeT(n_rows - n_equalities))
        self._solver = clarabel.DefaultSolver(
            P, q, constraint, self._b_const, cones, self._settings
        )
        if not self._solver.is_data_update_allowed():  # pragma: no cover - settings checked
            raise InvalidParameterError(
                "solver_settings disable Clarabel's data updates; keep presolve off"
            )
        self._shape = (n_rows, nv)

    # ------------------------------------------------------------------ update and solve
    def _solve_qp(
        self, x0: np.ndarray, ref_states: np.ndarray, ref_inputs: np.ndarray,
        normals: np.ndarray, offsets: np.ndarray,
    ) -> _QPAttempt:
        r"""Solve in deviation coordinates :math:`w = u - u^r`, :math:`e = x - x^r`.

        The cost (8) becomes :math:`\sum w_t^\top R w_t + \sum e_t^\top Q_t e_t`
        with no linear term, so ``q`` never changes and Clarabel's objective *is*
        the filter's cost. (With ``u``, ``x`` as variables the objective is the cost
        minus the constant :math:`\sum x^{r\top} Q x^r`, often 100x larger than the
        cost itself, and the relative gap tolerance would then be 100x looser on
        the cost: measured input errors up to 6e-4 instead of 5e-6.) Only ``b``
        (references, ``x0``, offsets) and the halfspace entries of ``A`` change.
        """
        nu, nx, n, hs0 = self._nu, self._nx, self._n, self._hs_row0
        reference = self._reference
        reference[:nu] = ref_inputs.ravel()
        reference[nu:] = ref_states.ravel()
        b = self._b
        b[:hs0] = self._b_const[:hs0] - self._G_fixed @ reference
        b[:n] += self._A @ x0
        if normals.shape[0]:
            positions = ref_states @ self._C.T  # reference positions, (T, d)
            b[hs0 : hs0 + normals.shape[0] * self._T] = (
                offsets - (normals * positions).sum(axis=-1)
            ).ravel()
        a_values = (normals @ self._C).ravel()[self._hs_flat]
        try:
            self._solver.update(b=b, A=(self._hs_positions, a_values))
            begin = time.perf_counter()
            solution = self._solver.solve()
            solve_time = time.perf_counter() - begin
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as exc:  # pyo3 panics derive from BaseException
            return _QPAttempt(None, None, f"exception: {exc!r}", 0, 0.0, False)
        status = str(solution.status)
        z = np.asarray(solution.x)
        inputs = None
        if len(z) == self._shape[1]:
            inputs = z[:nu].reshape(self._T, self._m) + ref_inputs
        slack = None
        if self._soft and inputs is not None:
            slack = z[nu + nx :].reshape(self._n_obstacles, self._T)
        return _QPAttempt(
            inputs, slack, status, int(solution.iterations), solve_time, status in _SOLVED,
            float(solution.obj_val),  # the cost (8) itself, in deviation coordinates
        )

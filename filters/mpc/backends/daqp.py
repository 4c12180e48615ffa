r"""DAQP back end: the whitened condensed QP of an :class:`~filters.mpc.MPCProblem`.

DAQP (Arnström, Bemporad and Axehill, IEEE TAC 2022) is a dual active-set solver in
C. It solves the condensed QP of :mod:`filters.mpc.condensed` in whitened variables
:math:`z = U^\top u` (identity Hessian): the input box, the arena and the terminal rows
are constant rows, the halfspace rows :math:`a_{i,t}^\top W_t z` are written per step.
With an identity Hessian DAQP uses the rows as given, so the per-step work is linear
in the number of rows times :math:`T m` (a dense Hessian costs :math:`(T m)^2` per row).

**Lazy (screened) rows, exact** (``lazy=True``; the default for ``T m >``
:data:`LAZY_MIN_INPUTS`). A long horizon has hundreds to thousands of rows, and a dual
active-set method scans all of them at every iteration, while only tens are active. So:

1. screen: keep the rows whose excess ``lhs - rhs`` at the unconstrained minimiser
   :math:`z^\circ = -f_z`, or at the previous answer shifted by one step, is above
   ``-SCREEN_MARGIN``;
2. solve the QP with the kept rows only (the *relaxed* QP);
3. evaluate every row at its answer (one matrix-vector product, see
   :meth:`~filters.mpc.condensed.CondensedQP.excess`); add the violated ones and
   solve again, until none is violated.

This is exact, not a heuristic. The relaxed QP has fewer rows, so its optimal cost is
at most the full QP's; an answer that meets every row is feasible for the full QP
with that cost, hence optimal (the QP is strictly convex: *the* optimum). If the
relaxed hard QP is infeasible, so is the full one. For soft rows (the recovery QP,
``soft=True``) the same holds: a dropped soft row that the answer meets costs no
penalty. Every round adds at least one row, so the loop ends.

**Warm start** (until :meth:`DAQPBackend.reset`, which the filter calls at episode
start). In a closed loop the next step's QP is the last one shifted by one step, so
the lazy path keeps (a) the previous answer, shifted, as a second screening point;
(b) its active set, shifted (the rows of step :math:`t+1` become those of step
:math:`t`, the last step keeps its own), which enters the first relaxed QP and starts
DAQP there (``dual_start``); (c) after an infeasible QP, its rows, shifted, which
usually contain the next step's conflict, so a run of infeasible steps is detected
in one round. Each round starts from the previous round's active set. None of this
changes the answer (the optimum of a strictly convex QP), only the work: on the
scaling grid's T = 80 steps a warm start halved DAQP's iterations, and (c) cut an
infeasible step's from hundreds to a median of 4-25.

**Soft rows** (``soft=True``, and the recovery QP) are DAQP's soft constraints
(sense 8) with the linear weight :math:`w = \rho` (``slack_penalty``) on each side and
the reciprocal quadratic weight ``SOFT_RHO``: a violation :math:`s \ge 0` of a soft row
costs :math:`\rho s + s^2 / (2\,\mathrm{SOFT\_RHO})`, the exact L1 penalty of the
other back ends up to :math:`5 \cdot 10^{-7} s^2`. No slack variables are added; the
slacks reported are the violations of the returned inputs. Checked against the CVXPY
reference on the test instances: DAQP's penalised objective was never above CVXPY's
(``SOFT_RHO`` = 1e4 or 1e6; 1e8 and more lost up to 2e3 in it, numerically).

Soft QPs with many violated rows are where an active-set method is slow: each violated
row enters the active set, one per iteration, and DAQP's dual has them bounded by
:math:`\rho`. With hundreds of violated rows (long horizons, strongly infeasible
steps) an interior-point method is faster, which is why ``backend="auto"`` solves the
soft QPs of long horizons with Clarabel (:func:`filters.mpc.filter.auto_backend`).

**Statuses.** DAQP's exit flags are reported with Clarabel's names where one exists
(``1``, ``2`` -> ``"Solved"``, ``-1`` -> ``"PrimalInfeasible"``, ``-4`` ->
``"MaxIterations"``), so that the filter's statuses and fallbacks read the same for
every back end; other flags read ``"daqp exitflag N"``.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import daqp
import numpy as np

from filters.errors import InvalidParameterError, InvalidTypeError
from filters.mpc._linalg import matvec_operator
from filters.mpc.condensed import CondensedQP, StepRows
from filters.mpc.problem import MPCProblem
from filters.mpc.result import QPSolution, StepData

__all__ = [
    "ADD_TOLERANCE",
    "LAZY_MIN_INPUTS",
    "SCREEN_MARGIN",
    "SOFT_RHO",
    "DAQPBackend",
    "daqp_settings",
]

#: DAQP exit flags by the Clarabel status name the filter reports for them.
_STATUS = {1: "Solved", 2: "Solved", -1: "PrimalInfeasible", -4: "MaxIterations"}
#: Reciprocal quadratic weight of the soft rows (see the module docstring).
SOFT_RHO = 1e6
#: ``lazy=None`` screens the rows when the condensed QP has more than this many inputs.
LAZY_MIN_INPUTS = 40
#: Rows whose excess at the screening points is above ``-SCREEN_MARGIN`` (m, or m/s²
#: for input rows) enter the first relaxed QP.
SCREEN_MARGIN = 0.25
#: A dropped row violated by more than this (same units) at a relaxed answer is added.
ADD_TOLERANCE = 1e-9


def daqp_settings(overrides: Mapping[str, Any] | None) -> dict[str, Any]:
    """DAQP settings of the filter's QPs: DAQP's defaults with ``overrides`` applied.

    Raises
    ------
    InvalidTypeError
        If ``overrides`` is not a mapping.
    InvalidParameterError
        On an unknown setting (the keys of ``daqp.Model().settings``).
    """
    known = daqp.Model().settings
    if overrides is None:
        return {}
    if not isinstance(overrides, Mapping):
        raise InvalidTypeError(
            f"solver_settings must be a mapping of DAQP settings, got {overrides!r}"
        )
    for key in overrides:
        if key not in known:
            raise InvalidParameterError(
                f"solver_settings: unknown DAQP setting {key!r} (known: {sorted(known)})"
            )
    return dict(overrides)


class DAQPBackend:
    """The whitened condensed QP of one :class:`~filters.mpc.MPCProblem`, solved by DAQP.

    Parameters
    ----------
    problem
        What to build (its ``soft_rows`` are DAQP soft constraints).
    solver_settings
        DAQP settings to override (see :func:`daqp_settings`).
    warm_start
        Without ``lazy``: start each solve from the previous solve's active set
        (default ``False``: every solve starts from the empty active set, so a used model
        returns bit for bit what a fresh one returns).
    lazy
        Screen the rows (module docstring); ``None`` (default): when ``T m >``
        :data:`LAZY_MIN_INPUTS`. With ``lazy``, the previous answer, shifted by one step,
        is a second screening point until :meth:`reset`.
    Raises
    ------
    InvalidParameterError
        If a setting is unknown or has a value DAQP refuses.
    """

    name = "daqp"

    def __init__(
        self, problem: MPCProblem, *, solver_settings: Mapping[str, Any] | None = None,
        warm_start: bool = False, lazy: bool | None = None,
    ) -> None:
        self.problem = problem
        self._settings = daqp_settings(solver_settings)
        self._warm_start = bool(warm_start)
        self.qp = CondensedQP(problem)
        nu = self.qp.nu
        self.lazy = nu > LAZY_MIN_INPUTS if lazy is None else bool(lazy)
        self._identity = np.eye(nu)
        self._build()

    # ------------------------------------------------------------------ set-up
    def _build(self) -> None:
        qp, p = self.qp, self.problem
        T, K, nu, n_fixed = qp.T, qp.K, qp.nu, qp.n_fixed
        self._soft_fixed = qp.fixed_soft
        self._soft_hs = p.soft_halfspaces
        self._soft_bounds = bool(self._soft_fixed.any())  # once here, not per soft solve
        self._any_soft = self._soft_bounds or bool(self._soft_hs and K)
        self._guess: tuple | None = None  # previous answer and active set (lazy), until reset()
        self._conflict: tuple | None = None  # rows of the previous infeasible QP (lazy)
        self.rounds = 0  # relaxed QPs solved by the last lazy solve
        self._z_of_u = matvec_operator(qp.z_of_u)
        if self.lazy:
            self._model = daqp.Model()
            try:  # a bad setting raises now, not at every step
                if self._settings:
                    self._model.settings = self._settings
            except (TypeError, ValueError) as exc:
                raise InvalidParameterError(
                    f"solver_settings: DAQP refused {self._settings!r}: {exc}") from exc
            return
        # Every row, every step: [fixed rows; halfspace rows step-major].
        self._A = np.zeros((n_fixed + K * T, nu))
        self._A[:n_fixed] = qp.fixed_rows
        self._A_hs = self._A[n_fixed:].reshape(T, K, nu)  # a view: written in place
        self._upper = np.full(n_fixed + K * T, np.inf)
        self._lower = np.full(n_fixed + K * T, -np.inf)
        self._upper_hs = self._upper[n_fixed:].reshape(T, K)
        soft = np.concatenate([self._soft_fixed, np.full(K * T, self._soft_hs)])
        self._sense = np.where(soft, 8, 0).astype(np.intc)
        self._soft_weights = None
        if soft.any():
            self._soft_weights = (np.full(len(soft), SOFT_RHO),
                                  np.full(len(soft), p.slack_penalty))
        self._cold = True
        try:
            model = self._new_model()
        except (TypeError, ValueError) as exc:
            raise InvalidParameterError(
                f"solver_settings: DAQP refused {self._settings!r}: {exc}") from exc
        self._model = None if isinstance(model, int) else model

    def _new_model(self) -> daqp.Model | int:
        """A DAQP model of every row set up with placeholder data (zero halfspace rows,
        ``f = 0``), or DAQP's negative setup flag. Every solve, the first included, then
        writes its data by ``update``: a used model returns bit for bit what a fresh one
        returns (setup and update differ in the last bits)."""
        model = daqp.Model()
        if self._settings:
            model.settings = self._settings
        A = self._A.copy()
        A[self.qp.n_fixed :] = 0.0
        upper, lower = np.full(len(self._upper), np.inf), np.full(len(self._lower), -np.inf)
        f = np.zeros(self.qp.nu)
        flag, _ = model.setup(self._identity, f, A, upper, lower, self._sense.copy())
        self._setup_arrays = (f, A, upper, lower)  # kept alive with the model
        if flag >= 0 and self._soft_weights is not None:
            rho, w = self._soft_weights
            model.soft_weights(rho_l=rho, rho_u=rho, w_l=w, w_u=w)
        return int(flag) if flag < 0 else model

    def reset(self) -> None:
        """Forget the previous step (the lazy path's warm start)."""
        self._guess = None
        self._conflict = None

    # ------------------------------------------------------------------ solve
    def solve(self, step: StepData) -> QPSolution:
        """Write the step's data, solve; never raises on a failed solve."""
        try:
            rows = self.qp.step_rows(step.x0, step.ref_states, step.ref_inputs,
                                     step.normals, step.offsets)
            if self.lazy:
                return self._solve_lazy(rows)
            return self._solve_full(rows)
        except (KeyboardInterrupt, SystemExit):
            raise
        except Exception as exc:
            self.drop_model()
            return QPSolution(False, f"exception: {exc!r}")

    def _solve_full(self, rows: StepRows) -> QPSolution:
        n_fixed = self.qp.n_fixed
        if self.qp.K:
            np.matmul(rows.normals, self.qp.position_maps, out=self._A_hs)
            self._upper_hs[...] = rows.hs_upper
        self._upper[:n_fixed] = rows.upper
        self._lower[:n_fixed] = rows.lower
        x, status, flag, iterations, solve_time = self.solve_written(rows.f)
        if x is None:  # DAQP refused the setup
            return QPSolution(False, status, solve_time=solve_time)
        return self._solution(x, flag, iterations, solve_time, rows)

    @property
    def settings(self) -> dict[str, Any]:
        """The DAQP settings of this back end's models (DAQP's defaults, overridden)."""
        return {**daqp.Model().settings, **self._settings}

    def solve_written(self, f: np.ndarray) -> tuple[np.ndarray | None, str, int, int, float]:
        """DAQP on the rows written in the full model's buffers and the linear cost ``f``
        (``lazy=False``).

        Returns ``(z, status, exitflag, iterations, solve_time)``: ``z`` the whitened
        answer (meaningful when ``exitflag >= 1``), ``status`` the name the filter reports.
        A model that DAQP refuses to set up gives ``(None, "daqp setup exitflag N", N, 0,
        t)``. Raises what DAQP raises (:meth:`solve` turns that into a failed solve; see
        :meth:`drop_model`).
        """
        begin = time.perf_counter()
        if self._model is None:
            model = self._new_model()
            if isinstance(model, int):
                return (None, f"daqp setup exitflag {model}", model, 0,
                        time.perf_counter() - begin)
            self._model = model
        if self._cold or not self._warm_start:
            self._model.update(f=f, A=self._A, bupper=self._upper, blower=self._lower,
                               sense=self._sense)
        else:
            self._model.update(f=f, A=self._A, bupper=self._upper, blower=self._lower)
        x, _, flag, info = self._model.solve()
        solve_time = time.perf_counter() - begin
        flag = int(flag)
        self._cold = flag < 1
        return (x, _STATUS.get(flag, f"daqp exitflag {flag}"), flag,
                int(info.get("iterations", 0)), solve_time)

    def drop_model(self) -> None:
        """Forget the DAQP model (after an exception): the next solve sets up a new one."""
        self._model, self._cold = None, True

    def _solve_lazy(self, rows: StepRows) -> QPSolution:
        qp = self.qp
        z = -rows.f
        fixed, halfspace, values = qp.excess(z, rows)
        keep_fixed, keep_hs = fixed > -SCREEN_MARGIN, halfspace > -SCREEN_MARGIN
        dual_fixed = dual_hs = None
        if self._guess is not None:  # the previous answer and active set, shifted one step
            guess, active_fixed, active_hs = self._guess
            shifted = np.concatenate((guess[qp.m :], guess[-qp.m :]))
            at_guess, hs_at_guess, _ = qp.excess(self._z_of_u @ shifted, rows)
            keep_fixed |= at_guess > -SCREEN_MARGIN
            keep_hs |= hs_at_guess > -SCREEN_MARGIN
            dual_fixed, dual_hs = self._shift_fixed(active_fixed), _shift_steps(active_hs)
            keep_fixed |= dual_fixed != 0.0
            keep_hs |= dual_hs != 0.0
        if self._conflict is not None:  # the rows of the previous infeasible QP, shifted
            keep_fixed |= self._shift_fixed(self._conflict[0])
            keep_hs |= _shift_steps(self._conflict[1])
        self._conflict = None
        begin = time.perf_counter()
        iterations, flag = 0, 1
        self.rounds = 0
        while keep_fixed.any() or keep_hs.any():
            self.rounds += 1
            flag, z, its, dual_fixed, dual_hs = self._solve_relaxed(
                rows, keep_fixed, keep_hs, dual_fixed, dual_hs)
            iterations += its
            if flag < 1:
                # An infeasible QP's rows hold its conflict; in a closed loop the next
                # step's QP usually has the same one, found in one round with them.
                self._conflict = (keep_fixed, keep_hs) if flag == -1 else None
                return self._solution(None, flag, iterations, time.perf_counter() - begin, rows)
            fixed, halfspace, values = qp.excess(z, rows)
            add_fixed = (fixed > ADD_TOLERANCE) & ~keep_fixed
            add_hs = (halfspace > ADD_TOLERANCE) & ~keep_hs
            if not (add_fixed.any() or add_hs.any()):
                break
            keep_fixed |= add_fixed
            keep_hs |= add_hs
        else:  # nothing screened in: the unconstrained minimiser meets every row
            dual_fixed, dual_hs = np.zeros(qp.n_fixed), np.zeros((qp.T, qp.K))
        solution = self._solution(z, flag, iterations, time.perf_counter() - begin, rows,
                                  (fixed, halfspace, values))
        self._guess = (solution.inputs.reshape(-1), dual_fixed, dual_hs)
        return solution

    def _shift_fixed(self, signs: np.ndarray) -> np.ndarray:
        """Active fixed rows of the previous step, moved one step earlier."""
        qp = self.qp
        inputs, arena, _, speed = qp.row_slices
        out = signs.copy()
        for part in (inputs, arena, speed):
            out[part] = _shift_steps(signs[part].reshape(qp.T, -1)).reshape(-1)
        return out

    def _solve_relaxed(
        self, rows: StepRows, keep_fixed: np.ndarray, keep_hs: np.ndarray,
        dual_fixed: np.ndarray | None, dual_hs: np.ndarray | None,
    ) -> tuple[int, np.ndarray, int, np.ndarray, np.ndarray]:
        """DAQP on the kept rows, warm-started from ``dual_*`` (signs of the multipliers
        of the rows to activate first): ``(exitflag, z, iterations, dual_fixed, dual_hs)``."""
        qp = self.qp
        fixed = np.flatnonzero(keep_fixed)
        steps, obstacles = np.nonzero(keep_hs)
        n_kept = len(fixed)
        A = np.empty((n_kept + len(steps), qp.nu))
        A[:n_kept] = qp.fixed_rows[fixed]
        if len(steps):
            qp.halfspace_rows(rows, steps, obstacles, out=A[n_kept:])
        upper = np.concatenate((rows.upper[fixed], rows.hs_upper[steps, obstacles]))
        lower = np.concatenate((rows.lower[fixed], np.full(len(steps), -np.inf)))
        soft = np.concatenate((self._soft_fixed[fixed], np.full(len(steps), self._soft_hs)))
        sense = np.where(soft, 8, 0).astype(np.intc)
        if dual_fixed is not None and not soft.any():
            # Hard rows only: DAQP activates the start set in setup, before soft weights
            # could be set, so soft QPs start cold (a warm start gained them nothing).
            start = np.concatenate((dual_fixed[fixed], dual_hs[steps, obstacles]))
            flag, _ = self._model.setup(self._identity, rows.f, A, upper, lower, sense,
                                        dual_start=start)
        else:
            flag, _ = self._model.setup(self._identity, rows.f, A, upper, lower, sense)
        dual_fixed, dual_hs = np.zeros(qp.n_fixed), np.zeros((qp.T, qp.K))
        if flag < 0:
            return int(flag), rows.f, 0, dual_fixed, dual_hs
        if soft.any():
            rho = np.full(len(soft), SOFT_RHO)
            w = np.full(len(soft), self.problem.slack_penalty)
            self._model.soft_weights(rho_l=rho, rho_u=rho, w_l=w, w_u=w)
        x, _, flag, info = self._model.solve()
        lam = np.sign(info["lam"])
        dual_fixed[fixed] = lam[:n_kept]
        dual_hs[steps, obstacles] = lam[n_kept:]
        return int(flag), np.asarray(x), int(info.get("iterations", 0)), dual_fixed, dual_hs

    def _solution(self, z: np.ndarray | None, flag: int, iterations: int, solve_time: float,
                  rows: StepRows, excess: tuple | None = None) -> QPSolution:
        status = _STATUS.get(flag, f"daqp exitflag {flag}")
        if flag < 1 or z is None:
            self._guess = None
            return QPSolution(False, status, iterations=iterations, solve_time=solve_time)
        qp = self.qp
        u = qp.u_of_z @ z
        inputs = u.reshape(qp.T, qp.m)
        if not self._any_soft:
            return QPSolution(True, status, inputs, None, None, iterations, solve_time)
        fixed, halfspace, values = excess if excess is not None else qp.excess(z, rows)
        hs_slack = bound_slack = None
        if self._soft_hs:
            hs_slack = np.maximum(halfspace.T, 0.0)
        if self._soft_bounds:
            bound_slack = qp.bound_slack(values, rows)
        return QPSolution(True, status, inputs, hs_slack, bound_slack, iterations, solve_time)


def _shift_steps(signs: np.ndarray) -> np.ndarray:
    """Rows by step (first axis), moved one step earlier; the last step keeps its own."""
    out = np.empty_like(signs)
    out[:-1] = signs[1:]
    out[-1] = signs[-1]
    return out

r"""The MPC safety filter: step validation, the shortcut, the acceptance check, the recovery.

One :meth:`MPCSafetyFilter.solve` call:

1. validates the step's data (:mod:`filters.mpc.checks`; bad data raises);
2. **shortcut** (with ``reference_inputs`` and ``skip_feasible_reference``): the
   unconstrained minimiser of the cost (:attr:`MPCProblem.gain`; for
   ``objective="first_input"`` it is :math:`u = u^r`) is *the* optimum whenever it meets
   every row exactly, so no QP is solved;
3. solves the **hard QP** (halfspace, arena and terminal rows hard; halfspace rows
   softened with ``soft=True``) with the back end;
4. **accepts** an answer only if its inputs lie in the box to ``INPUT_CLIP_TOLERANCE``
   (they are then clipped into it) and the roll-out of the clipped inputs from ``x0``
   meets every hard row to ``FEASIBILITY_TOLERANCE`` (and every soft row to the back
   end's slack plus that tolerance, when no clipping beyond that tolerance made the
   back end's slacks stale; the slacks reported are always recomputed from the plan);
5. otherwise **recovers**: ``fallback="soft"`` solves the recovery QP (the halfspace
   rows softened, exact L1 penalty ``slack_penalty``; the least violation, then the
   lowest speed, see :mod:`filters.mpc.recovery`), with the arena and terminal rows
   softened too only if it is infeasible, then brakes if that fails too;
   ``fallback="paper"`` shifts the last plan, then brakes.

A step never raises because a QP is infeasible or a solver fails; the
:class:`~filters.mpc.FilterStatus` says what was returned.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np

from filters._validation import finite_array
from filters.constants import (  # noqa: F401  (re-exported: filters.mpc.filter.* names)
    DISABLED_OFFSET,
    FEASIBILITY_TOLERANCE,
    HORIZON,
    INPUT_CLIP_TOLERANCE,
    SLACK_TOLERANCE,
    SPEED_SIDES,
)
from filters.errors import InvalidParameterError, InvalidTypeError
from filters.mpc._linalg import matvec_operator
from filters.mpc.acceptance import PlanChecker
from filters.mpc.backends import (
    AUTO_DAQP_MAX_INPUTS,
    BACKENDS,
    REMOVED_BACKENDS,
    auto_backend,
    check_backend,
    make_backend,
)
from filters.mpc.checks import step_arrays
from filters.mpc.problem import MPCProblem
from filters.mpc.recovery import (
    braking_gain,
    recovery_problems,
    rollout_with_brake,
    shifted_plan,
)
from filters.mpc.result import (
    FilterResult,
    FilterStatus,
    PaddedSteps,
    QPSolution,
    StepData,
    filter_result,
    recovery_status,
)

__all__ = [
    "AUTO_DAQP_MAX_INPUTS",
    "BACKENDS",
    "DISABLED_OFFSET",
    "FALLBACKS",
    "FEASIBILITY_TOLERANCE",
    "INPUT_CLIP_TOLERANCE",
    "REMOVED_BACKENDS",
    "SLACK_TOLERANCE",
    "MPCSafetyFilter",
    "auto_backend",
]

#: What to do when the hard QP fails.
FALLBACKS = ("soft", "brake", "paper")

_NO_QP = "unconstrained optimum feasible (no QP needed)"


class MPCSafetyFilter:
    r"""MPC safety filter (the paper's Problem 2, or the predictive safety filter).

    Parameters
    ----------
    A, B, C
        Dynamics :math:`x_{t+1} = A x_t + B u_t` and position :math:`y = C x`, shapes
        ``(n, n)``, ``(n, m)``, ``(d, n)``. For the paper's ego double integrator
        ``A = [[I, Ts I], [0, I]]``, ``B = [[Ts²/2 I], [Ts I]]``, ``C = [I, 0]``, Ts = 0.2 s.
    horizon
        Number of steps ``T`` (the paper: 10).
    Q, Q_terminal
        Symmetric PSD state weights ``(n, n)`` for steps ``1..T-1`` and ``T``
        (weights mean :math:`x^\top Q x`); required by ``objective="trajectory"``,
        ignored by ``"first_input"``.
    R
        Symmetric positive definite input weight ``(m, m)`` (keeps the QP strictly
        convex, so the filtered input is unique).
    input_bounds, position_bounds
        ``(low, high)`` of the input box (m/s²) and of the arena (m): numbers or arrays of
        shape ``(m,)`` / ``(d,)``, ±inf for a free side; ``None``: unbounded.
    n_obstacles
        Halfspace rows per step the QP holds; calls may pass fewer (the rest are
        disabled). Rows with a zero normal and a positive offset are accepted (they
        always hold): a caller can switch rows off with them.
    soft
        Solve the first QP with the halfspace rows softened (nonnegative slacks, exact
        L1 penalty). The arena stays hard in that QP (softened only in the recovery QP).
    slack_penalty
        :math:`\rho > 0`, cost per m of violation of a softened row. The L1 penalty is
        exact: with :math:`\rho` above the largest multiplier of the hard QP, the soft
        QP's solution is the hard one whenever the hard one is feasible; otherwise the
        slacks reach the minimal total violation. 1e6 (the default) gave the minimal
        violation to 1e-8 m on strongly infeasible crossing instances.
    brake_gain
        Gain ``K`` ``(m, n)`` of braking :math:`u = \mathrm{clip}(-K x)`; default from the
        model (:func:`filters.mpc.recovery.braking_gain`: :math:`-v/T_s` for the double
        integrator).
    solver_settings
        Back-end settings: Clarabel settings to override for ``backend="clarabel"``
        (and for ``"auto"``, which then always picks Clarabel: the settings are
        Clarabel's); DAQP settings for ``"daqp"``; for
        ``backend="cvxpy"``, keywords of ``problem.solve``).
    skip_feasible_reference
        With ``reference_inputs``, return the unconstrained optimum without a QP when it
        meets every row exactly (``iterations`` 0, ``solve_time`` 0).
    objective
        ``"trajectory"`` (default; the paper's Problem 2: track reference inputs and
        states) or ``"first_input"`` (Wabersich & Zeilinger's predictive safety filter:
        :math:`\|u_0 - u^r_0\|^2_R + w \sum_{t \ge 1} \|u_t - u^r_t\|^2_R`, no state terms;
        the reference states are then not used).
    later_input_weight
        ``w > 0`` of ``"first_input"`` (default 1e-2).
    terminal_set
        ``(G, g)``: the plan ends in :math:`G x_T \le g` (e.g.
        :func:`filters.mpc.stopping_terminal_set`); ``None`` (default): none.
    fallback
        ``"soft"`` (default: the recovery QPs tracking the reference, then braking),
        ``"brake"`` (recovery QPs that minimise the speed instead) or ``"paper"`` (shift
        the last plan, then brake); see :mod:`filters.mpc.recovery`.
    max_speed
        :math:`v_\max` in m/s: every QP keeps the planned velocities :math:`v_1..v_T`
        in the ``speed_sides``-gon inscribed in the disc :math:`\|v\| \le v_\max` (hard
        rows; the state must be ``[position; velocity]``); ``inf`` (default): no limit.
    speed_sides
        Sides of that polygon, ``>= 3`` (default :data:`~filters.constants.SPEED_SIDES`).
    backend
        ``"auto"`` (default: DAQP for the hard QP; for QPs with soft rows DAQP while
        ``T m <= 40``, else Clarabel; see :func:`auto_backend`), ``"daqp"`` (the
        whitened condensed QP, dual active set, lazy rows for long horizons; soft rows as
        DAQP soft constraints), ``"clarabel"`` (the sparse QP built once, updated per
        step) or ``"cvxpy"`` (the readable reference, for tests and benchmarks; imports
        CVXPY). :attr:`backend` and :attr:`recovery_backend` tell which ones ``"auto"``
        picked. A name of :data:`REMOVED_BACKENDS` raises an error naming
        :data:`BACKENDS`.
    fast_path
        Deprecated, no effect (the step has one implementation); passing it warns.

    Raises
    ------
    InvalidArrayError, InvalidParameterError, InvalidTypeError
        On bad model data, weights, bounds, options (see :class:`MPCProblem`).

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
        horizon: int = HORIZON,
        Q: np.ndarray | None = None,
        Q_terminal: np.ndarray | None = None,
        R: np.ndarray,
        input_bounds: tuple[object, object] | None = None,
        position_bounds: tuple[object, object] | None = None,
        n_obstacles: int,
        soft: bool = False,
        slack_penalty: float = 1e6,
        brake_gain: np.ndarray | None = None,
        solver_settings: Mapping[str, Any] | None = None,
        skip_feasible_reference: bool = True,
        objective: str = "trajectory",
        later_input_weight: float = 1e-2,
        terminal_set: tuple[np.ndarray, np.ndarray] | None = None,
        fallback: str = "soft",
        backend: str = "auto",
        fast_path: bool | None = None,
        max_speed: float = np.inf,
        speed_sides: int = SPEED_SIDES,
    ) -> None:
        for name, value in (("soft", soft), ("skip_feasible_reference", skip_feasible_reference)):
            if not isinstance(value, (bool, np.bool_)):
                raise InvalidTypeError(f"{name} must be a bool, got {value!r}")
        if fast_path is not None:
            warnings.warn("MPCSafetyFilter(fast_path=...) has no effect and is deprecated: "
                          "the filter step has one implementation", DeprecationWarning,
                          stacklevel=2)
        if fallback not in FALLBACKS:
            raise InvalidParameterError(f"fallback must be one of {FALLBACKS}, got {fallback!r}")
        check_backend(backend)
        problem = MPCProblem(
            A, B, C, horizon, R, Q, Q_terminal, objective=objective,
            later_input_weight=later_input_weight, input_bounds=input_bounds,
            position_bounds=position_bounds, terminal_set=terminal_set,
            n_obstacles=n_obstacles, soft_rows=frozenset({"halfspaces"} if soft else ()),
            slack_penalty=slack_penalty, max_speed=max_speed, speed_sides=speed_sides,
        )
        self.problem = problem
        self._soft = bool(soft)
        self._skip = bool(skip_feasible_reference)
        self._fallback = fallback
        recovery_problem, rescue_problem = recovery_problems(problem, fallback == "brake")
        recovery_backend = backend
        if backend == "auto":
            if solver_settings is not None:
                backend = recovery_backend = "clarabel"
            else:
                backend = auto_backend(problem)
                recovery_backend = auto_backend(rescue_problem)
        self._backend_name = backend
        T, n, m = problem.horizon, problem.n, problem.m
        if brake_gain is None:
            self._brake_gain = braking_gain(problem.A, problem.B, problem.C)
        else:
            self._brake_gain = finite_array("brake_gain", brake_gain, shape=(m, n))
        self._primary = make_backend(backend, problem, solver_settings)
        self._recovery = self._rescue = None  # the recovery QPs: arena hard, then soft
        if fallback != "paper":
            self._recovery = make_backend(recovery_backend, recovery_problem, solver_settings)
            self._rescue = make_backend(recovery_backend, rescue_problem, solver_settings)
        # The unconstrained minimiser in one product: u° = O [x0; x^r; u^r] with
        # O = [-K Phi, K, I - K Gamma] (the gain's formula, see MPCProblem.gain).
        phi, gamma = problem.rollout
        gain = problem.gain
        self._optimum = matvec_operator(
            np.hstack([-gain @ phi, gain, np.eye(T * m) - gain @ gamma]))
        self._v = np.empty(n + T * n + T * m)  # [x0; x^r; u^r]
        self._check = PlanChecker(problem)  # roll-out, row excesses, acceptance, cost
        u_low, u_high = problem.input_bounds
        self._u_low_all, self._u_high_all = np.tile(u_low, T), np.tile(u_high, T)
        self._zero_inputs = np.zeros((T, m))
        self._zero_inputs.setflags(write=False)
        # Hot-path constants (property lookups and shape tuples cost per step).
        self._T, self._n, self._m, self._d, self._K = T, n, m, problem.d, problem.n_obstacles
        self._has_state_cost = problem.has_state_cost
        self._primary_soft_rows = problem.soft_rows
        # An accepted answer meets its hard rows to FEASIBILITY_TOLERANCE: with the arena
        # and terminal rows hard and that tolerance within SLACK_TOLERANCE, their total
        # violation (bound_slack) is 0 without summing it.
        self._bounds_held = ("bounds" not in problem.soft_rows
                             and FEASIBILITY_TOLERANCE <= SLACK_TOLERANCE)
        self._recovery_zeros = (np.zeros((T, n)), self._zero_inputs)
        self._padded = PaddedSteps(self._K, T, problem.d)
        self._plan: np.ndarray | None = None
        self._failures = 0
        self._qp_solves = 0
        self._step: StepData | None = None  # the last QP step's data, as the back ends take it

    # ------------------------------------------------------------------ properties
    @property
    def horizon(self) -> int:
        """Prediction horizon ``T`` (number of steps)."""
        return self.problem.horizon

    @property
    def n_obstacles(self) -> int:
        """Largest number of halfspace rows per step the QP holds."""
        return self.problem.n_obstacles

    @property
    def soft(self) -> bool:
        """Whether the first QP softens the halfspace rows."""
        return self._soft

    @property
    def slack_penalty(self) -> float:
        """:math:`\\rho`, cost per m of violation of a softened row."""
        return self.problem.slack_penalty

    @property
    def objective(self) -> str:
        """``"trajectory"`` or ``"first_input"``."""
        return self.problem.objective

    @property
    def fallback(self) -> str:
        """``"soft"`` or ``"paper"``."""
        return self._fallback

    @property
    def backend(self) -> str:
        """The primary QP's back end: ``"daqp"``, ``"clarabel"`` or ``"cvxpy"`` (``"auto"``
        resolved)."""
        return self._backend_name

    @property
    def recovery_backend(self) -> str | None:
        """The recovery QP's back end (``"auto"`` resolved), ``None`` with ``fallback="paper"``."""
        return None if self._recovery is None else self._recovery.name

    @property
    def input_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(low, high)`` of the input box, each ``(m,)`` (±inf: unbounded)."""
        low, high = self.problem.input_bounds
        return low.copy(), high.copy()

    @property
    def position_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(low, high)`` of the arena, each ``(d,)`` (±inf: unbounded)."""
        low, high = self.problem.position_bounds
        return low.copy(), high.copy()

    @property
    def last_plan(self) -> np.ndarray | None:
        """Copy of the last accepted plan ``(T, m)``, or ``None``."""
        return None if self._plan is None else self._plan.copy()

    @property
    def last_qp_solves(self) -> int:
        """QPs solved by the last :meth:`solve`: 0 (shortcut), 1 (hard), 2 (recovery), 3 (the
        arena-soft recovery)."""
        return self._qp_solves

    def reset(self) -> None:
        """Forget the stored plan, the failure count and the back ends' warm starts (call
        at episode start: a reset filter answers as a new one does)."""
        self._plan = None
        self._failures = 0
        for backend in (self._primary, self._recovery, self._rescue):
            if hasattr(backend, "reset"):
                backend.reset()

    def braking_input(self, x: np.ndarray) -> np.ndarray:
        """Braking input at state ``x``, ``clip(-K x)`` to the input box, shape ``(m,)``."""
        return np.clip(-self._brake_gain @ x, *self.problem.input_bounds)

    # ------------------------------------------------------------------ the step
    def _call(self, backend: Any, step: StepData) -> QPSolution:
        self._qp_solves += 1
        try:
            return backend.solve(step)
        except Exception as exc:  # a back end bug must not crash the control loop
            return QPSolution(False, f"exception: {exc!r}")

    def solve(
        self,
        x0: np.ndarray,
        reference_states: np.ndarray,
        halfspaces: object = None,
        *,
        reference_inputs: np.ndarray | None = None,
    ) -> FilterResult:
        r"""Filter a reference: solve the QP, or recover.

        Parameters
        ----------
        x0
            Current state :math:`x_0`, shape ``(n,)`` (m and m/s for the ego).
        reference_states
            Reference trajectory, shape ``(T + 1, n)``; row 0 is ignored (the plan starts
            at ``x0``), rows ``1..T`` are :math:`x^r_1..x^r_T` (not used by
            ``objective="first_input"``, but validated).
        halfspaces
            Safe side ``normals[i, t-1] @ (C x_t) <= offsets[i, t-1]``: an object with
            ``.normals`` ``(k, T, d)`` and ``.offsets`` ``(k, T)`` (as from
            :func:`filters.safe_halfspaces`), a pair ``(normals, offsets)``, or ``None``.
            ``k <= n_obstacles``; zero normals with positive offsets switch rows off.
        reference_inputs
            :math:`u^r_0..u^r_{T-1}`, shape ``(T, m)``; default zeros (the paper's
            :math:`u^\top R u`). Needed for the shortcut.

        Returns
        -------
        FilterResult
            Never a failure: see :class:`~filters.mpc.FilterStatus`.

        Raises
        ------
        InvalidArrayError
            On a wrong shape, a NaN/infinite entry, or more than ``n_obstacles`` rows.
        InvalidTypeError
            If ``halfspaces`` has an unsupported type.
        """
        start = time.perf_counter()
        T, n, m = self._T, self._n, self._m
        x0, reference_states, reference_inputs, normals, offsets = step_arrays(
            x0, reference_states, reference_inputs, halfspaces, T, n, m, self._d, self._K)
        return self._solve_step(x0, reference_states[1:], reference_inputs, normals, offsets,
                                start)

    def _solve_step(self, x0: np.ndarray, ref_states: np.ndarray,
                    reference_inputs: np.ndarray | None, normals: np.ndarray,
                    offsets: np.ndarray, start: float) -> FilterResult:
        """The step on checked data (:meth:`solve`): the shortcut, the QP, the recovery."""
        T, m = self._T, self._m
        check = self._check
        ref_inputs = self._zero_inputs if reference_inputs is None else reference_inputs
        k = normals.shape[0]
        self._qp_solves = 0
        at_reference = None  # the evaluation of u = u^r, when made
        if not self._has_state_cost:
            # first_input: x^r is the roll-out of u^r (keeps b small), which is also the
            # unconstrained optimum: one evaluation gives both.
            at_reference = check.evaluate(x0, ref_inputs, normals, offsets)
            ref_states = at_reference[0][1:]

        if self._skip and reference_inputs is not None:
            u = ref_inputs.reshape(-1)
            if self._has_state_cost:  # a new array
                u = self._optimum @ np.concatenate(
                    (x0, ref_states.reshape(-1), u), out=self._v)
            # The rows first when their evaluation is at hand (they fail far more often
            # than the box), else the box first (it spares the evaluation).
            evaluation = at_reference
            if evaluation is None and self._in_box(u):
                evaluation = check.evaluate(x0, u, normals, offsets)
            if evaluation is not None:
                states, halfspace, bounds = evaluation
                if np.maximum.reduce(bounds, initial=-np.inf) <= 0.0 and (
                    not k or np.maximum.reduce(halfspace, axis=None) <= 0.0
                ) and (at_reference is None or self._in_box(u)):
                    inputs = np.array(u).reshape(T, m)  # a copy: it becomes the stored plan
                    self._plan, self._failures = inputs, 0
                    slack = np.zeros((k, T)) if self._soft else None
                    return self._result(
                        FilterStatus.OPTIMAL, inputs, states, slack, 0.0, _NO_QP, 0, 0.0,
                        check.cost(inputs, states, ref_states, reference_inputs), start,
                    )

        step = self._padded(x0, ref_states, ref_inputs, normals, offsets)
        self._step = step

        primary = self._call(self._primary, step)
        answer = check.accept(primary, self._primary_soft_rows, x0, normals, offsets)
        iterations, solve_time = primary.iterations, primary.solve_time
        status_text = primary.status if isinstance(answer, tuple) or not answer else (
            f"{primary.status} ({answer})"
        )
        if isinstance(answer, tuple):
            inputs, states, halfspace, bounds = answer
            self._plan, self._failures = inputs, 0
            slack = check.slack(halfspace) if self._soft else None
            status = FilterStatus.SOFT if slack is not None and slack.any() else (
                FilterStatus.OPTIMAL
            )
            bound_total = 0.0 if self._bounds_held else check.bound_total(bounds)
            return self._result(status, inputs, states, slack, bound_total,
                                status_text, iterations, solve_time,
                                check.cost(inputs, states, ref_states, reference_inputs), start)
        self._failures += 1
        return self._recover(step, x0, normals, offsets, status_text, iterations, solve_time,
                             start)

    def _in_box(self, u: np.ndarray) -> bool:
        """Whether the stacked inputs ``u`` ``(T m,)`` lie in the input box (m/s²)."""
        return bool(np.logical_and.reduce(u >= self._u_low_all)
                    and np.logical_and.reduce(u <= self._u_high_all))

    def _recover(self, step: StepData, x0: np.ndarray, normals: np.ndarray,
                 offsets: np.ndarray, status_text: str, iterations: int, solve_time: float,
                 start: float) -> FilterResult:
        """After a failed hard QP: the recovery QPs (arena hard, then soft; then braking),
        or the paper's fallback."""
        check = self._check
        prefix = None if self._recovery is not None else shifted_plan(self._plan, self._failures)
        status_text = f"hard QP: {status_text}"
        data = step if self._fallback == "soft" else StepData(  # "brake": no reference
            x0, *self._recovery_zeros, step.normals, step.offsets)
        for name, backend in (("recovery QP", self._recovery), ("arena-soft QP", self._rescue)):
            if backend is None:  # fallback="paper": the last plan, shifted
                break
            recovery = self._call(backend, data)
            answer = check.accept(recovery, backend.problem.soft_rows, x0, normals, offsets)
            iterations += recovery.iterations
            solve_time += recovery.solve_time
            reason = "" if isinstance(answer, tuple) or not answer else f" ({answer})"
            status_text = f"{status_text}; {name}: {recovery.status}{reason}"
            if isinstance(answer, tuple):
                inputs, states, halfspace, bounds = answer
                self._plan = inputs
                slack, bound_total = check.slack(halfspace), check.bound_total(bounds)
                return self._result(
                    recovery_status(slack, bound_total), inputs, states, slack, bound_total,
                    status_text, iterations, solve_time,
                    check.cost(inputs, states, step.ref_states, step.ref_inputs), start)
        return self._brake(x0, normals, offsets, prefix, status_text, iterations, solve_time,
                           step, start)

    def _brake(self, x0: np.ndarray, normals: np.ndarray, offsets: np.ndarray,
               prefix: np.ndarray | None, status_text: str, iterations: int,
               solve_time: float, step: StepData, start: float) -> FilterResult:
        """The shifted plan ``prefix`` (``"shifted"``), or braking from ``x0`` (``"brake"``)."""
        p, T, m, check = self.problem, self._T, self._m, self._check
        status = FilterStatus.BRAKE if prefix is None else FilterStatus.SHIFTED
        inputs, states = rollout_with_brake(
            p.A, p.B, x0, np.zeros((0, m)) if prefix is None else prefix, T,
            self._brake_gain, p.input_bounds,
        )
        _, halfspace, bounds = check.evaluate(x0, inputs, normals, offsets)
        return self._result(status, inputs, states, check.slack(halfspace),
                            check.bound_total(bounds), status_text, iterations, solve_time,
                            check.cost(inputs, states, step.ref_states, step.ref_inputs),
                            start)

    def _result(
        self, status: FilterStatus, inputs: np.ndarray, states: np.ndarray,
        slack: np.ndarray | None, bound_slack: float, solver_status: str, iterations: int,
        solve_time: float, objective: float, start: float,
    ) -> FilterResult:
        return filter_result(status, inputs, states, slack, bound_slack, solver_status,
                             iterations, solve_time, objective,
                             time.perf_counter() - start, self._failures)

"""The part of the MPC safety filter that does not depend on the QP solver.

:class:`SafetyFilterBase` holds what every back end of Problem 2 shares: the
validation of the model and of each step's data, the precomputed roll-out and
unconstrained minimiser, the exact feasibility check of a solver's answer, the
fallback rule of the paper's Remark (the last plan shifted, then braking) and
the assembly of the :class:`~filters.mpc_result.FilterResult`. The back ends
are :class:`filters.mpc.MPCSafetyFilter` (Clarabel, built once) and
:class:`filters.mpc_cvxpy.CVXPYSafetyFilter` (the readable reference).

The module also holds the tolerances both back ends use. It imports no solver.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import scipy.linalg

from filters._validation import finite_array, scalar_in_range
from filters.errors import InvalidArrayError, InvalidTypeError
from filters.mpc_checks import _all_finite, _box, _finite, _integer, _weight, parse_halfspaces
from filters.mpc_result import FilterResult, FilterStatus, _QPAttempt

__all__ = [
    "DISABLED_OFFSET",
    "FEASIBILITY_TOLERANCE",
    "SLACK_TOLERANCE",
    "SOFT_GAP_TOLERANCE",
    "SafetyFilterBase",
]

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

#: Dot products over the last axis, broadcast: (k, T, d) with (T, d) -> (k, T). The
#: gufunc np.vecdot (NumPy >= 2) takes about half the time of the equivalent einsum.
_vecdot = getattr(np, "vecdot", None) or (lambda a, b: np.einsum("...d,...d->...", a, b))

#: What :meth:`SafetyFilterBase.solve` reports when the unconstrained minimiser
#: meets every constraint, so that no QP is solved (``iterations`` 0, ``solve_time`` 0).
_NO_QP = _QPAttempt(
    None, None, "unconstrained optimum feasible (no QP needed)", 0, 0.0, True, 0.0
)


class SafetyFilterBase:
    """Validation, fallback and result assembly shared by the QP back ends.

    The constructor validates the model, weights and bounds (see
    :class:`filters.mpc.MPCSafetyFilter` for the parameters) and precomputes the
    roll-out, the unconstrained minimiser's gain and the braking gain;
    :meth:`solve` validates one step's data, calls the back end, checks its
    answer against every constraint and falls back (``SHIFTED``, then
    ``BRAKE``) when it is unusable.

    Subclasses implement :meth:`_solve_qp`: given ``x0``, the references and the
    halfspaces padded to ``n_obstacles`` rows (unused rows read
    ``0 @ y <= DISABLED_OFFSET``), return a :class:`~filters.mpc_result._QPAttempt`.
    A back end that leaves rows out (``_QPAttempt.relaxed``) is called again
    with ``include`` set to the rows to add (see :meth:`_missed_rows`).
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
            ``BRAKE`` (see :class:`FilterStatus` and the :mod:`filters.mpc` docstring).

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
        """Solve Problem 2 for the (padded) data; ``include``: see the class docstring."""
        raise NotImplementedError

r"""DAQP back end: the condensed (inputs-only) QP of an :class:`~filters.mpc.MPCProblem`.

DAQP (Arnström, Bemporad and Axehill, IEEE TAC 2022) is a dual active-set solver in C;
on the small dense QPs of a short horizon it answers in tens of µs (update and solve:
~25 µs at T = 10 with 3 obstacles, measured on this project's loaded 2-core machine).

**Condensed form.** The states are eliminated with the prediction matrices of the
problem (:attr:`MPCProblem.rollout`), :math:`X = \Phi x_0 + \Gamma u` with :math:`X =
[x_1; \dots; x_T]`, so the variables are the inputs :math:`u \in \mathbb{R}^{T m}` only:

.. math::

    \min_u \ \tfrac12 u^\top H u + f^\top u, \qquad
    H = 2 (\bar R + \Gamma^\top \bar Q \Gamma), \quad
    f = -2 \bar R u^r + 2 \Gamma^\top \bar Q (\Phi x_0 - X^r),

(the cost (8) up to a constant; :math:`\bar R`, :math:`\bar Q` block diagonal), subject to

* the input box as DAQP's simple bounds :math:`u_\text{low} \le u_t \le u_\text{high}`;
* the arena :math:`y_\text{low} - C \Phi_t x_0 \le C \Gamma_t u \le y_\text{high} - C
  \Phi_t x_0` (two-sided rows, one per step and finite axis);
* the terminal rows :math:`G \Gamma_T u \le g - G \Phi_T x_0`;
* the halfspaces :math:`a_{i,t}^\top C \Gamma_t u \le b_{i,t} - a_{i,t}^\top C \Phi_t x_0`
  (disabled rows, ``0 @ y <= 1``, are zero rows that always hold).

:math:`H`, the arena and terminal rows are built once; per step only the halfspace rows
of the constraint matrix, the right-hand sides and ``f`` change (``daqp.Model.update``).
Each solve starts from the empty active set (``warm_start=True`` starts from the
previous one; it saved half an iteration and no measurable time, and a cold start
keeps every step independent of the ones before). The work per step grows like
:math:`(T m)^2` times the number of rows (DAQP's update forms :math:`A H^{-1/2}`), so
for long horizons the sparse Clarabel back end is faster: see ``backend="auto"`` of
:class:`~filters.mpc.MPCSafetyFilter`.

**Soft rows** (``soft=True``, and the recovery QP) are DAQP's soft constraints
(sense 8) with the linear weight :math:`w = \rho` (``slack_penalty``) on each side and
the reciprocal quadratic weight ``SOFT_RHO``: a violation :math:`s \ge 0` of a soft row
costs :math:`\rho s + s^2 / (2\,\mathrm{SOFT\_RHO})`, the exact L1 penalty of the
other back ends up to :math:`5 \cdot 10^{-7} s^2`. No slack variables are added (the
Hessian stays the inputs' one); the slacks reported are the violations of the returned
inputs. Checked against the CVXPY reference on the test instances: DAQP's penalised
objective was never above CVXPY's (``SOFT_RHO`` = 1e4 or 1e6; 1e8 and more lost up to
2e3 in it, numerically). Measured (CPU, loaded machine, T = 10, 3 obstacles, terminal
set): steps that needed the recovery QP 0.38 ms with DAQP, 1.43 ms with Clarabel.

**Statuses.** DAQP's exit flags are reported with Clarabel's names where one exists
(``1`` -> ``"Solved"``, ``-1`` -> ``"PrimalInfeasible"``, ``-4`` -> ``"MaxIterations"``),
so that the filter's statuses and fallbacks read the same for both back ends; other
flags read ``"daqp exitflag N"``.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import daqp
import numpy as np

from filters.errors import InvalidParameterError, InvalidTypeError
from filters.mpc._linalg import matvec_operator
from filters.mpc.problem import MPCProblem
from filters.mpc.result import QPSolution, StepData

__all__ = ["SOFT_RHO", "DAQPBackend", "daqp_settings"]

#: DAQP exit flags by the Clarabel status name the filter reports for them.
_STATUS = {1: "Solved", 2: "Solved", -1: "PrimalInfeasible", -4: "MaxIterations"}
#: Reciprocal quadratic weight of the soft rows (see the module docstring).
SOFT_RHO = 1e6


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
    """The condensed QP of one :class:`~filters.mpc.MPCProblem`, as a DAQP model.

    Parameters
    ----------
    problem
        What to build (its ``soft_rows`` are DAQP soft constraints).
    solver_settings
        DAQP settings to override (see :func:`daqp_settings`).
    warm_start
        Start each solve from the previous solve's active set (default ``False``). Off,
        every solve starts from the empty active set, so a used model returns bit for
        bit what a fresh one returns (episodes are reproducible whatever ran before).
        Measured on 200 crossing steps (3 obstacles, T = 10): warm 5.5 iterations and
        26 µs per solve call, cold 5.9 and 24-30 µs, inputs equal to 1e-13; the per-step
        update (DAQP's transform of every row by the Hessian's factor) dominates.

    Raises
    ------
    InvalidParameterError
        If a setting is unknown or has a value DAQP refuses.
    """

    name = "daqp"

    def __init__(
        self, problem: MPCProblem, *, solver_settings: Mapping[str, Any] | None = None,
        warm_start: bool = False,
    ) -> None:
        self.problem = problem
        self._settings = daqp_settings(solver_settings)
        self._warm_start = bool(warm_start)
        self._build()

    def _build(self) -> None:
        p = self.problem
        T, n, m, d, K = p.horizon, p.n, p.m, p.d, p.n_obstacles
        nu = T * m
        phi, gamma = p.rollout  # (T n, n), (T n, T m)
        R_bar = np.zeros((nu, nu))
        for t, Rt in enumerate(p.input_weights):
            R_bar[t * m : (t + 1) * m, t * m : (t + 1) * m] = Rt
        Q_bar = np.zeros((T * n, T * n))
        for t, Qt in enumerate(p.state_weights):
            Q_bar[t * n : (t + 1) * n, t * n : (t + 1) * n] = Qt
        hessian = 2.0 * (R_bar + gamma.T @ Q_bar @ gamma)
        self._H = np.ascontiguousarray(0.5 * (hessian + hessian.T))
        # f = -2 R u^r + 2 Gamma' Q (Phi x0 - X^r) = F [x0; X^r; u^r]
        self._F = matvec_operator(np.hstack([2.0 * gamma.T @ Q_bar @ phi, -2.0 * gamma.T @ Q_bar,
                             -2.0 * R_bar]))

        # Positions C x_t = C Phi_t x0 + C Gamma_t u, t = 1..T.
        C_phi = np.einsum("dn,tnk->tdk", p.C, phi.reshape(T, n, n))  # (T, d, n)
        C_gamma = np.einsum("dn,tnk->tdk", p.C, gamma.reshape(T, n, nu))  # (T, d, nu)
        self._C_gamma = np.ascontiguousarray(C_gamma)

        rows, upper, lower = [], [], []  # constant rows, their bounds at x0 = 0
        x0_maps = []  # the bounds shift by -(map @ x0)
        y_low, y_high = p.position_bounds
        axes = np.flatnonzero(np.isfinite(y_low) | np.isfinite(y_high))
        if axes.size:
            rows.append(C_gamma[:, axes].reshape(-1, nu))
            upper.append(np.tile(y_high[axes], T))
            lower.append(np.tile(y_low[axes], T))
            x0_maps.append(C_phi[:, axes].reshape(-1, n))
        if p.terminal_set is not None and p.terminal_set[0].shape[0]:
            G, g = p.terminal_set
            rows.append(G @ gamma[(T - 1) * n :])
            upper.append(g)
            lower.append(np.full(len(g), -np.inf))
            x0_maps.append(G @ phi[(T - 1) * n :])
        n_fixed = sum(len(r) for r in rows)
        self._n_fixed = n_fixed
        n_arena = len(rows[0]) if axes.size else 0
        hs0_ = nu + n_fixed
        # Halfspace rows step-major: row n_fixed + (t - 1) K + i is a_it' C Gamma_t.
        self._A = np.zeros((n_fixed + K * T, nu))
        if n_fixed:
            self._A[:n_fixed] = np.vstack(rows)
        self._A_hs = self._A[n_fixed:].reshape(T, K, nu)  # a view: written in place
        self._fixed_upper = np.concatenate(upper) if upper else np.zeros(0)
        self._fixed_lower = np.concatenate(lower) if lower else np.zeros(0)
        # One product S x0: the shift of the fixed rows, then the positions C Phi_t x0.
        self._S = matvec_operator(np.vstack([*x0_maps, C_phi.reshape(T * d, n)]))

        u_low, u_high = p.input_bounds
        n_rows = nu + n_fixed + K * T
        self._upper = np.full(n_rows, np.inf)
        self._lower = np.full(n_rows, -np.inf)
        self._upper[:nu] = np.tile(u_high, T)
        self._lower[:nu] = np.tile(u_low, T)
        self._hs0 = nu + n_fixed
        self._nu = nu
        soft = np.zeros(n_rows, dtype=bool)
        if p.soft_bounds:
            soft[nu:hs0_] = True
        if p.soft_halfspaces:
            soft[hs0_:] = True
        self._soft = soft
        self._sense = np.where(soft, 8, 0).astype(np.int32)
        self._n_arena = n_arena
        self._arena_axes = axes
        self._hi = np.isfinite(y_high[axes])
        self._lo = np.isfinite(y_low[axes])
        # Hot-path constants and views (attribute and property lookups cost per step).
        self._T, self._m, self._K = T, m, K
        self._any_soft = bool(soft.any())
        self._upper_fixed, self._lower_fixed = self._upper[nu:hs0_], self._lower[nu:hs0_]
        self._upper_hs = self._upper[hs0_:].reshape(T, K)  # a view: written in place
        # Dense S (small problems): S x0 is written into a buffer whose views are
        # precomputed; a CSR S (large ones) returns a new array per product.
        self._shift = np.empty(self._S.shape[0]) if isinstance(self._S, np.ndarray) else None
        if self._shift is not None:
            self._shift_fixed = self._shift[:n_fixed]
            self._positions0 = self._shift[n_fixed:].reshape(T, 1, d, 1)
        self._positions0_shape = (T, 1, d, 1)
        self._at_x0 = np.empty((T, K, 1, 1))  # a_it . C Phi_t x0
        self._at_x0_flat = self._at_x0.reshape(T, K)  # a view
        self._v = np.empty(n + T * n + nu)  # [x0; X^r; u^r]
        self._model: daqp.Model | None = None
        self._cold = True
        try:  # built here so that a bad setting raises now, not at every step
            model = self._new_model()
        except (TypeError, ValueError) as exc:
            raise InvalidParameterError(
                f"solver_settings: DAQP refused {self._settings!r}: {exc}") from exc
        self._model = None if isinstance(model, int) else model

    def _new_model(self) -> daqp.Model | int:
        """A DAQP model set up with placeholder data (zero halfspace rows, ``f = 0``), or
        DAQP's negative setup flag. Every solve, the first included, then writes its data
        by ``update``: a used model returns bit for bit what a fresh one returns (setup
        and update differ in the last bits)."""
        model = daqp.Model()
        if self._settings:
            model.settings = self._settings
        A = self._A.copy()
        A[self._n_fixed :] = 0.0
        upper, lower = self._upper.copy(), self._lower.copy()
        upper[self._nu :], lower[self._nu :] = np.inf, -np.inf
        f = np.zeros(self._nu)
        flag, _ = model.setup(self._H, f, A, upper, lower, self._sense.copy())
        self._setup_arrays = (f, A, upper, lower)  # kept alive with the model
        if flag >= 0 and self._soft.any():
            n_rows = len(self._upper)
            rho = np.full(n_rows, SOFT_RHO)
            w = np.full(n_rows, self.problem.slack_penalty)
            model.soft_weights(rho_l=rho, rho_u=rho, w_l=w, w_u=w)
            self._setup_arrays += (rho, w)
        return int(flag) if flag < 0 else model

    def _data(self, step: StepData) -> np.ndarray:
        """Write the step's rows and bounds into the preallocated arrays; return ``f``."""
        n_fixed = self._n_fixed
        if self._shift is not None:
            np.matmul(self._S, step.x0, out=self._shift)
            shift_fixed, positions0 = self._shift_fixed, self._positions0
        else:
            shift = self._S @ step.x0
            shift_fixed = shift[:n_fixed]
            positions0 = shift[n_fixed:].reshape(self._positions0_shape)
        if n_fixed:
            np.subtract(self._fixed_upper, shift_fixed, out=self._upper_fixed)
            np.subtract(self._fixed_lower, shift_fixed, out=self._lower_fixed)
        if self._K:
            normals = step.normals.transpose(1, 0, 2)  # (T, K, d)
            np.matmul(normals, self._C_gamma, out=self._A_hs)
            np.matmul(normals[:, :, None, :], positions0, out=self._at_x0)  # (T, K, 1, 1)
            np.subtract(step.offsets.T, self._at_x0_flat, out=self._upper_hs)
        v = np.concatenate(
            (step.x0, step.ref_states.reshape(-1), step.ref_inputs.reshape(-1)), out=self._v
        )
        return self._F @ v

    def solve(self, step: StepData) -> QPSolution:
        """Write the step's data into the model and solve; never raises on a failed solve."""
        try:
            f = self._data(step)
            begin = time.perf_counter()
            if self._model is None:
                self._model = self._new_model()
                if isinstance(self._model, int):
                    flag, self._model = self._model, None
                    return QPSolution(False, f"daqp setup exitflag {flag}",
                                      solve_time=time.perf_counter() - begin)
            if self._cold or not self._warm_start:
                self._model.update(f=f, A=self._A, bupper=self._upper, blower=self._lower,
                                   sense=self._sense)
            else:
                self._model.update(f=f, A=self._A, bupper=self._upper, blower=self._lower)
            x, _, flag, info = self._model.solve()
            solve_time = time.perf_counter() - begin
        except (KeyboardInterrupt, SystemExit):
            raise
        except Exception as exc:
            self._model, self._cold = None, True
            return QPSolution(False, f"exception: {exc!r}")
        flag = int(flag)
        status = _STATUS.get(flag, f"daqp exitflag {flag}")
        iterations = int(info.get("iterations", 0))
        self._cold = flag < 1
        if flag < 1:
            return QPSolution(False, status, iterations=iterations, solve_time=solve_time)
        inputs = np.array(x, dtype=float).reshape(self._T, self._m)
        if not self._any_soft:
            return QPSolution(True, status, inputs, None, None, iterations, solve_time)
        p = self.problem
        hs_slack = bound_slack = None
        values = self._A @ inputs.reshape(-1)
        nu = self._nu
        excess_up = values - self._upper[nu:]
        excess_low = self._lower[nu:] - values
        if p.soft_halfspaces:
            hs_slack = np.maximum(excess_up[self._n_fixed :], 0.0).reshape(
                self._T, self._K).T
        if p.soft_bounds:
            T, n_axes = self._T, len(self._arena_axes)
            up = excess_up[: self._n_arena].reshape(T, n_axes)[:, self._hi]
            low = excess_low[: self._n_arena].reshape(T, n_axes)[:, self._lo]
            terminal = excess_up[self._n_arena : self._n_fixed]
            bound_slack = np.maximum(
                np.concatenate([up.reshape(-1), low.reshape(-1), terminal]), 0.0)
        return QPSolution(True, status, inputs, hs_slack, bound_slack, iterations, solve_time)

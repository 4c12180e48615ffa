r"""The per-step evaluation of a plan: roll-out, row excesses, acceptance, cost.

:class:`PlanChecker` holds the maps of one :class:`~filters.mpc.MPCProblem` that the
filter applies to a plan :math:`u` at every step:

* :meth:`PlanChecker.evaluate`: one product :math:`M [x_0; u] - r` gives the roll-out
  :math:`x_0..x_T` (m, m/s), the positions :math:`C x_t`, and the excess ``lhs - rhs``
  of every bound row (arena, terminal, speed; ``<= 0``: the row holds); the halfspace
  excess is :math:`a_{i,t}^\top C x_t - b_{i,t}` (m);
* :meth:`PlanChecker.accept`: whether a back end's answer is usable (inputs in the box
  to ``INPUT_CLIP_TOLERANCE``, then clipped; every hard row met by the roll-out of the
  clipped inputs to ``FEASIBILITY_TOLERANCE``, a soft row to the back end's slack plus
  that tolerance);
* :meth:`PlanChecker.cost`: the cost (8) with block-diagonal weights (two products).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg

from filters.constants import FEASIBILITY_TOLERANCE, INPUT_CLIP_TOLERANCE, SLACK_TOLERANCE
from filters.mpc._linalg import matvec_operator
from filters.mpc.problem import MPCProblem
from filters.mpc.result import QPSolution

__all__ = ["PlanChecker"]

_vecdot = getattr(np, "vecdot", None) or (lambda a, b: np.einsum("...d,...d->...", a, b))


class PlanChecker:
    """The per-step maps of ``problem`` (module docstring); no state between steps
    besides a work buffer."""

    def __init__(self, problem: MPCProblem) -> None:
        T, n, m = problem.horizon, problem.n, problem.m
        evaluation, offset = problem.check_map
        # The affine map as one product: [M, -r] @ [x0; u; 1].
        self._eval = matvec_operator(np.hstack([evaluation, -offset[:, None]]))
        self._split = ((T + 1) * n, (T + 1) * n + T * problem.d)
        #: Arena and terminal rows (the speed rows follow them in the bound excess).
        self.n_bound = len(offset) - self._split[1] - T * len(problem.speed_rows[1])
        self._R_block = matvec_operator(scipy.linalg.block_diag(*problem.input_weights))
        self._Q_block = matvec_operator(scipy.linalg.block_diag(*problem.state_weights))
        self._has_state_cost = problem.has_state_cost
        self._u_low, self._u_high = problem.input_bounds
        self._states_shape, self._positions_shape = (T + 1, n), (T, problem.d)
        self._z = np.ones(n + T * m + 1)  # [x0; u; 1] of the evaluation map
        self._xu = self._z[:-1]  # its [x0; u] part, written per evaluation

    def evaluate(self, x0: np.ndarray, inputs: np.ndarray, normals: np.ndarray,
                 offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Roll-out ``(T + 1, n)``, halfspace excess ``(k, T)``, bound-row excess (1-D, in
        the order of :attr:`MPCProblem.check_map`: arena, terminal, then speed rows)."""
        np.concatenate((x0, inputs.reshape(-1)), out=self._xu)
        out = self._eval @ self._z
        split, end = self._split
        states = out[:split].reshape(self._states_shape)
        halfspace = _vecdot(normals, out[split:end].reshape(self._positions_shape)) - offsets
        return states, halfspace, out[end:]

    def accept(
        self, solution: QPSolution, soft_rows: frozenset[str], x0: np.ndarray,
        normals: np.ndarray, offsets: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | str:
        """Inputs, states and excesses of an acceptable answer, or why it was rejected
        (``""``: the back end found none)."""
        if not solution.found or solution.inputs is None:
            return ""
        raw = solution.inputs
        # One reduction: the largest box violation max(u - high, low - u), which is also
        # the clip distance max|clip(u) - u|; NaN or inf for a non-finite entry.
        over = float(np.maximum.reduce(
            np.maximum(raw - self._u_high, self._u_low - raw), axis=None))
        if math.isnan(over) or over == math.inf:
            return "rejected: non-finite solution"
        if over > 0.0:
            inputs = np.minimum(np.maximum(raw, self._u_low), self._u_high)
            clipped = over
        else:
            inputs, clipped = np.array(raw), 0.0  # a copy: it becomes the stored plan
        if not clipped <= INPUT_CLIP_TOLERANCE:
            return f"rejected: input bound violated by {clipped:.3g}"
        states, halfspace, bounds = self.evaluate(x0, inputs, normals, offsets)
        k = normals.shape[0]
        # The back end's slacks describe its own inputs: after a clip beyond the
        # feasibility tolerance they are stale, and a soft row is allowed the violation of
        # the clipped plan itself (the slack reported is recomputed from the plan anyway).
        fresh = clipped <= FEASIBILITY_TOLERANCE
        excess_h, excess_b = halfspace, bounds
        if "halfspaces" in soft_rows and solution.halfspace_slack is not None:
            excess_h = halfspace - np.maximum(
                solution.halfspace_slack[:k] if fresh else halfspace, 0.0)
        if "bounds" in soft_rows and solution.bound_slack is not None:
            nb = self.n_bound  # the speed rows after them are always hard
            excess_b = bounds.copy()
            excess_b[:nb] -= np.maximum(solution.bound_slack if fresh else bounds[:nb], 0.0)
        worst = float(np.maximum.reduce(excess_b, initial=-np.inf))
        if k:
            worst = max(worst, float(np.maximum.reduce(excess_h, axis=None)))
        if not worst <= FEASIBILITY_TOLERANCE:  # False for NaN too
            return f"rejected: constraint violation {worst:.3g} > {FEASIBILITY_TOLERANCE:g}"
        return inputs, states, halfspace, bounds

    def cost(self, inputs: np.ndarray, states: np.ndarray, ref_states: np.ndarray,
             ref_inputs: np.ndarray | None) -> float:
        """:meth:`MPCProblem.cost` with the block-diagonal weights (two products);
        ``ref_inputs=None``: zeros."""
        du = inputs.reshape(-1) if ref_inputs is None else (inputs - ref_inputs).reshape(-1)
        total = du @ (self._R_block @ du)
        if self._has_state_cost:
            dx = (states[1:] - ref_states).reshape(-1)
            total += dx @ (self._Q_block @ dx)
        return float(total)

    @staticmethod
    def slack(halfspace: np.ndarray) -> np.ndarray:
        """Violations ``max(0, excess)``, entries <= SLACK_TOLERANCE set to 0."""
        return np.where(halfspace > SLACK_TOLERANCE, halfspace, 0.0)

    def bound_total(self, bounds: np.ndarray) -> float:
        """Total violation of the arena and terminal rows (not the speed rows after them),
        entries <= SLACK_TOLERANCE not counted."""
        bounds = bounds[: self.n_bound]
        if not np.maximum.reduce(bounds, initial=-np.inf) > SLACK_TOLERANCE:
            return 0.0
        return float(np.add.reduce(bounds[bounds > SLACK_TOLERANCE]))

r"""What the filter does when the hard QP is infeasible: a recovery QP, the paper's
shifted plan, braking.

**The recovery QPs** (:func:`recovery_problems`) minimise the violation of the
halfspace rows (exact L1 penalty :math:`\rho`), and then, with ``fallback="soft"``
(the default), the filter's own objective: the plan closest to the reference among the
least-violating ones. With ``fallback="brake"`` they minimise the speed instead:

.. math::

    \min_u \ \rho \sum_{i,t} s_{i,t} + \sum_{t=1}^{T} w_v \|v_t\|^2
        + \sum_{t=0}^{T-1} w_u \|u_t\|^2,

with :math:`v_t = N^\top x_t` the part of the state the position does not see (the
velocity of the double integrator), relative to zero, not to the obstacles; no
reference is tracked. The speed limit rows stay hard. The arena and terminal rows are
hard in the first recovery QP, and softened (same :math:`\rho`) in a second one only
when the first is infeasible (the ego outside the arena, or unable to stop inside it).
With :math:`\rho` above the multipliers the violation is the least possible; among the
plans that reach it, the slowest is chosen, so the recovery brakes rather than
accelerating to the input bound unless that lowers the violation. Braking is not the
default: in dense crossing streams (the stress class ``dense8``) a braking ego stays in
the lane of the next crossers (the measurements are in the filter guide, "Recovery and
statuses").

**The paper's Remark after Problem 2: shift the last plan, then brake.**

When the QP fails, the paper applies the next input of the last optimal plan,
shifting it once per failed step, :math:`u^*_j, \dots, u^*_{T-1}` after :math:`j`
consecutive failures, until it runs out; we pad the shifted plan with braking inputs
to the horizon length, and brake from the current state once no plan is left. This
is ``fallback="paper"`` of :class:`filters.mpc.MPCSafetyFilter`; braking is also the
last resort of ``fallback="soft"`` when the recovery QP fails too.

The shifted plan is replayed open loop: it is *not* checked against the new
halfspaces or the arena (the paper's rule, kept for reproduction).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.linalg

from filters.mpc.problem import MPCProblem

__all__ = ["RECOVERY_INPUT_WEIGHT", "RECOVERY_SPEED_WEIGHT", "recovery_problems"]

#: :math:`w_v`, weight of the planned speeds :math:`\|v_t\|^2` in the recovery QPs, per (m/s)².
RECOVERY_SPEED_WEIGHT = 1.0
#: :math:`w_u`, weight of the inputs :math:`\|u_t\|^2` in the recovery QPs, per (m/s²)²
#: (keeps them strictly convex; small, so that braking hard is cheap).
RECOVERY_INPUT_WEIGHT = 1e-2


def recovery_problems(problem: MPCProblem, braking: bool = False,
                      ) -> tuple[MPCProblem, MPCProblem]:
    """The two recovery QPs of ``problem`` (module docstring): halfspace rows soft and the
    arena and terminal rows hard; then every one of those rows soft. Same model, horizon,
    bounds, terminal set, rows and speed limit; ``problem``'s objective, or with
    ``braking`` the braking one (solved with zero reference states and inputs)."""
    if not braking:
        tracking = dataclasses.replace(problem, soft_rows=frozenset({"halfspaces"}))
        return tracking, tracking.with_soft_rows({"halfspaces", "bounds"})
    basis = scipy.linalg.null_space(problem.C)  # the velocity directions, (n, n - d)
    speed = RECOVERY_SPEED_WEIGHT * basis @ basis.T
    braking = dataclasses.replace(
        problem, objective="trajectory", Q=speed, Q_terminal=speed,
        R=RECOVERY_INPUT_WEIGHT * np.eye(problem.m), soft_rows=frozenset({"halfspaces"}))
    return braking, braking.with_soft_rows({"halfspaces", "bounds"})


def braking_gain(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    r"""Gain :math:`K` of the braking input :math:`u = \mathrm{clip}(-K x)`, shape ``(m, n)``.

    The "velocity" is the part of the state the output map does not see, :math:`v =
    N^\top x` with :math:`N` an orthonormal basis of :math:`\ker C`. Braking picks the
    input that brings the next velocity closest to zero, :math:`u = -(N^\top B)^+ N^\top
    A x`, clipped to the input box. For the double integrator (:math:`C = [I\ 0]`,
    ``B = [Ts²/2 I; Ts I]``) this is :math:`u = \mathrm{clip}(-v / T_s)`: the velocity is
    cancelled in one step if the bounds allow, else as fast as they allow, per axis.
    If ``C`` sees the whole state, braking is the input closest to zero.
    """
    basis = scipy.linalg.null_space(C)
    if basis.shape[1] == 0:
        return np.zeros((B.shape[1], A.shape[0]))
    return np.linalg.pinv(basis.T @ B, rcond=1e-10) @ (basis.T @ A)


def rollout_with_brake(
    A: np.ndarray, B: np.ndarray, x0: np.ndarray, prefix: np.ndarray, horizon: int,
    gain: np.ndarray, input_bounds: tuple[np.ndarray, np.ndarray],
) -> tuple[np.ndarray, np.ndarray]:
    """Apply ``prefix`` (``(j, m)``), then brake until ``horizon``; return inputs and states.

    Shapes ``(T, m)`` and ``(T + 1, n)``; braking is ``clip(-gain @ x, *input_bounds)``.
    """
    low, high = input_bounds
    inputs = np.empty((horizon, B.shape[1]))
    states = np.empty((horizon + 1, A.shape[0]))
    states[0] = x0
    for t in range(horizon):
        inputs[t] = prefix[t] if t < len(prefix) else np.clip(-gain @ states[t], low, high)
        states[t + 1] = A @ states[t] + B @ inputs[t]
    return inputs, states


def shifted_plan(plan: np.ndarray | None, failures: int) -> np.ndarray | None:
    """The stored plan shifted by ``failures`` steps, or ``None`` when it has run out.

    After ``j`` consecutive failures the plan gives :math:`u^*_j..u^*_{T-1}`; ``None``
    when there is no plan or ``j >= T`` (then brake).
    """
    if plan is None or failures > len(plan) - 1:
        return None
    return plan[failures:]

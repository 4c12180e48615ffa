r"""Compiled (numba) kernels of the filter's fast hard-QP step (:mod:`filters.mpc.fast`).

Private: :class:`filters.mpc.fast.FastHardStep` checks every shape and prepares the
constant arrays; these kernels do not check indices. Importing this module imports
numba (and loads the kernels from numba's on-disk cache, or compiles them), so nothing
imports it at ``import filters``.

Two calls per step, with the DAQP solve between them:

* :func:`prepare_step`: checks that the step's numbers are finite, forms the
  effective reference (for ``objective="first_input"`` the roll-out of :math:`u^r`), the
  **shortcut** (the unconstrained minimiser :math:`u^\circ`, accepted when it lies in the
  input box and meets every row exactly), and otherwise the whitened condensed QP's data
  of :mod:`filters.mpc.condensed`: :math:`f_z = F [x_0; X^r; u^r]`, the bounds of the
  fixed rows shifted by the free response :math:`\Phi x_0`, and every halfspace row
  :math:`a_{i,t}^\top W_t z \le b_{i,t} - a_{i,t}^\top C \Phi_t x_0` (unused rows
  ``0 @ z <= DISABLED_OFFSET``), written in place into the DAQP back end's arrays;
* :func:`accept_step`: the filter's acceptance check of a DAQP answer :math:`z`:
  :math:`u = U^{-\top} z`, clipped into the box (rejected beyond the clip tolerance),
  rolled out from :math:`x_0`, every halfspace, arena and terminal row checked to the
  feasibility tolerance; the cost (8) of the accepted plan.

The roll-outs run the dynamics step by step, :math:`x_{t+1} = A x_t + B u_t`, where the
general path multiplies by the stacked prediction matrices: the two agree to rounding.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from filters.mpc.fast import (
    ACCEPTED,
    INFEASIBLE,
    NON_FINITE,
    QP,
    REJECT_CLIP,
    REJECT_NON_FINITE,
    REJECT_VIOLATION,
    SHORTCUT,
    SOLVED,
)

_FLAGS = dict(cache=True, nogil=True, error_model="numpy")
_INLINE = dict(_FLAGS, inline="always")
# Sums in any order (vectorised partial sums, as in filters._kernels): the order is fixed
# when a kernel is compiled for this CPU, so a machine gives the same bits on every call.
_SUMS = dict(_FLAGS, fastmath={"reassoc"})


@njit(**_INLINE)
def _rollout(x0, u, A, B, states):
    """``states[t + 1] = A states[t] + B u_t`` from ``states[0] = x0``; ``u`` flat ``(T m,)``."""
    horizon = states.shape[0] - 1
    n, m = B.shape
    for i in range(n):
        states[0, i] = x0[i]
    for t in range(horizon):
        for i in range(n):
            total = 0.0
            for j in range(n):
                total += A[i, j] * states[t, j]
            for j in range(m):
                total += B[i, j] * u[t * m + j]
            states[t + 1, i] = total


@njit(**_INLINE)
def _positions(states, C):
    """``(T, d)`` positions :math:`y_t = C x_{t+1}`, ``t = 0..T-1``, of ``states`` ``(T+1, n)``."""
    horizon = states.shape[0] - 1
    d, n = C.shape
    position = np.empty((horizon, d))
    for t in range(horizon):
        for a in range(d):
            value = 0.0
            for j in range(n):
                value += C[a, j] * states[t + 1, j]
            position[t, a] = value
    return position


@njit(**_INLINE)
def _excess(states, normals, offsets, C, y_low, y_high, G, g, tolerance):
    r"""``(worst bound row, worst halfspace row, total bound violation above tolerance)``.

    Excess is ``lhs - rhs`` (<= 0: the row holds): the arena faces with a finite bound
    (:math:`C x_t - y_{high}`, :math:`y_{low} - C x_t`, ``t = 1..T``), the terminal rows
    :math:`G x_T - g`, the halfspace rows :math:`a_{i,t} \cdot C x_{t+1} - b_{i,t}`
    (``-inf`` when there is none). The total adds the bound excesses above
    ``tolerance``.
    """
    horizon = states.shape[0] - 1
    d, n = C.shape
    k = normals.shape[0]
    worst_bound = -np.inf
    worst_halfspace = -np.inf
    total = 0.0
    positions = _positions(states, C)
    for t in range(horizon):
        position = positions[t]
        for a in range(d):
            value = position[a]
            if y_high[a] < np.inf:
                e = value - y_high[a]
                worst_bound = max(worst_bound, e)
                total += e if e > tolerance else 0.0
            if y_low[a] > -np.inf:
                e = y_low[a] - value
                worst_bound = max(worst_bound, e)
                total += e if e > tolerance else 0.0
        for i in range(k):
            value = 0.0
            for a in range(d):
                value += normals[i, t, a] * position[a]
            worst_halfspace = max(worst_halfspace, value - offsets[i, t])
    for r in range(G.shape[0]):
        value = 0.0
        for j in range(n):
            value += G[r, j] * states[horizon, j]
        e = value - g[r]
        worst_bound = max(worst_bound, e)
        total += e if e > tolerance else 0.0
    return worst_bound, worst_halfspace, total


@njit(**_INLINE)
def _cost(u, states, x_ref, u_ref, R_w, Q_w, state_cost):
    r""":math:`\sum_t (u_t - u^r_t)^\top R_t (u_t - u^r_t) + \sum_{t \ge 1} (x_t - x^r_t)^\top
    Q_t (x_t - x^r_t)` (the state terms only with ``state_cost``)."""
    horizon, m = u_ref.shape
    n = states.shape[1]
    total = 0.0
    for t in range(horizon):
        for a in range(m):
            da = u[t * m + a] - u_ref[t, a]
            for b in range(m):
                total += da * R_w[t, a, b] * (u[t * m + b] - u_ref[t, b])
    if state_cost:
        for t in range(horizon):
            for a in range(n):
                da = states[t + 1, a] - x_ref[t, a]
                for b in range(n):
                    total += da * Q_w[t, a, b] * (states[t + 1, b] - x_ref[t, b])
    return total


@njit(**_INLINE)
def _finite(array):
    for value in array.ravel():
        if not math.isfinite(value):
            return False
    return True


@njit(**_SUMS)
def prepare_step(x0, ref_states, u_ref, normals, offsets, shortcut, state_cost,
                 A, B, C, gain, F, W, u_low, u_high, y_low, y_high, G, g,
                 input_axes, arena_axes, fixed_upper, fixed_lower, disabled, slack_tolerance,
                 R_w, Q_w, x_ref, u, states, f, qp_A, qp_AT, upper, lower, scratch, info,
                 write_A):
    r"""The shortcut, or the QP data of one step (module docstring).

    Inputs: ``x0`` ``(n,)``; ``ref_states`` ``(T + 1, n)`` (row 0 unused); ``u_ref``
    ``(T, m)``; ``normals`` ``(k, T, d)``, ``offsets`` ``(k, T)``, ``k <= K``;
    ``shortcut`` (try it); ``state_cost`` (``objective="trajectory"``). Constants: the
    model; ``gain`` ``(T m, T n)``; ``F`` ``(T m, n + T n + T m)``; ``W`` ``(T, d, T m)``;
    the boxes (``±inf`` for a free side); ``G``, ``g``; the axes of the input and arena
    rows; the fixed rows' unshifted bounds; the unused rows' offset; the weights
    ``R_w`` ``(T, m, m)``, ``Q_w`` ``(T, n, n)``.

    Outputs: ``x_ref`` ``(T, n)`` the effective reference states; with the shortcut
    ``u`` ``(T m,)``, ``states`` ``(T + 1, n)`` and ``info[0]`` its cost; otherwise
    ``f`` ``(T m,)``, the DAQP arrays ``qp_A`` ``(n_fixed + K T, T m)`` (only its
    halfspace rows are written, and only with ``write_A``), ``upper`` and ``lower``, and
    (unless it is empty) the ``k`` used halfspace rows of each step into the transposed
    rows ``qp_AT``, compactly: row ``i < k`` of step ``t`` into column
    ``n_fixed + t k + i`` (the ``K - k`` unused rows per step, ``0 @ z <= disabled``, are
    left out; see :func:`hard_step`).
    ``scratch`` ``(n + T n + T m,)``.

    Returns :data:`NON_FINITE` (some input is NaN or infinite: nothing is written),
    :data:`SHORTCUT` or :data:`QP`.
    """
    horizon, m = u_ref.shape
    n = x0.shape[0]
    d = C.shape[0]
    k = normals.shape[0]
    K = (qp_A.shape[0] - fixed_upper.shape[0]) // horizon
    n_fixed = fixed_upper.shape[0]
    nu = horizon * m
    if not (_finite(x0) and _finite(ref_states) and _finite(u_ref) and _finite(normals)
            and _finite(offsets)):
        return NON_FINITE
    # the effective reference: the given states, or (first_input) the roll-out of u^r
    if state_cost:
        for t in range(horizon):
            for i in range(n):
                x_ref[t, i] = ref_states[t + 1, i]
    else:
        _rollout(x0, u_ref.ravel(), A, B, states)
        for t in range(horizon):
            for i in range(n):
                x_ref[t, i] = states[t + 1, i]
    if shortcut:  # the unconstrained minimiser u = u^r + K (X^r - Phi x0 - Gamma u^r)
        flat = u_ref.ravel()
        for j in range(nu):
            u[j] = flat[j]
        if state_cost:
            _rollout(x0, flat, A, B, states)
            for j in range(nu):
                total = 0.0
                for t in range(horizon):
                    for i in range(n):
                        total += gain[j, t * n + i] * (x_ref[t, i] - states[t + 1, i])
                u[j] = flat[j] + total
        inside = True
        for t in range(horizon):
            for a in range(m):
                inside &= u_low[a] <= u[t * m + a] <= u_high[a]
        if inside:
            _rollout(x0, u, A, B, states)
            worst_bound, worst_halfspace, _ = _excess(states, normals, offsets, C, y_low,
                                                      y_high, G, g, slack_tolerance)
            if worst_bound <= 0.0 and worst_halfspace <= 0.0:
                info[0] = _cost(u, states, x_ref, u_ref, R_w, Q_w, state_cost)
                return SHORTCUT
    # f_z = F [x0; X^r; u^r]
    for i in range(n):
        scratch[i] = x0[i]
    for t in range(horizon):
        for i in range(n):
            scratch[n + t * n + i] = x_ref[t, i]
    flat = u_ref.ravel()
    for j in range(nu):
        scratch[n + horizon * n + j] = flat[j]
    skip = n if state_cost else n + horizon * n  # first_input: F's X^r block is zero
    for r in range(nu):
        total = 0.0
        for c in range(n):
            total += F[r, c] * scratch[c]
        for c in range(skip, scratch.shape[0]):
            total += F[r, c] * scratch[c]
        f[r] = total
    # the free response x^0_t = A^t x0 (into states), its positions and the shifted bounds
    zero = np.zeros(nu)
    _rollout(x0, zero, A, B, states)
    row = horizon * input_axes.shape[0]
    for r in range(row):  # input rows: no shift
        upper[r] = fixed_upper[r]
        lower[r] = fixed_lower[r]
    position = _positions(states, C)
    for t in range(horizon):  # arena rows, step-major
        for a in arena_axes:
            upper[row] = fixed_upper[row] - position[t, a]
            lower[row] = fixed_lower[row] - position[t, a]
            row += 1
    for r in range(G.shape[0]):  # terminal rows
        value = 0.0
        for j in range(n):
            value += G[r, j] * states[horizon, j]
        upper[row] = fixed_upper[row] - value
        lower[row] = fixed_lower[row] - value
        row += 1
    # halfspace rows, step-major: a' W_t z <= b - a' C Phi_t x0
    transposed = qp_AT.shape[0] > 0
    row = np.empty(nu)
    for t in range(horizon):
        for i in range(K):
            q = n_fixed + t * K + i
            lower[q] = -np.inf
            if i < k:
                shift = 0.0
                for a in range(d):
                    shift += normals[i, t, a] * position[t, a]
                upper[q] = offsets[i, t] - shift
                for c in range(nu):
                    row[c] = normals[i, t, 0] * W[t, 0, c]
                for a in range(1, d):
                    weight = normals[i, t, a]
                    for c in range(nu):
                        row[c] += weight * W[t, a, c]
            else:
                upper[q] = disabled
                for c in range(nu):
                    row[c] = 0.0
            if write_A:
                for c in range(nu):
                    qp_A[q, c] = row[c]
            if transposed and i < k:  # compact: the step's k used rows only
                column = n_fixed + t * k + i
                for c in range(nu):
                    qp_AT[c, column] = row[c]
    return QP


@njit(**_INLINE)
def _row_excess(states, normals, offsets, C, y_low, y_high, G, g, halfspace, bounds):
    """Excess ``lhs - rhs`` of every row, in the filter's order: ``halfspace`` ``(k, T)``;
    ``bounds``: the upper arena faces with a finite bound (by step, then axis), the lower
    faces, the terminal rows."""
    horizon = states.shape[0] - 1
    d, n = C.shape
    k = normals.shape[0]
    position = _positions(states, C)
    for t in range(horizon):
        for i in range(k):
            value = 0.0
            for a in range(d):
                value += normals[i, t, a] * position[t, a]
            halfspace[i, t] = value - offsets[i, t]
    row = 0
    for t in range(horizon):
        for a in range(d):
            if y_high[a] < np.inf:
                bounds[row] = position[t, a] - y_high[a]
                row += 1
    for t in range(horizon):
        for a in range(d):
            if y_low[a] > -np.inf:
                bounds[row] = y_low[a] - position[t, a]
                row += 1
    for r in range(G.shape[0]):
        value = 0.0
        for j in range(n):
            value += G[r, j] * states[horizon, j]
        bounds[row] = value - g[r]
        row += 1


@njit(**_SUMS)
def accept_step(z, x0, x_ref, u_ref, normals, offsets, state_cost, soft_halfspaces,
                soft_bounds, u_of_z, A, B, C, u_low, u_high, y_low, y_high, G, g,
                clip_tolerance, feasibility_tolerance, slack_tolerance, R_w, Q_w, u, states,
                halfspace, bounds, allow_halfspace, allow_bounds, info):
    r"""The acceptance check of a DAQP answer ``z`` (module docstring).

    :math:`u = U^{-\top} z` must be finite and within ``clip_tolerance`` of the input box
    (it is clipped into it); the roll-out of the clipped inputs must meet every row to
    ``feasibility_tolerance``. A soft row (``soft_halfspaces``, ``soft_bounds``) is
    allowed the violation of the unclipped answer (DAQP's slack), or, when the clip
    moved an input by more than ``feasibility_tolerance`` (DAQP's slacks are then stale),
    its own violation: the filter's ``_accept``.

    Writes ``u`` ``(T m,)`` (the clipped inputs), ``states`` ``(T + 1, n)``, the rows'
    excess at them ``halfspace`` ``(k, T)`` and ``bounds`` (the filter's order; used
    with soft rows, and as scratch: ``allow_*`` likewise), and ``info``: ``[cost,
    clipped, worst excess, total bound violation above slack_tolerance]``. Returns
    :data:`ACCEPTED`, :data:`REJECT_NON_FINITE` (``u`` not finite), :data:`REJECT_CLIP`
    (``info[1]`` beyond ``clip_tolerance``) or :data:`REJECT_VIOLATION` (``info[2]``
    beyond ``feasibility_tolerance``, or NaN).
    """
    horizon, m = u_ref.shape
    nu = horizon * m
    finite = True
    clipped = 0.0
    for r in range(nu):  # u = U^{-T} z (lower triangular)
        total = 0.0
        for c in range(r + 1):
            total += u_of_z[r, c] * z[c]
        finite &= math.isfinite(total)
        u[r] = total
    if not finite:
        return REJECT_NON_FINITE
    soft = soft_halfspaces or soft_bounds
    fresh = True
    if soft:  # the rows' excess at the unclipped answer: the soft rows' allowance
        _rollout(x0, u, A, B, states)
        _row_excess(states, normals, offsets, C, y_low, y_high, G, g, allow_halfspace,
                    allow_bounds)
    for r in range(nu):
        a = r % m
        value = min(max(u[r], u_low[a]), u_high[a])
        clipped = max(clipped, abs(value - u[r]))
        u[r] = value
    info[1] = clipped
    if not clipped <= clip_tolerance:
        return REJECT_CLIP
    fresh = clipped <= feasibility_tolerance
    _rollout(x0, u, A, B, states)
    if soft:
        _row_excess(states, normals, offsets, C, y_low, y_high, G, g, halfspace, bounds)
        worst = -np.inf
        total = 0.0
        for i in range(halfspace.shape[0]):
            for t in range(horizon):
                e = halfspace[i, t]
                if soft_halfspaces:
                    e -= max(allow_halfspace[i, t] if fresh else e, 0.0)
                worst = max(worst, e)
        for r in range(bounds.shape[0]):
            e = bounds[r]
            total += e if e > slack_tolerance else 0.0
            if soft_bounds:
                e -= max(allow_bounds[r] if fresh else e, 0.0)
            worst = max(worst, e)
    else:
        worst_bound, worst_halfspace, total = _excess(states, normals, offsets, C, y_low,
                                                      y_high, G, g, slack_tolerance)
        worst = max(worst_bound, worst_halfspace)
    info[2] = worst
    info[3] = total
    if not worst <= feasibility_tolerance:
        return REJECT_VIOLATION
    info[0] = _cost(u, states, x_ref, u_ref, R_w, Q_w, state_cost)
    return ACCEPTED


# --------------------------------------------------------------------------- the hard QP


@njit(**_INLINE)
def _rotate_rows(M, i, j, c, s, start):
    """Rows ``i``, ``j`` of ``M`` (columns ``start:``): ``(c x + s y, -s x + c y)``."""
    for k in range(start, M.shape[1]):
        x = M[i, k]
        y = M[j, k]
        M[i, k] = c * x + s * y
        M[j, k] = -s * x + c * y


@njit(**_SUMS)
def ldp_solve(AT, upper, lower, f, z, tolerance, max_iterations):
    r"""Goldfarb-Idnani's dual active-set method on every row of ``AT`` (:func:`ldp_rows`)."""
    return ldp_rows(AT, AT.shape[1], upper, lower, f, z, tolerance, max_iterations)


@njit(**_SUMS)
def ldp_rows(AT, n_rows, upper, lower, f, z, tolerance, max_iterations):
    r"""Goldfarb-Idnani's dual active-set method for the whitened QP (identity Hessian).

    .. math:: \min_z \tfrac12 \|z\|^2 + f^\top z \quad \text{s.t.} \quad
        l_j \le a_j^\top z \le u_j \ \text{for every row } j \text{ of } A

    (``±inf`` for a free side). From the unconstrained minimiser :math:`z = -f`, the
    most violated row (by more than ``tolerance``) enters; a full step makes it active, a
    partial step drops the active row whose multiplier reaches zero first, so the
    multipliers stay nonnegative (dual feasible) throughout: the first point that meets
    every row is the optimum. The active rows' normals are kept as :math:`N = J R`
    (``J`` orthogonal, stored transposed; ``R`` upper triangular), updated by Givens
    rotations (Goldfarb and Idnani 1983, with :math:`H = I` so that :math:`J = Q`).

    The rows come transposed, ``AT`` ``(T m, >= n_rows)``, of which the first ``n_rows``
    columns are the QP's rows (the rows' values at ``z`` are then vectorised sums over
    the rows), with their bounds ``upper``, ``lower`` ``(>= n_rows,)``. Writes ``z``;
    returns ``(status, iterations)``: status 1 solved, -1 infeasible (a violated row that
    no step can satisfy), -4 ``max_iterations`` reached.
    """
    nu = f.shape[0]
    values = np.empty(n_rows)
    JT = np.zeros((nu, nu))  # row i: column i of J
    R = np.zeros((nu, nu))
    for i in range(nu):
        JT[i, i] = 1.0
        z[i] = -f[i]
    active = np.empty(nu, dtype=np.int64)
    lam = np.empty(nu)
    state = np.zeros(n_rows, dtype=np.int8)  # 1: upper side active, -1: lower side
    d = np.empty(nu)
    step = np.empty(nu)
    r = np.empty(nu)
    q = 0
    iterations = 0
    while True:
        # the most violated row
        worst = tolerance
        p = -1
        side = 0.0
        for j in range(n_rows):
            values[j] = 0.0
        for c in range(nu):
            zc = z[c]
            for j in range(n_rows):
                values[j] += AT[c, j] * zc
        for j in range(n_rows):
            value = values[j]
            if value - upper[j] > worst and state[j] != 1:
                worst = value - upper[j]
                p = j
                side = 1.0
            if lower[j] - value > worst and state[j] != -1:
                worst = lower[j] - value
                p = j
                side = -1.0
        if p < 0:
            return 1, iterations
        norm2 = 0.0
        for c in range(nu):
            norm2 += AT[c, p] * AT[c, p]
        lam_p = 0.0
        while True:  # until row p is active
            iterations += 1
            if iterations > max_iterations:
                return -4, iterations
            # d = J' n with n = -side a_p (the row as n' z >= -side bound)
            for i in range(nu):
                total = 0.0
                for c in range(nu):
                    total += JT[i, c] * AT[c, p]
                d[i] = -side * total
            # primal direction J2 d2, dual direction r = R^{-1} d1
            free2 = 0.0
            for c in range(nu):
                step[c] = 0.0
            for i in range(q, nu):
                free2 += d[i] * d[i]
                for c in range(nu):
                    step[c] += JT[i, c] * d[i]
            for i in range(q - 1, -1, -1):
                total = d[i]
                for k in range(i + 1, q):
                    total -= R[i, k] * r[k]
                r[i] = total / R[i, i]
            partial = np.inf
            drop = -1
            for i in range(q):
                if r[i] > 0.0 and max(lam[i], 0.0) / r[i] < partial:
                    partial = max(lam[i], 0.0) / r[i]
                    drop = i
            full = np.inf
            if free2 > 1e-12 * norm2:
                value = 0.0
                for c in range(nu):
                    value += AT[c, p] * z[c]
                violation = value - upper[p] if side > 0.0 else lower[p] - value
                full = violation / free2
            if partial == np.inf and full == np.inf:
                return -1, iterations
            t = min(partial, full)
            if full < np.inf:
                for c in range(nu):
                    z[c] += t * step[c]
            for i in range(q):
                lam[i] -= t * r[i]
            lam_p += t
            if full <= partial:  # row p becomes active: rotate d[q+1:] into d[q]
                for i in range(nu - 1, q, -1):
                    if d[i] != 0.0:
                        h = math.hypot(d[i - 1], d[i])
                        c_ = d[i - 1] / h
                        s_ = d[i] / h
                        d[i - 1] = h
                        d[i] = 0.0
                        _rotate_rows(JT, i - 1, i, c_, s_, 0)
                for i in range(q + 1):
                    R[i, q] = d[i]
                active[q] = p
                lam[q] = lam_p
                state[p] = 1 if side > 0.0 else -1
                q += 1
                break
            # drop the active row whose multiplier reached zero, restore R's triangle
            state[active[drop]] = 0
            for i in range(drop, q - 1):
                active[i] = active[i + 1]
                lam[i] = lam[i + 1]
                for k in range(q):
                    R[k, i] = R[k, i + 1]
            q -= 1
            for i in range(drop, q):
                a = R[i, i]
                b = R[i + 1, i]
                if b != 0.0:
                    h = math.hypot(a, b)
                    c_ = a / h
                    s_ = b / h
                    _rotate_rows(R, i, i + 1, c_, s_, i)
                    R[i + 1, i] = 0.0
                    _rotate_rows(JT, i, i + 1, c_, s_, 0)


@njit(**_SUMS)
def hard_step(x0, ref_states, u_ref, normals, offsets, shortcut, u, states, state_cost,
              A, B, C, gain, F, W, u_low, u_high, y_low, y_high, G, g,
              input_axes, arena_axes, fixed_upper, fixed_lower, disabled, slack_tolerance,
              R_w, Q_w, u_of_z, clip_tolerance, feasibility_tolerance, primal_tolerance,
              max_iterations, x_ref, f, qp_A, qp_AT, upper, lower, scratch, z, info):
    """One hard step in one call: :func:`prepare_step` (the rows into ``qp_AT`` only),
    then (when the shortcut does not answer) :func:`ldp_solve` on the QP data just
    written and :func:`accept_step` of its answer.

    Returns :data:`NON_FINITE`, :data:`SHORTCUT`, :data:`SOLVED` (``u``, ``states`` and
    ``info`` hold the accepted answer; ``info[4]`` the iterations), :data:`INFEASIBLE`
    (the solver found the QP infeasible) or :data:`QP` (it stopped, or its answer was
    rejected). DAQP's row matrix ``qp_A`` is not written (see
    :meth:`filters.mpc.fast.FastHardStep.write_daqp_rows`: ``qp_AT`` holds the used rows
    compactly); ``upper``, ``lower`` and ``f`` are, in DAQP's full layout.
    """
    code = prepare_step(x0, ref_states, u_ref, normals, offsets, shortcut, state_cost,
                        A, B, C, gain, F, W, u_low, u_high, y_low, y_high, G, g,
                        input_axes, arena_axes, fixed_upper, fixed_lower, disabled,
                        slack_tolerance, R_w, Q_w, x_ref, u, states, f, qp_A, qp_AT, upper,
                        lower, scratch, info, False)
    if code != QP:
        return code
    # The solver sees the used rows only: the fixed rows, then per step the k used
    # halfspace rows, in the full layout's order (so the same row wins every choice of
    # the most violated one; an unused row, 0 @ z <= disabled, is never violated).
    horizon = u_ref.shape[0]
    k = normals.shape[0]
    n_fixed = fixed_upper.shape[0]
    K = (upper.shape[0] - n_fixed) // horizon
    n_rows = n_fixed + horizon * k
    used_upper = np.empty(n_rows)
    used_lower = np.empty(n_rows)
    for r in range(n_fixed):
        used_upper[r] = upper[r]
        used_lower[r] = lower[r]
    for t in range(horizon):
        for i in range(k):
            used_upper[n_fixed + t * k + i] = upper[n_fixed + t * K + i]
            used_lower[n_fixed + t * k + i] = lower[n_fixed + t * K + i]
    status, iterations = ldp_rows(qp_AT, n_rows, used_upper, used_lower, f, z,
                                  primal_tolerance, max_iterations)
    info[4] = iterations
    if status == -1:
        return INFEASIBLE
    if status != 1:
        return QP
    empty2 = np.empty((0, 0))
    empty1 = np.empty(0)
    accepted = accept_step(z, x0, x_ref, u_ref, normals, offsets, state_cost, False, False,
                           u_of_z, A, B, C, u_low, u_high, y_low, y_high, G, g,
                           clip_tolerance, feasibility_tolerance, slack_tolerance, R_w, Q_w,
                           u, states, empty2, empty1, empty2, empty1, info)
    return SOLVED if accepted == ACCEPTED else QP

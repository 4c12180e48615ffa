r"""Compiled (numba) primal-dual interior-point method for the filter's soft QP, by Riccati.

Private: :class:`filters.mpc.backends.riccati.RiccatiBackend` checks every shape and
builds the rows; this kernel does not check indices. Importing this module imports
numba (and loads the kernel from numba's on-disk cache, or compiles it).

The QP (every row soft, the exact L1 penalty; the input box hard):

.. math::

    \min_{u, s}\; \sum_{t=0}^{T-1} (u_t - u^r_t)^\top R_t (u_t - u^r_t)
        + \sum_{t=1}^{T} (x_t - x^r_t)^\top Q_t (x_t - x^r_t) + \rho \sum_j s_j

    \text{s.t. } x_{t+1} = A x_t + B u_t,\quad x_0 \text{ given},\quad
    a_j^\top x_{\tau_j} \le b_j + s_j,\quad s_j \ge 0,\quad
    \underline u \le u_t \le \overline u,

one row :math:`j` per halfspace, arena face and terminal row (:math:`a_j \in
\mathbb{R}^n` acts on the state of its step :math:`\tau_j \in 1..T`). The iterates
always satisfy the dynamics (the states are the roll-out of the inputs), so the only
primal unknowns are :math:`u` and :math:`s`. Each row has two inequalities,
:math:`t_j = b_j + s_j - a_j^\top x_{\tau_j} \ge 0` (dual :math:`y_j`) and
:math:`s_j \ge 0` (dual :math:`z_j`), with :math:`y_j + z_j = \rho` at a stationary
point; each finite input bound one, :math:`u - \underline u \ge 0` and
:math:`\overline u - u \ge 0`.

A Newton step of the perturbed KKT conditions (Mehrotra's predictor-corrector, one
step length for primal and dual) eliminates, row by row, :math:`\Delta s`,
:math:`\Delta t`, :math:`\Delta z` and :math:`\Delta y = \sigma_j (a_j^\top \Delta
x_{\tau_j} + \beta_j)` with :math:`\sigma_j = 1 / (t_j / y_j + s_j / z_j)`, and the
input bounds likewise. What is left is an LQ problem in :math:`\Delta u` with stage
weights :math:`2 Q_t + \sum_{\tau_j = t} \sigma_j a_j a_j^\top` and :math:`2 R_t +`
(diagonal), solved by a Riccati recursion: ``O(T (n^3 + m^3) + rows n^2)`` work per
iteration, linear in the horizon and in the rows. The predictor and the corrector share
one factorisation, and each iteration reads the rows three times: (1) the last step,
the residuals, the weights and the predictor's linear term; (2) the predictor's
directions, with the corrector's linear term accumulated as ``base + target x slope``
(it is affine in Mehrotra's centring target, known only after this pass); (3) the
corrector's directions and the step length.

Numerics: the row weight carries a dual regularisation, :math:`\sigma_j = 1 / (t_j / y_j
+ s_j / z_j + 10^{-7} / \rho)`, in the Newton matrix only (the residuals are exact, so
the limit is the QP's optimum); without it the Riccati pivots lost positive
definiteness to cancellation in the last iterations, where a row active at its kink has
:math:`t_j, s_j \to 0`. The start puts every row 10 m inside both of its inequalities
(:math:`s_j = \max(a_j^\top x_{\tau_j} - b_j, 0) + 10`) with :math:`t_j y_j = s_j z_j`;
on the scaling grid's recovery QPs starts of 3-30 m took the same iterations, 0.1-0.3 m
two to three times as many.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_FLAGS = dict(cache=True, nogil=True, error_model="numpy")

#: Status codes of :func:`solve_soft_qp`.
SOLVED, MAX_ITERATIONS, NUMERICAL, ALMOST_SOLVED = 0, 1, 2, 3

_STEP_FRACTION = 0.995  # of the way to the boundary of the positive orthant
# The reduced accuracy reported as ALMOST_SOLVED when the iterations run out or the
# factorisation breaks down before the full one (Clarabel's reduced tolerances are 5e-5).
_LOOSE = 1e-6
_INITIAL_SLACK = 10.0  # m inside each row's two inequalities at the start
_REGULARIZATION = 1e-7  # times 1 / rho: the dual regularisation of the row weights


@njit(**_FLAGS, inline="always")
def _advance(A, B, x, u, t, n, m):
    """``x[t + 1] = A x[t] + B u[t]``."""
    for i in range(n):
        acc = 0.0
        for k in range(n):
            acc += A[i, k] * x[t, k]
        for k in range(m):
            acc += B[i, k] * u[t, k]
        x[t + 1, i] = acc


@njit(**_FLAGS)
def _rollout(A, B, x0, u, x, nt, mt):
    """``x[t + 1] = A x[t] + B u[t]`` from ``x[0] = x0``."""
    n, m = len(nt), len(mt)
    x[0, :] = x0
    for t in range(u.shape[0]):
        _advance(A, B, x, u, t, n, m)


@njit(**_FLAGS)
def _factor(A, B, Hx, Hu, L, M, K, nt, mt):
    """Riccati factorisation of the LQ problem with stage weights ``Hx`` (steps 1..T at
    ``Hx[1:]``) and ``Hu`` (steps 0..T-1).

    Writes, for ``t = T-1..0``: ``L[t]`` the Cholesky factor of
    :math:`S_t = H^u_t + B^\top P_{t+1} B`, ``M[t]`` :math:`= B^\top P_{t+1} A` and the gain
    ``K[t]`` :math:`= -S_t^{-1} M_t`. Returns ``False`` if some :math:`S_t` is not
    positive definite (numerically).
    """
    T = Hu.shape[0]
    n, m = len(nt), len(mt)
    P = Hx[T].copy()
    PA = np.empty((n, n))
    PB = np.empty((n, m))
    S = np.empty((m, m))
    for t in range(T - 1, -1, -1):
        for i in range(n):
            for j in range(n):
                acc = 0.0
                for k in range(n):
                    acc += P[i, k] * A[k, j]
                PA[i, j] = acc
            for j in range(m):
                acc = 0.0
                for k in range(n):
                    acc += P[i, k] * B[k, j]
                PB[i, j] = acc
        for i in range(m):
            for j in range(m):
                acc = Hu[t, i, j]
                for k in range(n):
                    acc += B[k, i] * PB[k, j]
                S[i, j] = acc
            for j in range(n):
                acc = 0.0
                for k in range(n):
                    acc += B[k, i] * PA[k, j]
                M[t, i, j] = acc
        # Cholesky S = L L'
        for j in range(m):
            d = S[j, j]
            for k in range(j):
                d -= L[t, j, k] * L[t, j, k]
            if not d > 0.0:
                return False
            d = math.sqrt(d)
            L[t, j, j] = d
            for i in range(j + 1, m):
                acc = S[i, j]
                for k in range(j):
                    acc -= L[t, i, k] * L[t, j, k]
                L[t, i, j] = acc / d
            for i in range(j):
                L[t, i, j] = 0.0
        # K = -S^{-1} M, column by column
        for c in range(n):
            for i in range(m):
                acc = M[t, i, c]
                for k in range(i):
                    acc -= L[t, i, k] * K[t, k, c]
                K[t, i, c] = acc / L[t, i, i]
            for i in range(m - 1, -1, -1):
                acc = K[t, i, c]
                for k in range(i + 1, m):
                    acc -= L[t, k, i] * K[t, k, c]
                K[t, i, c] = acc / L[t, i, i]
            for i in range(m):
                K[t, i, c] = -K[t, i, c]
        if t == 0:
            break
        # P_t = Hx_t + A' P A + M' K
        for i in range(n):
            for j in range(n):
                acc = Hx[t, i, j]
                for k in range(n):
                    acc += A[k, i] * PA[k, j]
                for k in range(m):
                    acc += M[t, k, i] * K[t, k, j]
                P[i, j] = acc
        for i in range(n):  # symmetrise against drift
            for j in range(i + 1, n):
                v = 0.5 * (P[i, j] + P[j, i])
                P[i, j] = v
                P[j, i] = v
    return True


@njit(**_FLAGS)
def _solve(A, B, L, M, K, gx, gu, du, dx, nt, mt):
    r"""The LQ step with linear terms ``gx`` (steps 1..T at ``gx[1:]``) and ``gu``.

    Backward: :math:`k_t = -S_t^{-1}(g^u_t + B^\top p_{t+1})`, :math:`p_t = g^x_t +
    A^\top p_{t+1} + M_t^\top k_t`; forward from :math:`\Delta x_0 = 0`:
    :math:`\Delta u_t = K_t \Delta x_t + k_t`. ``du`` holds the :math:`k_t` in between.
    """
    T = gu.shape[0]
    n, m = len(nt), len(mt)
    p = gx[T].copy()
    p_new = np.empty(n)
    for t in range(T - 1, -1, -1):
        for i in range(m):  # rhs = -(gu + B' p)
            acc = gu[t, i]
            for k in range(n):
                acc += B[k, i] * p[k]
            du[t, i] = -acc
        for i in range(m):  # L L' k = rhs
            acc = du[t, i]
            for k in range(i):
                acc -= L[t, i, k] * du[t, k]
            du[t, i] = acc / L[t, i, i]
        for i in range(m - 1, -1, -1):
            acc = du[t, i]
            for k in range(i + 1, m):
                acc -= L[t, k, i] * du[t, k]
            du[t, i] = acc / L[t, i, i]
        if t == 0:
            break
        for i in range(n):
            acc = gx[t, i]
            for k in range(n):
                acc += A[k, i] * p[k]
            for k in range(m):
                acc += M[t, k, i] * du[t, k]
            p_new[i] = acc
        p[:] = p_new
    for i in range(n):
        dx[0, i] = 0.0
    for t in range(T):
        for i in range(m):
            acc = du[t, i]
            for k in range(n):
                acc += K[t, i, k] * dx[t, k]
            du[t, i] = acc
        _advance(A, B, dx, du, t, n, m)


@njit(**_FLAGS)
def solve_soft_qp(A, B, R2, Q2, x0, u_ref, x_ref, lo, hi, ra, rt, rb, rho, tolerance,
                  max_iterations, u, s, nt, mt):
    r"""Solve the soft QP (module docstring); write the inputs ``u`` and slacks ``s``.

    Parameters
    ----------
    A, B
        Dynamics ``(n, n)``, ``(n, m)``.
    R2, Q2
        :math:`2 R_t` ``(T, m, m)`` and :math:`2 Q_t` for the states ``x_1..x_T``
        ``(T, n, n)``.
    x0, u_ref, x_ref
        Initial state ``(n,)``, reference inputs ``(T, m)`` and states ``x^r_1..x^r_T``
        ``(T, n)``.
    lo, hi
        Input box ``(m,)`` (``±inf`` for a free side).
    ra, rt, rb
        The rows :math:`a_j^\top x_{\tau_j} \le b_j + s_j`: ``(M, n)``, step ``(M,)``
        (int, in ``1..T``), ``(M,)``.
    rho
        The L1 penalty :math:`\rho > 0` per unit of slack.
    tolerance
        Relative accuracy of the residuals and of the duality gap.
    max_iterations
        Iterations before giving up.
    u, s
        Outputs ``(T, m)`` and ``(M,)``.

    Returns
    -------
    (status, iterations)
        ``SOLVED``, ``MAX_ITERATIONS`` or ``NUMERICAL`` (a non-positive-definite pivot or a
        non-finite iterate), and the iterations taken.
    """
    T = u_ref.shape[0]
    n, m = len(nt), len(mt)
    rows = rb.shape[0]
    has_lo = np.empty(m, dtype=np.bool_)
    has_hi = np.empty(m, dtype=np.bool_)
    for i in range(m):
        has_lo[i] = math.isfinite(lo[i])
        has_hi[i] = math.isfinite(hi[i])
    # ---- starting point: the reference inputs pulled into the box, each row centred
    for t in range(T):
        for i in range(m):
            v = u_ref[t, i]
            if has_lo[i] and has_hi[i]:
                margin = 1e-2 * (hi[i] - lo[i])
                v = min(max(v, lo[i] + margin), hi[i] - margin)
            elif has_lo[i]:
                v = max(v, lo[i] + 1.0)
            elif has_hi[i]:
                v = min(v, hi[i] - 1.0)
            u[t, i] = v
    x = np.empty((T + 1, n))
    _rollout(A, B, x0, u, x, nt, mt)
    ta = np.empty(rows)
    ya = np.empty(rows)
    zs = np.empty(rows)
    a_max = np.zeros(rows)  # max_k |a_jk|, for the scale of the dual residual
    mu0 = 0.0
    scale_b = 1.0
    for j in range(rows):
        acc = -rb[j]
        for k in range(n):
            acc += ra[j, k] * x[rt[j], k]
        s[j] = max(acc, 0.0) + _INITIAL_SLACK
        ta[j] = s[j] - acc
        ya[j] = rho * s[j] / (s[j] + ta[j])  # t y = s z
        zs[j] = rho - ya[j]
        for k in range(n):
            a_max[j] = max(a_max[j], abs(ra[j, k]))
        mu0 += ta[j] * ya[j]
        scale_b = max(scale_b, abs(rb[j]))
    mu0 = mu0 / rows if rows else 1.0
    n_pairs = 2 * rows
    tl = np.ones((T, m))
    th = np.ones((T, m))
    yl = np.zeros((T, m))
    yh = np.zeros((T, m))
    for t in range(T):
        for i in range(m):
            if has_lo[i]:
                tl[t, i] = u[t, i] - lo[i]
                yl[t, i] = max(mu0 / tl[t, i], 1.0)
                n_pairs += 1
            if has_hi[i]:
                th[t, i] = hi[i] - u[t, i]
                yh[t, i] = max(mu0 / th[t, i], 1.0)
                n_pairs += 1
    n_pairs = max(n_pairs, 1)
    # ---- work arrays
    Hx = np.empty((T + 1, n, n))
    Hu = np.empty((T, m, m))
    gx0 = np.zeros((T + 1, n))  # the Lagrangian's state gradient at the iterate
    gx = np.zeros((T + 1, n))  # the linear term of the LQ step
    g_base = np.zeros((T + 1, n))  # the corrector's: gx0 + g_base + target g_target
    g_target = np.zeros((T + 1, n))
    gu = np.empty((T, m))
    L = np.zeros((T, m, m))
    Mm = np.empty((T, m, n))
    Kk = np.empty((T, m, n))
    du = np.zeros((T, m))
    dx = np.zeros((T + 1, n))
    lam = np.empty(n)
    lam_new = np.empty(n)
    r_row = np.empty(rows)  # primal residual of the row
    i_ta = np.empty(rows)
    i_s = np.empty(rows)
    i_ya = np.empty(rows)
    i_zs = np.empty(rows)
    sigma = np.empty(rows)
    dya = np.zeros(rows)
    dzs = np.zeros(rows)
    dta = np.zeros(rows)
    ds = np.zeros(rows)
    cross_a = np.zeros(rows)  # the predictor's dt dy, the corrector's second-order term
    cross_s = np.zeros(rows)
    rl = np.zeros((T, m))
    rh = np.zeros((T, m))
    dl = np.zeros((T, m))  # yl / tl
    dh = np.zeros((T, m))
    dtl = np.zeros((T, m))
    dth = np.zeros((T, m))
    dyl = np.zeros((T, m))
    dyh = np.zeros((T, m))
    cross_l = np.zeros((T, m))
    cross_h = np.zeros((T, m))
    regularization = _REGULARIZATION / rho

    # Three passes over the rows per iteration: (1) the step of the last iteration, the
    # residuals, the Newton weights and the predictor's linear term; (2) the predictor's
    # directions, and the corrector's linear term as a function of its centring target;
    # (3) the corrector's directions and the step length.
    alpha = 0.0  # the first pass (1) takes no step
    for iteration in range(max_iterations + 1):
        # ---- pass (1)
        for t in range(T):
            for i in range(m):
                u[t, i] += alpha * du[t, i]
                if has_lo[i]:
                    tl[t, i] += alpha * dtl[t, i]
                    yl[t, i] += alpha * dyl[t, i]
                if has_hi[i]:
                    th[t, i] += alpha * dth[t, i]
                    yh[t, i] += alpha * dyh[t, i]
        _rollout(A, B, x0, u, x, nt, mt)
        res_p = 0.0
        res_d = 0.0
        gap = 0.0
        scale_d = 1.0
        penalty = 0.0
        checksum = 0.0
        for t in range(1, T + 1):
            for i in range(n):
                acc = 0.0
                for k in range(n):
                    Hx[t, i, k] = Q2[t - 1, i, k]
                    acc += Q2[t - 1, i, k] * (x[t, k] - x_ref[t - 1, k])
                gx0[t, i] = acc
                gx[t, i] = acc
        for j in range(rows):
            t_j = ta[j] + alpha * dta[j]
            s_j = s[j] + alpha * ds[j]
            y_j = ya[j] + alpha * dya[j]
            z_j = zs[j] + alpha * dzs[j]
            ta[j] = t_j
            s[j] = s_j
            ya[j] = y_j
            zs[j] = z_j
            tj = rt[j]
            acc = t_j - rb[j] - s_j
            for k in range(n):
                acc += ra[j, k] * x[tj, k]
            r_row[j] = acc
            checksum += acc
            pen = rho - y_j - z_j
            res_p = max(res_p, abs(acc))
            res_d = max(res_d, abs(pen))
            gap += t_j * y_j + s_j * z_j
            penalty += s_j
            # four reciprocals from one division (divisions dominate this loop)
            primal = t_j * s_j
            dual = y_j * z_j
            inverse = 1.0 / (primal * dual)
            i_ta[j] = s_j * dual * inverse
            i_s[j] = t_j * dual * inverse
            iy = z_j * primal * inverse
            iz = y_j * primal * inverse
            i_ya[j] = iy
            i_zs[j] = iz
            # sigma = 1 / (t / y + s / z + regularization)
            w = dual / (t_j * z_j + s_j * y_j + regularization * dual)
            sigma[j] = w
            scale_d = max(scale_d, y_j * a_max[j])
            # the predictor's beta (target 0, no second-order term)
            wb = w * (acc + s_j * (pen + z_j) * iz - t_j)
            for i in range(n):
                a = ra[j, i]
                gx0[tj, i] += y_j * a
                gx[tj, i] += (y_j + wb) * a
                if a != 0.0:
                    wa = w * a
                    for k in range(n):
                        Hx[tj, i, k] += wa * ra[j, k]
        for t in range(T):
            for i in range(m):
                for k in range(m):
                    Hu[t, i, k] = R2[t, i, k]
                if has_lo[i]:
                    rl[t, i] = lo[i] - u[t, i] + tl[t, i]
                    res_p = max(res_p, abs(rl[t, i]))
                    gap += tl[t, i] * yl[t, i]
                    dl[t, i] = yl[t, i] / tl[t, i]
                if has_hi[i]:
                    rh[t, i] = u[t, i] - hi[i] + th[t, i]
                    res_p = max(res_p, abs(rh[t, i]))
                    gap += th[t, i] * yh[t, i]
                    dh[t, i] = yh[t, i] / th[t, i]
                Hu[t, i, i] += dl[t, i] + dh[t, i]
        # the stationarity of the inputs, by the adjoint recursion
        for i in range(n):
            lam[i] = gx0[T, i]
        for t in range(T - 1, -1, -1):
            for i in range(m):
                acc = -yl[t, i] + yh[t, i]
                for k in range(m):
                    acc += R2[t, i, k] * (u[t, k] - u_ref[t, k])
                direct = acc
                for k in range(n):
                    acc += B[k, i] * lam[k]
                scale_d = max(scale_d, abs(direct), abs(acc - direct))
                res_d = max(res_d, abs(acc))
                checksum += acc  # max() would skip a NaN; a sum keeps it
            if t == 0:
                break
            for i in range(n):
                acc = gx0[t, i]
                for k in range(n):
                    acc += A[k, i] * lam[k]
                lam_new[i] = acc
            for i in range(n):
                lam[i] = lam_new[i]
        if not (math.isfinite(checksum) and math.isfinite(gap) and math.isfinite(scale_d)):
            return NUMERICAL, iteration
        objective = max(1.0, rho * penalty)
        if (res_p <= tolerance * scale_b and res_d <= tolerance * scale_d
                and gap <= tolerance * objective):
            return SOLVED, iteration
        loose = (res_p <= _LOOSE * scale_b and res_d <= _LOOSE * scale_d
                 and gap <= _LOOSE * objective)
        if iteration == max_iterations:
            return (ALMOST_SOLVED if loose else MAX_ITERATIONS), iteration
        if not _factor(A, B, Hx, Hu, L, Mm, Kk, nt, mt):
            return (ALMOST_SOLVED if loose else NUMERICAL), iteration
        mu = gap / n_pairs

        # ---- predictor (target 0), then corrector (Mehrotra's centring target)
        target = 0.0
        for phase in range(2):
            corrector = 1.0 if phase == 1 else 0.0
            for t in range(T):
                for i in range(m):
                    acc = yh[t, i] - yl[t, i]
                    for k in range(m):
                        acc += R2[t, i, k] * (u[t, k] - u_ref[t, k])
                    if has_lo[i]:
                        cl = target - tl[t, i] * yl[t, i] - corrector * cross_l[t, i]
                        acc -= dl[t, i] * rl[t, i] + cl / tl[t, i]
                    if has_hi[i]:
                        ch = target - th[t, i] * yh[t, i] - corrector * cross_h[t, i]
                        acc += dh[t, i] * rh[t, i] + ch / th[t, i]
                    gu[t, i] = acc
            if phase == 1:
                for t in range(1, T + 1):
                    for i in range(n):
                        gx[t, i] = gx0[t, i] + g_base[t, i] + target * g_target[t, i]
            _solve(A, B, L, Mm, Kk, gx, gu, du, dx, nt, mt)
            # passes (2) and (3): the eliminated directions and the longest step
            worst = 0.0  # max of -dv / v: the step to the boundary is 1 / worst
            sum_0 = 0.0  # (predictor) sum (t + a dt)(y + a dy) = sum_0 + a sum_1 + a^2 sum_2
            sum_1 = 0.0
            sum_2 = 0.0
            if phase == 0:
                for t in range(1, T + 1):
                    for i in range(n):
                        g_base[t, i] = 0.0
                        g_target[t, i] = 0.0
            for j in range(rows):
                t_j = ta[j]
                s_j = s[j]
                y_j = ya[j]
                z_j = zs[j]
                iy = i_ya[j]
                iz = i_zs[j]
                w = sigma[j]
                pen = rho - y_j - z_j
                # beta = r + (s (rho - y - z) - c_s) / z + c_a / y, with
                # c = target - t y - (corrector) cross
                ca = target - t_j * y_j - corrector * cross_a[j]
                cs = target - s_j * z_j - corrector * cross_s[j]
                acc = r_row[j] + (s_j * pen - cs) * iz + ca * iy
                tj = rt[j]
                for k in range(n):
                    acc += ra[j, k] * dx[tj, k]
                dy = w * acc
                dz = pen - dy
                dt = (ca - t_j * dy) * iy
                dsj = (cs - s_j * dz) * iz
                dya[j] = dy
                dzs[j] = dz
                dta[j] = dt
                ds[j] = dsj
                worst = max(worst, -dt * i_ta[j], -dsj * i_s[j], -dy * iy, -dz * iz)
                if phase == 0:
                    sum_0 += t_j * y_j + s_j * z_j
                    sum_1 += t_j * dy + y_j * dt + s_j * dz + z_j * dsj
                    sum_2 += dt * dy + dsj * dz
                    xa = dt * dy
                    xs = dsj * dz
                    cross_a[j] = xa
                    cross_s[j] = xs
                    # the corrector's beta = base + target (1 / y - 1 / z)
                    base = w * (r_row[j] + (s_j * pen + s_j * z_j + xs) * iz
                                - (t_j * y_j + xa) * iy)
                    slope = w * (iy - iz)
                    for k in range(n):
                        g_base[tj, k] += base * ra[j, k]
                        g_target[tj, k] += slope * ra[j, k]
            for t in range(T):
                for i in range(m):
                    # the lower bound moves against du (t = u - lo), the upper with it
                    for side in range(2):
                        if side == 0 and has_lo[i]:
                            tb, yb, db, rb_, crb = tl, yl, dl, rl, cross_l
                            dtb, dyb, move = dtl, dyl, -du[t, i]
                        elif side == 1 and has_hi[i]:
                            tb, yb, db, rb_, crb = th, yh, dh, rh, cross_h
                            dtb, dyb, move = dth, dyh, du[t, i]
                        else:
                            continue
                        c = target - tb[t, i] * yb[t, i] - corrector * crb[t, i]
                        dy = db[t, i] * (rb_[t, i] + move) + c / tb[t, i]
                        dt = (c - tb[t, i] * dy) / yb[t, i]
                        dyb[t, i] = dy
                        dtb[t, i] = dt
                        worst = max(worst, -dt / tb[t, i], -dy / yb[t, i])
                        if phase == 0:
                            sum_0 += tb[t, i] * yb[t, i]
                            sum_1 += tb[t, i] * dy + yb[t, i] * dt
                            sum_2 += dt * dy
                            crb[t, i] = dt * dy
            alpha = 1.0 if worst <= 1.0 else 1.0 / worst
            if phase == 0:
                gap_affine = sum_0 + alpha * sum_1 + alpha * alpha * sum_2
                ratio = max(gap_affine, 0.0) / gap if gap > 0.0 else 0.0
                target = ratio * ratio * ratio * mu
        alpha = min(1.0, _STEP_FRACTION * alpha)
    return MAX_ITERATIONS, max_iterations

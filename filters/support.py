r"""Proposition 1 with a polytope support: the DR-CVaR of :math:`-h \cdot p` when the
samples' law may only be transported inside :math:`\Xi = \{p : V p \le v\}`.

:func:`filters.safe_halfspaces` calls :func:`dr_cvar_on_polytope` for ``risk="dr_cvar"``
with ``support=(V, v)``; every other case has a closed form in :mod:`filters.risk`.

Bounded support (Proposition 1 with :math:`\Xi = \{p : V p \le v\}`, every sample
in :math:`\Xi`). For fixed :math:`\lambda`, LP duality turns the minimum over
:math:`\gamma_{ik}` in eq. (6) into
:math:`\sup_{p \in \Xi} a_k \cdot (p - p^i) - \lambda \lVert p - p^i \rVert_2`
(zero for :math:`k = 2`), and the minimum over :math:`\eta, \tau` is a CVaR. What
remains is a convex one-dimensional problem in the Wasserstein multiplier :math:`\lambda`:

.. math::

    R_\Xi = \min_{0 \le \lambda \le 1/\alpha} \;
    \lambda \epsilon + \mathrm{CVaR}_\alpha\big(x_j + \psi_j(\alpha\lambda)\big),
    \qquad
    \psi_j(\kappa) = \sup_{p \in \Xi} \;
    -h \cdot (p - p^j) - \kappa \lVert p - p^j \rVert_2 ,

with :math:`x_j = -h \cdot p^j`: a sample may be transported towards the ego at
unit gain and cost :math:`\kappa`, but not outside :math:`\Xi`. At
:math:`\lambda = 1/\alpha`, :math:`\psi = 0` and the value is the unbounded one, so
a bounded support is never more conservative. In the plane, :math:`\psi_j` is the
maximum of a concave function over the edges of :math:`\Xi` and has a closed
form per edge (setup O(N m^2), then O(N m) per evaluation); the minimum over
:math:`\lambda` is found by a golden-section search (48 evaluations), vectorised over
obstacles and steps. The value returned is attained at a feasible :math:`\lambda`, so
any residual error makes the offset smaller (safer), never larger. Unbounded
polyhedra are handled (:math:`\psi = \infty` below a recession threshold). For
``d != 2`` the CVXPY program of :mod:`filters.halfspace_cvxpy` is solved per
obstacle and step instead (slow). Like the paper, this is Proposition 1's program:
it swaps :math:`\sup_{\mathbb{P}}` and :math:`\inf_\tau`, an upper bound on the DR-CVaR.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from filters._validation import finite_array
from filters.errors import InvalidArrayError, InvalidTypeError
from filters.risk import cvar_last_axis

__all__ = ["check_support", "dr_cvar_on_polytope"]

#: Golden-section iterations over lambda in [0, 1/alpha]: the bracket shrinks to 1e-10 of it.
_GOLDEN_ITERATIONS = 48
_INV_PHI = (math.sqrt(5.0) - 1.0) / 2.0


def check_support(support: tuple[object, object], points: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(V, v)`` with unit rows, shapes ``(n, m, d)`` and ``(n, m)``.

    Raises
    ------
    InvalidTypeError
        If ``support`` is not a pair ``(V, v)``.
    InvalidArrayError
        If a shape does not fit ``points`` ``(n, N, T, d)``, a row of ``V`` is zero, an
        entry is not finite, or a sample lies outside :math:`\\{p : V p \\le v\\}`.
    """
    n_obstacles, _, _, dim = points.shape
    if not isinstance(support, (tuple, list)) or len(support) != 2:
        raise InvalidTypeError(f"support must be None or a pair (V, v), got {support!r}")
    V, v = finite_array("support V", support[0]), finite_array("support v", support[1])
    if V.ndim == 2:
        if v.shape != V.shape[:1]:
            raise InvalidArrayError(
                f"support v must have shape ({V.shape[0]},) to match V, got {v.shape}")
        V, v = (np.broadcast_to(a, (n_obstacles, *a.shape)) for a in (V, v))
    if V.ndim != 3 or V.shape[0] != n_obstacles or V.shape[2] != dim or V.shape[1] == 0:
        raise InvalidArrayError(f"support V must have shape (m, {dim}) or ({n_obstacles}, m, "
                                f"{dim}) with m >= 1, got {V.shape}")
    if v.shape != V.shape[:2]:
        raise InvalidArrayError(f"support v must have shape {V.shape[:2]}, got {v.shape}")
    finite_array("samples", points)  # before the support test, so NaN/inf is named as such
    norms = np.linalg.norm(V, axis=-1)
    if np.any(norms == 0.0):
        raise InvalidArrayError("support V must not have zero rows")
    V, v = V / norms[..., None], v / norms
    excess = np.einsum("istd,imd->istm", points, V) - v[:, None, None, :]
    tol = 1e-9 * (1.0 + np.max(np.abs(v)) + np.max(np.abs(points), initial=0.0))
    if np.any(excess > tol):
        i, s, t, _ = np.argwhere(excess > tol)[0]
        raise InvalidArrayError(
            f"samples must lie in the support {{p : V p <= v}}; samples[{i}, {s}, {t}] = "
            f"{points[i, s, t].tolist()} is outside (clip or project predictions first)")
    return V, v


def dr_cvar_on_polytope(losses: np.ndarray, points: np.ndarray, normals: np.ndarray,
                        polytope: tuple[np.ndarray, np.ndarray], alpha: float,
                        epsilon: float | np.ndarray) -> np.ndarray:
    """DR-CVaR of ``-h . p`` with support ``{p : V p <= v}`` (Proposition 1), shape ``(n, T)``.

    Parameters
    ----------
    losses
        Samples of :math:`-h_{i,t} \\cdot p`, shape ``(n, T, N)``, in m.
    points
        The samples :math:`p`, shape ``(n, N, T, d)``, in m, each inside the support.
    normals
        Unit normals :math:`h_{i,t}`, shape ``(n, T, d)``.
    polytope
        ``(V, v)`` from :func:`check_support`: unit rows ``(n, m, d)``, offsets ``(n, m)``.
    alpha, epsilon
        CVaR tail mass and Wasserstein radius (m; a float or ``(T,)``).

    Returns
    -------
    numpy.ndarray
        :math:`R_\\Xi`, shape ``(n, T)``, never above the unbounded-support value
        :math:`\\mathrm{CVaR}_\\alpha + \\epsilon/\\alpha`.
    """
    unbounded = cvar_last_axis(losses, alpha) + epsilon / alpha  # lambda = 1/alpha: feasible
    if points.shape[-1] != 2:  # never report more than the unbounded value
        return np.fmin(unbounded, _dr_cvar_on_polytope_cvxpy(points, normals, polytope, alpha,
                                                             epsilon))
    edges = _PlanarEdges(points, normals, *polytope)

    def objective(lam: np.ndarray) -> np.ndarray:
        kappa = alpha * lam
        value = lam * epsilon + cvar_last_axis(losses + edges.transport_gain(kappa), alpha)
        return np.where(kappa < edges.kappa_recession, np.inf, value)

    return np.minimum(unbounded, _golden_section(objective, 1.0 / alpha, losses.shape[:2]))


def _golden_section(
    objective: Callable[[np.ndarray], np.ndarray], upper: float, shape: tuple[int, ...]
) -> np.ndarray:
    """Minimum of convex ``objective`` over ``[0, upper]``, elementwise over a batch.

    ``objective`` maps an array of multipliers of shape ``shape`` to values of that
    shape (``+inf`` where infeasible, which only happens for small multipliers).
    Returns the smallest value seen: an upper bound (a feasible multiplier, hence a
    conservative offset) within about ``1e-10 * upper`` times the slope of the minimum.
    """
    a, b = np.zeros(shape), np.full(shape, upper)
    c, d = b - _INV_PHI * (b - a), a + _INV_PHI * (b - a)
    fc, fd = objective(c), objective(d)
    best = np.minimum(fc, fd)
    for _ in range(_GOLDEN_ITERATIONS):
        left = fc < fd  # minimum in [a, d]; ties (also inf, inf) move right
        a, b = np.where(left, a, c), np.where(left, d, b)
        c, d = np.where(left, b - _INV_PHI * (b - a), d), np.where(left, c, a + _INV_PHI * (b - a))
        fresh = objective(np.where(left, c, d))
        fc, fd = np.where(left, fresh, fd), np.where(left, fc, fresh)
        best = np.minimum(best, fresh)
    return best


class _PlanarEdges:
    """Per-sample edge data of a planar polytope, to evaluate :math:`\\psi_j(\\kappa)` fast.

    For sample :math:`p^j` and edge line :math:`\\{\\Delta : n_e \\cdot \\Delta = s_{je}\\}`
    (unit row :math:`n_e`, slack :math:`s_{je} = v_e - n_e \\cdot p^j \\ge 0`), parametrise
    :math:`\\Delta = s_{je} n_e + t\\, e_e` with :math:`e_e \\perp n_e`. Along it the gain
    :math:`-h \\cdot \\Delta - \\kappa \\lVert \\Delta \\rVert` is
    :math:`c_0 + c_1 t - \\kappa \\sqrt{s^2 + t^2}`, concave in ``t``, maximised at
    :math:`t^* = s c_1 / \\sqrt{\\kappa^2 - c_1^2}` (when :math:`\\kappa > |c_1|`) clipped
    to the edge :math:`[t_{lo}, t_{hi}]` cut out by the other rows. Arrays are stored
    edge-first, ``(m, n, T, N)``, so the maximum over edges is a fast slab-wise reduction.
    """

    def __init__(self, points: np.ndarray, normals: np.ndarray, V: np.ndarray, v: np.ndarray):
        # slack[e, i, t, j] = v_e - n_e . p^j, the distance from sample j to edge line e.
        projections = np.einsum("imd,isTd->miTs", V, points)
        slack = np.maximum(np.moveaxis(v, 1, 0)[:, :, None, None] - projections, 0.0)
        tangent = np.stack([-V[..., 1], V[..., 0]], axis=-1)  # (n, m, 2)
        h_dot_n = np.einsum("itd,imd->mit", normals, V)[..., None]  # (m, n, T, 1)
        self.rho = slack
        self.c0 = -slack * h_dot_n
        self.c1 = -np.einsum("itd,imd->mit", normals, tangent)[..., None]  # (m, n, T, 1)
        # Row k along edge e: n_k . (s_e n_e + t e_e) <= s_k,
        # i.e. t (n_k . e_e) <= s_k - s_e (n_k . n_e).
        along = np.einsum("ikd,ied->eki", V, tangent)[..., None, None]  # (m_e, m_k, n, 1, 1)
        cosine = np.einsum("ikd,ied->eki", V, V)[..., None, None]
        room = slack[None, :] - slack[:, None] * cosine  # (m_e, m_k, n, T, N)
        scale = 1e-9 * (1.0 + float(np.max(np.abs(v))) + float(np.max(np.abs(points))))
        parallel = np.abs(along) <= 1e-12
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = room / np.where(parallel, 1.0, along)
        t_hi = np.min(np.where(~parallel & (along > 0), ratio, np.inf), axis=1)
        t_lo = np.max(np.where(~parallel & (along < 0), ratio, -np.inf), axis=1)
        blocked = np.any(parallel & (room < -scale), axis=1)
        feasible = ~blocked & (t_lo <= t_hi + scale)
        self.t_lo = np.where(feasible, t_lo, 0.0)  # empty edges: finite dummies...
        self.t_hi = np.where(feasible, np.maximum(t_hi, t_lo), 0.0)
        self.penalty = np.where(feasible, 0.0, -np.inf)  # ...that never win the max
        self.has_rays = bool(np.isinf(self.t_lo).any() or np.isinf(self.t_hi).any())
        self.abs_c1 = np.abs(self.c1)
        self.rho_c1 = self.rho * self.c1
        self.t_unbounded = np.sign(self.c1) * np.inf  # t* when kappa <= |c1|
        self.t_unbounded[self.c1 == 0.0] = 0.0
        self.kappa_recession = _recession_threshold(normals, V, tangent)

    def transport_gain(self, kappa: np.ndarray) -> np.ndarray:
        """Transport gain :math:`\\psi_j(\\kappa)` of every sample (see the module docstring).

        ``kappa`` has shape ``(n, T)``; returns ``(n, T, N)``, ``>= 0``; only valid for
        ``kappa >= kappa_recession`` (otherwise the supremum is infinite).
        """
        k = kappa[None, :, :, None]
        interior = k > self.abs_c1  # small (m, n, T, 1) arrays from here...
        root = np.sqrt(np.where(interior, k * k - self.c1 * self.c1, 1.0))
        t = np.where(interior, self.rho_c1 / root, self.t_unbounded)  # ...to (m, n, T, N)
        np.clip(t, self.t_lo, self.t_hi, out=t)
        if self.has_rays:  # an unbounded edge: t may be infinite, take the limit value
            finite = np.isfinite(t)
            limit = np.where(self.abs_c1 > k, np.inf, self.c0)
            t = np.where(finite, t, 0.0)
        value = self.c0 + self.c1 * t - k * np.hypot(self.rho, t) + self.penalty
        if self.has_rays:
            value = np.where(finite, value, limit + self.penalty)
        return np.maximum(value.max(axis=0), 0.0)


def _recession_threshold(normals: np.ndarray, V: np.ndarray, tangent: np.ndarray) -> np.ndarray:
    """Recession threshold, shape ``(n, T)``.

    .. math::

        \\kappa_{rec} = \\max\\{-h \\cdot w : \\lVert w \\rVert = 1,\\ V w \\le 0\\}.

    :math:`\\psi = +\\infty` for :math:`\\kappa < \\kappa_{rec}`; ``-inf`` for a bounded
    support. In the plane the maximiser is :math:`-h` or an edge direction :math:`\\pm e`.
    """
    tol = 1e-12
    minus_h = -normals  # (n, T, 2)
    h_ok = np.all(np.einsum("imd,itd->itm", V, minus_h) <= tol, axis=-1)
    best = np.where(h_ok, 1.0, -np.inf)
    for sign in (1.0, -1.0):
        direction = sign * tangent  # (n, m, 2)
        ok = np.all(np.einsum("ikd,imd->imk", V, direction) <= tol, axis=-1)  # (n, m)
        gain = np.einsum("itd,imd->itm", minus_h, direction)
        best = np.maximum(best, np.max(np.where(ok[:, None, :], gain, -np.inf), axis=-1))
    return best


def _dr_cvar_on_polytope_cvxpy(points: np.ndarray, normals: np.ndarray,
                               polytope: tuple[np.ndarray, np.ndarray], alpha: float,
                               epsilon: float | np.ndarray) -> np.ndarray:
    """Slow path for ``d != 2``: Proposition 1 with CVXPY per obstacle and step."""
    from filters.halfspace_cvxpy import cvxpy_halfspace

    (V, v), (n_obstacles, _, horizon, _) = polytope, points.shape
    radii = np.broadcast_to(epsilon, (horizon,))
    # With r = 0 and delta = 0, g* is exactly the risk value R(-h . p).
    return np.array([[cvxpy_halfspace(points[i, :, t], normals[i, t], 0.0, risk="dr_cvar",
                                      alpha=alpha, delta=0.0, epsilon=float(radii[t]),
                                      support=(V[i], v[i])).g for t in range(horizon)]
                     for i in range(n_obstacles)]).reshape(n_obstacles, horizon)

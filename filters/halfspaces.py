"""Risk-based safe halfspaces for all obstacles and prediction steps in one vectorised call.

For obstacle :math:`i` at prediction step :math:`t` the ego position
:math:`y = C x` must satisfy

.. math::

    h_{i,t} \\cdot y \\le b_{i,t}, \\qquad
    h_{i,t} = \\frac{\\bar p_{i,t} - y^r_t}{\\lVert \\bar p_{i,t} - y^r_t \\rVert}, \\qquad
    b_{i,t} = -g^*_{i,t},

where :math:`\\bar p_{i,t}` is the mean of the obstacle's position samples
(so :math:`h` points from the ego reference towards the obstacle and the safe
side is *away* from the obstacle), and :math:`g^*` is the optimal value of
Definition 2 (eq. (4)) / Definition 3 (eq. (5)) of Safaoui & Summers. Since the
intrusion loss :math:`\\ell(p) = -(h \\cdot p + g - r)` is a translate of
:math:`-h \\cdot p` and every metric here is translation equivariant,

.. math::

    g^* = R(-h \\cdot p) - \\delta + r, \\qquad
    r = S_{\\mathcal{O}}(h) + S_{-\\mathcal{A}}(h)\\ \\ \\text{(eq. (2))},

with :math:`R` the mean, :math:`\\mathrm{CVaR}_\\alpha`, or the DR-CVaR of
Proposition 1 (see :mod:`filters.risk`; :math:`\\mathrm{CVaR}_\\alpha + \\epsilon/\\alpha`
for the unbounded support :math:`\\Xi = \\mathbb{R}^d`).


With a polytope support :math:`\\Xi = \\{p : V p \\le v\\}` the DR-CVaR is Proposition 1's
program, evaluated by :func:`filters.support.dr_cvar_on_polytope`.

The one implementation of the halfspaces, checked against the CVXPY programs of
:mod:`filters.halfspace_cvxpy` by tolerance (``tests/filters/test_halfspace_reference.py``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from filters._validation import finite_array
from filters.constants import ALPHA, DELTA, EPSILON
from filters.geometry import Disc, Shape, collision_margin
from filters.halfspace_checks import (
    DEGENERATE_DISTANCE,
    _check_finite_result,
    _checked_inputs,
    _Inputs,
    warn_deprecated_backend,
)
from filters.risk import risk_of_samples
from filters.support import dr_cvar_on_polytope

__all__ = ["DEGENERATE_DISTANCE", "Halfspaces", "safe_halfspaces"]


@dataclass(frozen=True, eq=False)
class Halfspaces:
    """Safe halfspaces :math:`h_{i,t} \\cdot y \\le b_{i,t}` on the ego position.

    Attributes
    ----------
    normals
        Unit normals :math:`h_{i,t}`, shape ``(n_obstacles, T, d)``, pointing from the
        ego reference towards obstacle ``i``.
    offsets
        Offsets :math:`b_{i,t}` in metres, shape ``(n_obstacles, T)``. The safe side is
        ``normals[i, t] @ y <= offsets[i, t]``.
    risk
        The risk metric, one of :data:`filters.risk.RISKS`.
    alpha
        CVaR tail mass, or violation probability of a chance constraint.
    delta
        Risk bound (metres of intrusion depth).
    epsilon
        Wasserstein radius (metres): a float, or a read-only ``(T,)`` array (one per step).
    degenerate
        Bool, shape ``(n_obstacles, T)``: True where the sample mean coincided with the
        ego reference and the normal came from a fallback (see :func:`safe_halfspaces`).
    """

    normals: np.ndarray
    offsets: np.ndarray
    risk: str
    alpha: float
    delta: float
    epsilon: float | np.ndarray
    degenerate: np.ndarray

    @property
    def n_obstacles(self) -> int:
        """Number of obstacles."""
        return int(self.offsets.shape[0])

    @property
    def horizon(self) -> int:
        """Number of prediction steps ``T``."""
        return int(self.offsets.shape[1])

    def violation(self, positions: object) -> np.ndarray:
        """Signed violation :math:`h_{i,t} \\cdot y_t - b_{i,t}` in metres (``<= 0`` is safe).

        Parameters
        ----------
        positions
            Ego positions for steps ``1..T``, shape ``(T, d)``.

        Returns
        -------
        numpy.ndarray
            Shape ``(n_obstacles, T)``.

        Raises
        ------
        InvalidArrayError
            If ``positions`` is not a finite ``(T, d)`` array.
        """
        y = finite_array("positions", positions, shape=(self.horizon, self.normals.shape[-1]))
        return np.einsum("itd,td->it", self.normals, y) - self.offsets

    def contains(self, positions: object) -> np.ndarray:
        """Whether each ego position lies on the safe side, shape ``(n_obstacles, T)``.

        Raises
        ------
        InvalidArrayError
            If ``positions`` is not a finite ``(T, d)`` array.
        """
        return self.violation(positions) <= 0.0


def safe_halfspaces(
    reference_positions: object,
    samples: object,
    *,
    ego_shape: Shape,
    obstacle_shapes: Sequence[Shape],
    risk: str = "dr_cvar",
    alpha: float = ALPHA,
    delta: float = DELTA,
    epsilon: float | object = EPSILON,
    support: tuple[object, object] | None = None,
    previous_normals: object | None = None,
    ego_velocity: object | None = None,
    normals: object | None = None,
    conformal_margins: object | None = None,
    backend: str | None = None,
) -> Halfspaces:
    """Risk-based safe halfspaces for every obstacle and prediction step (Definitions 2-3).

    .. math::

        h_{i,t} = \\frac{\\bar p_{i,t} - y^r_t}{\\lVert \\bar p_{i,t} - y^r_t \\rVert},\\quad
        b_{i,t} = -\\big(R(-h_{i,t} \\cdot p_{i,t}) - \\delta + r_{i,t}\\big),\\quad
        r_{i,t} = S_{\\mathcal{O}_i}(h_{i,t}) + S_{-\\mathcal{A}}(h_{i,t}).

    The safe side is ``normals[i, t] @ y <= offsets[i, t]``. Larger offsets are less
    conservative: :math:`b_{\\text{mean}} \\ge b_{\\text{CVaR}} \\ge b_{\\text{DR-CVaR}}`,
    ``b`` grows with ``delta`` and shrinks with ``epsilon``.

    Parameters
    ----------
    reference_positions
        Ego reference positions :math:`y^r` for steps ``1..T``, shape ``(T, d)``, metres.
    samples
        Obstacle position samples, shape ``(n_obstacles, n_samples, T, d)``, metres.
        ``n_obstacles = 0`` gives empty results.
    ego_shape
        Ego geometry :math:`\\mathcal{A}` (:class:`Disc` or, for ``d = 2``, :class:`ConvexPolygon`).
    obstacle_shapes
        One shape :math:`\\mathcal{O}_i` per obstacle.
    risk
        One of :data:`filters.risk.RISKS`; :math:`R(-h \\cdot p)` is, with :math:`\\hat\\mu`,
        :math:`\\hat\\Sigma` the sample mean and unbiased covariance of the samples:

        * ``"mean"``: :math:`-h \\cdot \\hat\\mu`;
        * ``"cvar"``: the empirical :math:`\\mathrm{CVaR}_\\alpha`;
        * ``"dr_cvar"``: Proposition 1 (:math:`\\mathrm{CVaR}_\\alpha + \\epsilon/\\alpha`
          without ``support``);
        * ``"gaussian_cc"``:
          :math:`-h \\cdot \\hat\\mu + z_{1-\\alpha}\\sqrt{h^\\top\\hat\\Sigma h}`,
          :math:`P(\\text{intrusion} > \\delta) \\le \\alpha` if :math:`p` is Gaussian;
        * ``"moment_dr"``:
          :math:`-h \\cdot \\hat\\mu + \\sqrt{(1-\\alpha)/\\alpha}\\sqrt{h^\\top\\hat\\Sigma h}`,
          the same promise for every law with those two moments (Cantelli);
        * ``"conformal"``: :math:`-h \\cdot \\hat\\mu + q_t` with ``conformal_margins``
          :math:`q_t`; valid whenever :math:`\\lVert p - \\hat\\mu \\rVert \\le q_t`.

        See :mod:`filters.risk` (single sample: standard deviation 0).
    alpha
        CVaR tail mass in :math:`(0, 1]` (``alpha = 1`` makes CVaR the mean); for
        ``"gaussian_cc"``/``"moment_dr"`` the violation probability, in :math:`(0, 1)`
        (for :math:`\\alpha \\ge 1/2`, :math:`z_{1-\\alpha} \\le 0`: the Gaussian halfspace is
        at or beyond the mean one).
    delta
        Risk bound on the intrusion depth, metres (finite, any sign).
    epsilon
        Wasserstein radius, metres, ``>= 0`` (``"dr_cvar"`` only): a scalar, or an array
        of shape ``(T,)``, one radius per prediction step (e.g. from
        :class:`filters.calibration.WassersteinRadius`).
    support
        ``None`` for :math:`\\Xi = \\mathbb{R}^d` (closed forms), or a polytope
        :math:`\\Xi = \\{p : V p \\le v\\}` given as ``(V, v)``, either shared by all
        obstacles (``V`` of shape ``(m, d)``, ``v`` of shape ``(m,)``) or one per
        obstacle (``(n_obstacles, m, d)`` and ``(n_obstacles, m)``). It only affects
        ``"dr_cvar"`` (Proposition 1). It may be unbounded, and every sample must lie
        in it (clip or project predictions first).
    previous_normals
        Optional ``(n_obstacles, T, d)`` normals, e.g. the previous call's normals shifted
        by one step, used first when a normal is degenerate.
    ego_velocity
        Optional ego velocity, shape ``(d,)`` or ``(T, d)`` (m/s); its opposite is the
        second fallback for a degenerate normal.
    normals
        Optional given normals ``(n_obstacles, T, d)`` (normalised here; each must be
        non-zero). The offsets are then computed along them and ``reference_positions``
        only fixes the shapes. Used for the inter-sample rows
        (:mod:`filters.intersample`), whose normal comes from the next step.
    conformal_margins
        Required for ``"conformal"`` (ignored otherwise): margins :math:`q_t \\ge 0` in
        metres, a scalar, shape ``(T,)`` (one per look-ahead step) or ``(n_obstacles, T)``,
        e.g. :meth:`filters.calibration.ConformalMargin.margins`.
    backend
        Deprecated and ignored (there is one implementation); ``"auto"``, ``"numba"``
        or ``"numpy"`` give a :class:`DeprecationWarning`.

    Returns
    -------
    Halfspaces
        Normals ``(n_obstacles, T, d)``, offsets ``(n_obstacles, T)`` and flags.

    Notes
    -----
    When :math:`\\lVert \\bar p_{i,t} - y^r_t \\rVert <` :data:`DEGENERATE_DISTANCE`, the
    normal is, in order: ``previous_normals[i, t]`` normalised (if given and non-zero);
    else :math:`-v/\\lVert v \\rVert` for the ego velocity (if given and non-zero); else
    :math:`(1, 0, \\dots, 0)`. Such entries are flagged in ``degenerate``; nothing is NaN.

    Raises
    ------
    InvalidArrayError
        If an array has the wrong shape or holds NaN/inf, or a sample lies outside the
        support.
    InvalidParameterError
        If ``risk`` is unknown, ``alpha`` is outside its domain, ``epsilon < 0``,
        ``delta`` is not finite, the number of obstacle shapes does not match,
        ``conformal_margins`` is missing for ``"conformal"``, or ``backend`` is not
        ``None``, ``"auto"``, ``"numba"`` or ``"numpy"``.
    InvalidTypeError
        If a shape is not a :class:`Disc` or :class:`ConvexPolygon`.
    """
    warn_deprecated_backend(backend, "safe_halfspaces")
    data = _checked_inputs(reference_positions, samples, ego_shape, obstacle_shapes, risk,
                           alpha, delta, epsilon, support, previous_normals, ego_velocity,
                           normals, conformal_margins)
    with np.errstate(all="ignore"):  # non-finite samples are reported below, by name
        normals, degenerate = _step_normals(data)
        if data.points.shape[0] == 0:
            offsets = np.zeros((0, data.points.shape[2]))
            return Halfspaces(normals, offsets, data.risk, data.alpha, data.delta,
                              data.epsilon, degenerate)
        offsets = _offsets(data.points, normals, ego_shape, data.shapes, data.risk, data.alpha,
                           data.delta, data.epsilon, data.margins, data.polytope)
    _check_finite_result(samples if data.polytope is None else data.points, normals, offsets)
    return Halfspaces(normals, offsets, data.risk, data.alpha, data.delta, data.epsilon,
                      degenerate)


def _step_normals(data: _Inputs) -> tuple[np.ndarray, np.ndarray]:
    """The normals ``(n, T, d)`` and the degenerate flags ``(n, T)`` of checked inputs."""
    if data.given is None:
        return _normals(_sample_means(data.points), data.y_ref, data.previous, data.velocity)
    return data.given, np.zeros(data.given.shape[:2], dtype=bool)


def _offsets(
    points: np.ndarray,
    normals: np.ndarray,
    ego_shape: Shape,
    shapes: list[Shape],
    risk: str,
    alpha: float,
    delta: float,
    epsilon: float | np.ndarray,
    margins: np.ndarray | None,
    polytope: tuple[np.ndarray, np.ndarray] | None,
) -> np.ndarray:
    """Offsets :math:`b = -(R(-h \\cdot p) - \\delta + r)` of checked data, shape
    ``normals.shape[:-1]``, for normals ``(..., n, T, d)``: leading axes hold several
    normals per obstacle and step, each along the step's own samples (no ``polytope``
    then); the per-step ``(T,)`` and per-obstacle-step ``(n, T)`` settings broadcast."""
    losses = _losses(points, normals)  # (..., n, T, N): samples of -h . p
    if risk == "dr_cvar" and polytope is not None:
        value = dr_cvar_on_polytope(losses, points, normals, polytope, alpha, epsilon)
    else:
        value = risk_of_samples(losses, risk, alpha, epsilon, overwrite=True, margin=margins)
    return -(value - delta + _margins(ego_shape, shapes, normals))


# --------------------------------------------------------------------------- closed forms


def _normals(
    mean: np.ndarray,
    y_ref: np.ndarray,
    previous: np.ndarray | None,
    velocity: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals from the ego reference to the sample means, with the documented fallbacks."""
    n_obstacles, horizon, dim = mean.shape
    diff = mean - y_ref
    dist = np.sqrt((diff * diff).sum(axis=-1))
    if not np.isfinite(dist).all():  # overflowed: NaN, so that the result check names it
        dist = np.where(np.isfinite(dist), dist, np.nan)
    degenerate = dist < DEGENERATE_DISTANCE
    if not degenerate.any():
        return diff / dist[..., None], degenerate
    normals = diff / np.where(degenerate, 1.0, dist)[..., None]
    fallback = np.zeros((n_obstacles, horizon, dim))
    fallback[..., 0] = 1.0
    if velocity is not None:
        velocity = np.broadcast_to(velocity, (horizon, dim))
        speed = np.linalg.norm(velocity, axis=-1)
        moving = speed >= DEGENERATE_DISTANCE
        away = -velocity / np.where(moving, speed, 1.0)[..., None]
        fallback = np.where(moving[None, :, None], away[None], fallback)
    if previous is not None:
        size = np.linalg.norm(previous, axis=-1)
        usable = size >= DEGENERATE_DISTANCE
        unit = previous / np.where(usable, size, 1.0)[..., None]
        fallback = np.where(usable[..., None], unit, fallback)
    normals = np.where(degenerate[..., None], fallback, normals)
    return normals, degenerate


def _margins(ego_shape: Shape, shapes: list[Shape], normals: np.ndarray) -> np.ndarray:
    """Collision margins for normals ``(..., n, T, d)``: shape ``normals.shape[:-1]``, or
    ``(n, 1)`` for discs; one call per distinct obstacle shape."""
    if isinstance(ego_shape, Disc) and all(isinstance(s, Disc) for s in shapes):
        radii = np.array([s.radius for s in shapes])  # unit normals: S = radius
        return (radii + ego_shape.radius)[:, None]
    margins = np.empty(normals.shape[:-1])
    groups: dict[Shape, list[int]] = {}
    for index, shape in enumerate(shapes):
        groups.setdefault(shape, []).append(index)
    for shape, indices in groups.items():
        margins[..., indices, :] = collision_margin(ego_shape, shape, normals[..., indices, :, :])
    return margins


def _sample_means(points: np.ndarray) -> np.ndarray:
    """Sample means :math:`\\bar p_{i,t}`, shape ``(n, T, d)``, as one BLAS product."""
    n_obstacles, n_samples, horizon, dim = points.shape
    weights = np.full((1, n_samples), 1.0 / n_samples)
    flat = points.reshape(n_obstacles, n_samples, horizon * dim)
    return (weights @ flat).reshape(n_obstacles, horizon, dim)


def _losses(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Samples of :math:`-h_{i,t} \\cdot p`, shape ``(..., n, T, N)`` for normals
    ``(..., n, T, d)``, the sample axis last (C-contiguous).

    One batched product ``(n, T, N, d) @ (..., n, T, d, 1)``: O(n T N d) per leading index.
    """
    return np.matmul(points.transpose(0, 2, 1, 3), -normals[..., None])[..., 0]

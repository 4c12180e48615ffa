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

Bounded support (Proposition 1 with :math:`\\Xi = \\{p : V p \\le v\\}`, every sample
in :math:`\\Xi`). For fixed :math:`\\lambda`, LP duality turns the minimum over
:math:`\\gamma_{ik}` in eq. (6) into
:math:`\\sup_{p \\in \\Xi} a_k \\cdot (p - p^i) - \\lambda \\lVert p - p^i \\rVert_2`
(zero for :math:`k = 2`), and the minimum over :math:`\\eta, \\tau` is a CVaR. What
remains is a convex one-dimensional problem in the Wasserstein multiplier :math:`\\lambda`:

.. math::

    R_\\Xi = \\min_{0 \\le \\lambda \\le 1/\\alpha} \\;
    \\lambda \\epsilon + \\mathrm{CVaR}_\\alpha\\big(x_j + \\psi_j(\\alpha\\lambda)\\big),
    \\qquad
    \\psi_j(\\kappa) = \\sup_{p \\in \\Xi} \\;
    -h \\cdot (p - p^j) - \\kappa \\lVert p - p^j \\rVert_2 ,

with :math:`x_j = -h \\cdot p^j`: a sample may be transported towards the ego at
unit gain and cost :math:`\\kappa`, but not outside :math:`\\Xi`. At
:math:`\\lambda = 1/\\alpha`, :math:`\\psi = 0` and the value is the unbounded one, so
a bounded support is never more conservative. In the plane, :math:`\\psi_j` is the
maximum of a concave function over the edges of :math:`\\Xi` and has a closed
form per edge (setup O(N m^2), then O(N m) per evaluation); the minimum over
:math:`\\lambda` is found by a golden-section search (48 evaluations), vectorised over
obstacles and steps. The value returned is attained at a feasible :math:`\\lambda`, so
any residual error makes the offset smaller (safer), never larger. Unbounded
polyhedra are handled (:math:`\\psi = \\infty` below a recession threshold). For
``d != 2`` the CVXPY program of :mod:`filters.halfspace_cvxpy` is solved per
obstacle and step instead (slow). Like the paper, this is Proposition 1's program:
it swaps :math:`\\sup_{\\mathbb{P}}` and :math:`\\inf_\\tau`, an upper bound on the DR-CVaR.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from filters._validation import finite_array
from filters.errors import InvalidArrayError, InvalidParameterError, InvalidTypeError
from filters.geometry import ConvexPolygon, Disc, Shape, collision_margin
from filters.kernels import check_backend, compiled_rows, kernel_applies, use_kernel
from filters.risk import (
    check_alpha,
    check_epsilon_array,
    check_margins,
    check_risk,
    cvar_last_axis,
    risk_of_samples,
)

__all__ = ["DEGENERATE_DISTANCE", "Halfspaces", "offsets_along", "safe_halfspaces"]

#: Below this distance (metres) between the sample mean and the ego reference the
#: normal ``h`` is undefined and a fallback direction is used.
DEGENERATE_DISTANCE = 1e-9

#: Golden-section iterations over lambda in [0, 1/alpha]: the bracket shrinks to 1e-10 of it.
_GOLDEN_ITERATIONS = 48
_INV_PHI = (math.sqrt(5.0) - 1.0) / 2.0


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

    def _positions(self, positions: object) -> np.ndarray:
        return finite_array("positions", positions, shape=(self.horizon, self.normals.shape[-1]))

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
        y = self._positions(positions)
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
    alpha: float = 0.2,
    delta: float = 0.1,
    epsilon: float | object = 0.05,
    support: tuple[object, object] | None = None,
    previous_normals: object | None = None,
    ego_velocity: object | None = None,
    normals: object | None = None,
    conformal_margins: object | None = None,
    backend: str = "auto",
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
        ``"auto"`` (default): the compiled kernel of :mod:`filters.kernels` where it
        applies (disc shapes; with a polytope ``support``, every risk but
        ``"dr_cvar"``), else numpy; ``"numba"``: that kernel, or an error where it does
        not apply; ``"numpy"``: the vectorised reference. They agree to rounding.

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
        ``conformal_margins`` is missing for ``"conformal"``, or ``backend`` is unknown
        (or ``"numba"`` for a case the kernels do not cover).
    InvalidTypeError
        If a shape is not a :class:`Disc` or :class:`ConvexPolygon`.
    """
    backend = check_backend(backend)
    risk = check_risk(risk)
    alpha = check_alpha(alpha, risk)
    delta = _check_delta(delta)
    y_ref, points = _check_positions(reference_positions, samples)
    n_obstacles, _, horizon, dim = points.shape
    epsilon = check_epsilon_array(epsilon, horizon)
    margins = None
    if risk == "conformal":
        margins = check_margins(conformal_margins, (n_obstacles, horizon))
    shapes = _check_shapes(ego_shape, obstacle_shapes, n_obstacles, dim)
    polytope = None if support is None else _check_support(support, points)
    previous = None
    if previous_normals is not None:
        previous = finite_array(
            "previous_normals", previous_normals, shape=(n_obstacles, horizon, dim)
        )
    velocity = None if ego_velocity is None else _check_velocity(ego_velocity, horizon, dim)

    given = None if normals is None else _check_normals(normals, points.shape)
    if n_obstacles and use_kernel(backend, kernel_applies(ego_shape, shapes, polytope, risk)):
        rows = compiled_rows(
            points, horizon, y_ref, radii=_disc_radii(ego_shape, shapes), risk=risk,
            alpha=alpha, delta=delta, epsilon=epsilon, conformal_margins=margins,
            normals="paper" if given is None else given, previous_normals=previous,
            ego_velocity=velocity)
        _check_status(rows.status, samples)
        return Halfspaces(rows.normals, rows.offsets, risk, alpha, delta, epsilon,
                          rows.degenerate)
    with np.errstate(all="ignore"):  # non-finite samples are reported below, by name
        if given is None:
            normals, degenerate = _normals(_sample_means(points), y_ref, previous, velocity)
        else:
            normals, degenerate = given, np.zeros(given.shape[:2], dtype=bool)
        if n_obstacles == 0:
            offsets = np.zeros((0, horizon))
            return Halfspaces(normals, offsets, risk, alpha, delta, epsilon, degenerate)
        offsets = _offsets(points, normals, ego_shape, shapes, risk, alpha, delta, epsilon,
                           margins, polytope)
    _check_finite_result(samples if polytope is None else points, normals, offsets)
    return Halfspaces(normals, offsets, risk, alpha, delta, epsilon, degenerate)


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
    """Offsets :math:`b = -(R(-h \\cdot p) - \\delta + r)`, ``(n, T)``, of checked data."""
    losses = _losses(points, normals)  # (n, T, N): samples of -h . p
    if risk == "dr_cvar" and polytope is not None:
        value = _dr_cvar_on_polytope(losses, points, normals, polytope, alpha, epsilon)
    else:
        value = risk_of_samples(losses, risk, alpha, epsilon, overwrite=True, margin=margins)
    return -(value - delta + _margins(ego_shape, shapes, normals))


def offsets_along(
    normals: np.ndarray,
    samples: np.ndarray,
    *,
    ego_shape: Shape,
    obstacle_shapes: Sequence[Shape],
    risk: str = "dr_cvar",
    alpha: float = 0.2,
    delta: float = 0.1,
    epsilon: float | object = 0.05,
    support: tuple[object, object] | None = None,
    conformal_margins: object | None = None,
    backend: str = "auto",
) -> np.ndarray:
    """``safe_halfspaces(..., normals=normals).offsets`` for the filter's hot path.

    The same numbers, bit for bit, as :func:`safe_halfspaces` with given ``normals``
    (normalised here the same way), with the checks a caller that already holds
    checked halfspaces needs: the shapes of ``normals`` ``(n, T, d)`` and ``samples``
    ``(n, N_s, T', d)`` with ``T' >= T`` (the first ``T`` steps are used), the risk
    settings, and a finite result. Used for the inter-sample start rows
    (:mod:`filters.intersample`), whose normals are the next step's.

    Raises
    ------
    InvalidArrayError, InvalidParameterError, InvalidTypeError
        As :func:`safe_halfspaces`.
    """
    backend = check_backend(backend)
    risk = check_risk(risk)
    alpha = check_alpha(alpha, risk)
    delta = _check_delta(delta)
    if (type(normals) is not np.ndarray or normals.ndim != 3 or type(samples) is not np.ndarray
            or samples.ndim != 4 or samples.shape[0] != normals.shape[0]
            or samples.shape[2] < normals.shape[1] or samples.shape[3] != normals.shape[2]
            or samples.shape[1] == 0 or normals.shape[1] == 0 or support is not None):
        # anything unusual: the full checks (and their messages) of safe_halfspaces
        shape = np.shape(normals)
        horizon, dim = (shape[1], shape[2]) if len(shape) == 3 else (1, 2)
        points = samples
        if isinstance(samples, np.ndarray) and samples.ndim == 4:
            points = samples[:, :, :horizon]
        return safe_halfspaces(
            np.zeros((max(horizon, 1), max(dim, 1))), points,
            ego_shape=ego_shape, obstacle_shapes=obstacle_shapes, risk=risk, alpha=alpha,
            delta=delta, epsilon=epsilon, support=support, normals=normals,
            conformal_margins=conformal_margins, backend=backend).offsets
    n_obstacles, horizon, dim = normals.shape
    points = samples[:, :, :horizon] if samples.shape[2] != horizon else samples
    points = np.asarray(points, dtype=np.float64)
    epsilon = check_epsilon_array(epsilon, horizon)
    margins = None
    if risk == "conformal":
        margins = check_margins(conformal_margins, (n_obstacles, horizon))
    shapes = _check_shapes(ego_shape, obstacle_shapes, n_obstacles, dim)
    with np.errstate(all="ignore"):
        unit = _unit_normals(np.asarray(normals, dtype=np.float64))
        if n_obstacles == 0:
            return np.zeros((0, horizon))
        if use_kernel(backend, kernel_applies(ego_shape, shapes, None, risk)):
            rows = compiled_rows(
                samples, horizon, None, radii=_disc_radii(ego_shape, shapes), risk=risk,
                alpha=alpha, delta=delta, epsilon=epsilon, conformal_margins=margins,
                normals=unit)
            _check_status(rows.status, points)
            return rows.offsets
        offsets = _offsets(points, unit, ego_shape, shapes, risk, alpha, delta, epsilon,
                           margins, None)
    _check_finite_result(points, unit, offsets)
    return offsets


# --------------------------------------------------------------------------- validation


def _check_delta(delta: object) -> float:
    if type(delta) is float and -math.inf < delta < math.inf:
        return delta
    try:
        value = float(delta)  # type: ignore[arg-type]
    except (TypeError, ValueError) as exc:
        raise InvalidParameterError(f"delta must be a finite real number, got {delta!r}") from exc
    if not math.isfinite(value):
        raise InvalidParameterError(f"delta must be a finite real number (metres), got {delta!r}")
    return value


def _check_positions(reference: object, samples: object) -> tuple[np.ndarray, np.ndarray]:
    y_ref = np.asarray(reference, dtype=np.float64) if isinstance(reference, np.ndarray) else None
    if y_ref is None or y_ref.ndim != 2 or not np.isfinite(y_ref).all():
        y_ref = finite_array("reference_positions", reference, ndim=2)
    horizon, dim = y_ref.shape
    if horizon == 0 or dim == 0:
        raise InvalidArrayError(
            f"reference_positions must have shape (T, d) with T, d >= 1, got {y_ref.shape}"
        )
    try:  # finiteness is checked on the (much smaller) result, see _check_finite_result
        points = np.asarray(samples, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidArrayError(f"samples must be a numeric array, got {samples!r}") from exc
    if points.ndim != 4:
        raise InvalidArrayError(
            "samples must have 4 dimensions (n_obstacles, n_samples, T, d), "
            f"got shape {points.shape}"
        )
    if points.shape[2:] != (horizon, dim):
        raise InvalidArrayError(
            "samples must have shape (n_obstacles, n_samples, T, d) = "
            f"(n_obstacles, n_samples, {horizon}, {dim}) to match reference_positions, "
            f"got {points.shape}"
        )
    if points.shape[1] == 0:
        raise InvalidArrayError(f"samples must hold at least one sample, got shape {points.shape}")
    return y_ref, points


def _disc_radii(ego_shape: Shape, shapes: list[Shape]) -> np.ndarray:
    """Collision margins of disc pairs, ``r_A + r_O`` per obstacle (any unit normal)."""
    return np.array([shape.radius for shape in shapes]) + ego_shape.radius


def _check_status(status: int, samples: object) -> None:
    """Raise the numpy path's errors for a kernel status other than OK (0).

    A non-finite sample is named by :func:`filters._validation.finite_array`; finite
    samples whose halfspaces overflowed get the numpy path's "too large" error.
    """
    if status == 0:
        return
    finite_array("samples", samples)
    raise InvalidArrayError(
        "samples are too large: the safe halfspaces overflowed (positions are in metres)"
    )


def _check_finite_result(samples: object, normals: np.ndarray, offsets: np.ndarray) -> None:
    """Raise ``InvalidArrayError`` if the halfspaces are not finite.

    Any NaN/inf sample makes its sample mean, hence its normal or offset, non-finite,
    so checking the ``(n, T)`` result replaces a pass over every sample.
    """
    if math.isfinite(offsets.sum() + normals.sum()):
        return
    if np.isfinite(offsets).all() and np.isfinite(normals).all():
        return  # finite entries whose sum overflowed
    finite_array("samples", samples)  # names the first non-finite sample
    raise InvalidArrayError(
        "samples are too large: the safe halfspaces overflowed (positions are in metres)"
    )


def _check_shapes(
    ego_shape: object, obstacle_shapes: object, n_obstacles: int, dim: int
) -> list[Shape]:
    if (
        type(ego_shape) is Disc
        and type(obstacle_shapes) in (list, tuple)
        and len(obstacle_shapes) == n_obstacles
        and all(type(shape) is Disc for shape in obstacle_shapes)
    ):
        return list(obstacle_shapes)  # the common case, valid in any dimension
    if isinstance(obstacle_shapes, (str, bytes)) or not isinstance(obstacle_shapes, Sequence):
        raise InvalidTypeError(
            f"obstacle_shapes must be a sequence of shapes, got {type(obstacle_shapes).__name__}"
        )
    shapes = list(obstacle_shapes)
    if len(shapes) != n_obstacles:
        raise InvalidParameterError(
            f"obstacle_shapes must hold one shape per obstacle ({n_obstacles} from samples), "
            f"got {len(shapes)}"
        )
    named = [("ego_shape", ego_shape)]
    named += [(f"obstacle_shapes[{i}]", shape) for i, shape in enumerate(shapes)]
    for name, shape in named:
        if not isinstance(shape, (Disc, ConvexPolygon)):
            raise InvalidTypeError(
                f"{name} must be a Disc or ConvexPolygon, got {type(shape).__name__}"
            )
        if isinstance(shape, ConvexPolygon) and dim != 2:
            raise InvalidArrayError(
                f"{name} is a ConvexPolygon, which needs d = 2 positions, got d = {dim}"
            )
    return shapes


def _check_normals(normals: object, shape: tuple[int, ...]) -> np.ndarray:
    n_obstacles, _, horizon, dim = shape
    array = finite_array("normals", normals, shape=(n_obstacles, horizon, dim))
    return _unit_normals(array)


def _unit_normals(array: np.ndarray) -> np.ndarray:
    """``array / |array|`` along the last axis; raises on a zero or non-finite normal."""
    size = np.sqrt((array * array).sum(axis=-1))
    if not np.all(size >= DEGENERATE_DISTANCE):  # NaN fails too
        if not np.isfinite(size).all():
            finite_array("normals", array)  # names the first non-finite entry
        raise InvalidArrayError("normals must be non-zero vectors, got a zero normal")
    return array / size[..., None]


def _check_velocity(ego_velocity: object, horizon: int, dim: int) -> np.ndarray:
    """The ego velocity as given, ``(d,)`` or ``(T, d)``; broadcast only when a fallback
    needs it (this check runs every control step, the fallback rarely)."""
    try:
        velocity = np.asarray(ego_velocity, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidArrayError(f"ego_velocity must be numeric, got {ego_velocity!r}") from exc
    if velocity.shape not in ((dim,), (horizon, dim)):
        raise InvalidArrayError(
            f"ego_velocity must have shape ({dim},) or ({horizon}, {dim}), got {velocity.shape}"
        )
    if not np.isfinite(velocity).all():
        finite_array("ego_velocity", velocity)  # names the first non-finite entry
    return velocity


def _check_support(
    support: tuple[object, object], points: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(V, v)`` with unit rows, shapes ``(n, m, d)`` and ``(n, m)``."""
    n_obstacles, _, _, dim = points.shape
    if not isinstance(support, (tuple, list)) or len(support) != 2:
        raise InvalidTypeError(f"support must be None or a pair (V, v), got {support!r}")
    V = finite_array("support V", support[0])
    v = finite_array("support v", support[1])
    if V.ndim == 2:
        V, v = V[None], v[None]
        if v.shape[1:] != V.shape[1:2]:
            raise InvalidArrayError(
                f"support v must have shape ({V.shape[1]},) to match V, got {v.shape[1:]}"
            )
        V = np.broadcast_to(V, (n_obstacles, *V.shape[1:]))
        v = np.broadcast_to(v, (n_obstacles, v.shape[1]))
    if V.ndim != 3 or V.shape[0] != n_obstacles or V.shape[2] != dim or V.shape[1] == 0:
        raise InvalidArrayError(
            f"support V must have shape (m, {dim}) or ({n_obstacles}, m, {dim}) with m >= 1, "
            f"got {V.shape}"
        )
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
            f"{points[i, s, t].tolist()} is outside (clip or project predictions first)"
        )
    return V, v


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
    """Collision margins, shape ``(n, T)`` or ``(n, 1)``; one call per distinct obstacle shape."""
    if isinstance(ego_shape, Disc) and all(isinstance(s, Disc) for s in shapes):
        radii = np.array([s.radius for s in shapes])  # unit normals: S = radius
        return (radii + ego_shape.radius)[:, None]
    margins = np.empty(normals.shape[:2])
    groups: dict[Shape, list[int]] = {}
    for index, shape in enumerate(shapes):
        groups.setdefault(shape, []).append(index)
    for shape, indices in groups.items():
        margins[indices] = collision_margin(ego_shape, shape, normals[indices])
    return margins


def _sample_means(points: np.ndarray) -> np.ndarray:
    """Sample means :math:`\\bar p_{i,t}`, shape ``(n, T, d)``, as one BLAS product."""
    n_obstacles, n_samples, horizon, dim = points.shape
    weights = np.full((1, n_samples), 1.0 / n_samples)
    flat = points.reshape(n_obstacles, n_samples, horizon * dim)
    return (weights @ flat).reshape(n_obstacles, horizon, dim)


#: Prediction steps per block-diagonal product in :func:`_losses`: the work grows
#: linearly in T beyond it, and horizons up to it give the same bits as one product.
_LOSS_STEPS_PER_PRODUCT = 16


def _losses(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Samples of :math:`-h_{i,t} \\cdot p`, shape ``(n, T, N)``, sample axis last and contiguous.

    Batched products with the block-diagonal ``(c, c d)`` matrices of the normals of
    ``c = min(T, 16)`` consecutive steps: a product over all ``T`` steps at once would
    cost O(T^2 d N) per obstacle, these cost O(16 T d N).
    """
    n_obstacles, n_samples, horizon, dim = points.shape
    flat = points.reshape(n_obstacles, n_samples, horizon * dim)
    if horizon <= _LOSS_STEPS_PER_PRODUCT:
        return -(_block_diagonal(normals) @ flat.transpose(0, 2, 1))
    losses = np.empty((n_obstacles, horizon, n_samples))
    for start in range(0, horizon, _LOSS_STEPS_PER_PRODUCT):
        stop = min(start + _LOSS_STEPS_PER_PRODUCT, horizon)
        columns = flat[:, :, start * dim : stop * dim].transpose(0, 2, 1)
        np.matmul(_block_diagonal(normals[:, start:stop]), columns, out=losses[:, start:stop])
    return np.negative(losses, out=losses)


def _block_diagonal(normals: np.ndarray) -> np.ndarray:
    """``(n, c, c d)``: row ``t`` holds ``normals[:, t]`` in columns ``t d .. t d + d - 1``."""
    n_obstacles, steps, dim = normals.shape
    index = np.arange(steps)
    blocks = np.zeros((n_obstacles, steps, steps, dim))
    blocks[:, index, index, :] = normals
    return blocks.reshape(n_obstacles, steps, steps * dim)


# --------------------------------------------------------------------------- Proposition 1


def _dr_cvar_on_polytope(
    losses: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    polytope: tuple[np.ndarray, np.ndarray],
    alpha: float,
    epsilon: float | np.ndarray,
) -> np.ndarray:
    """DR-CVaR of ``-h . p`` with support ``{p : V p <= v}`` (Proposition 1), shape ``(n, T)``."""
    if points.shape[-1] != 2:
        return _dr_cvar_on_polytope_cvxpy(points, normals, polytope, alpha, epsilon)
    edges = _PlanarEdges(points, normals, *polytope)

    def objective(lam: np.ndarray) -> np.ndarray:
        kappa = alpha * lam
        value = lam * epsilon + cvar_last_axis(losses + edges.transport_gain(kappa), alpha)
        return np.where(kappa < edges.kappa_recession, np.inf, value)

    unbounded = cvar_last_axis(losses, alpha) + epsilon / alpha  # lambda = 1/alpha
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
    a = np.zeros(shape)
    b = np.full(shape, upper)
    c = b - _INV_PHI * (b - a)
    d = a + _INV_PHI * (b - a)
    fc, fd = objective(c), objective(d)
    best = np.minimum(fc, fd)
    for _ in range(_GOLDEN_ITERATIONS):
        left = fc < fd  # minimum in [a, d]; ties (also inf, inf) move right
        b = np.where(left, d, b)
        a = np.where(left, a, c)
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


def _dr_cvar_on_polytope_cvxpy(
    points: np.ndarray,
    normals: np.ndarray,
    polytope: tuple[np.ndarray, np.ndarray],
    alpha: float,
    epsilon: float | np.ndarray,
) -> np.ndarray:
    """Slow path for ``d != 2``: Proposition 1 with CVXPY per obstacle and step."""
    from filters.halfspace_cvxpy import cvxpy_halfspace

    V, v = polytope
    n_obstacles, _, horizon, _ = points.shape
    value = np.empty((n_obstacles, horizon))
    for i in range(n_obstacles):
        for t in range(horizon):
            # With r = 0 and delta = 0, g* is exactly the risk value R(-h . p).
            result = cvxpy_halfspace(
                points[i, :, t],
                normals[i, t],
                0.0,
                risk="dr_cvar",
                alpha=alpha,
                delta=0.0,
                epsilon=epsilon if np.ndim(epsilon) == 0 else float(epsilon[t]),
                support=(V[i], v[i]),
            )
            value[i, t] = result.g
    # lambda = 1/alpha is always feasible: never report more than the unbounded value.
    unbounded = cvar_last_axis(_losses(points, normals), alpha) + epsilon / alpha
    return np.fmin(unbounded, value)

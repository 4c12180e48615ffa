"""Convex shapes, their support functions, and the collision margin of a safe halfspace.

The paper (Safaoui & Summers, Sec. II-B, eq. (2)) replaces the collision-avoidance
condition :math:`(y \\oplus \\mathcal{A}) \\cap (p \\oplus \\mathcal{O}) = \\emptyset`
by the sufficient separating-hyperplane condition

.. math::

    z \\cdot (y - p) \\ge S_{\\mathcal{O}}(z) + S_{-\\mathcal{A}}(z),
    \\qquad S_{\\mathcal{C}}(z) := \\sup_{x \\in \\mathcal{C}} z \\cdot x,

for a unit vector :math:`z`. This module provides the support functions
:math:`S_{\\mathcal{C}}` of the two shapes the project needs (a disc/ball and a
convex polygon) and :func:`collision_margin`, the right-hand side above.

Shapes are expressed in the body frame of the robot or obstacle (the reference
point at the origin), lengths in metres.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import numpy as np

from filters._validation import finite_array
from filters.errors import InvalidArrayError, InvalidShapeError, InvalidTypeError

__all__ = ["ConvexPolygon", "Disc", "Shape", "check_shape", "collision_margin"]

#: Relative tolerance under which a polygon turn counts as collinear.
_COLLINEAR_RTOL = 1e-9


def _directions(value: object, dim: int | None) -> np.ndarray:
    """Return ``value`` as a finite array of directions whose last axis has length ``dim``."""
    array = finite_array("directions", value)
    if array.ndim == 0 or (dim is not None and array.shape[-1] != dim):
        raise InvalidArrayError(f"directions must have shape (..., {dim or 'd'}) for this "
                                f"shape, got {array.shape} ({value!r})")
    return array


@dataclass(frozen=True)
class Disc:
    """A disc (a ball in :math:`\\mathbb{R}^d`) of radius ``radius`` centred at the origin.

    Its support function is

    .. math::

        S_{\\mathcal{B}_r}(z) = r \\lVert z \\rVert_2 ,

    and the disc is symmetric, so :math:`-\\mathcal{B}_r = \\mathcal{B}_r`. The
    dimension is taken from the directions it is evaluated on; ``Disc(0.0)`` is a point.

    Parameters
    ----------
    radius
        Radius in metres, finite and non-negative.

    Raises
    ------
    InvalidTypeError
        If ``radius`` is not a real number.
    InvalidShapeError
        If ``radius`` is negative, NaN or infinite.
    """

    radius: float

    def __post_init__(self) -> None:
        if isinstance(self.radius, bool) or not isinstance(self.radius, numbers.Real):
            raise InvalidTypeError(f"Disc radius must be a real number, got {self.radius!r}")
        if not 0.0 <= float(self.radius) < math.inf:
            raise InvalidShapeError(
                f"Disc radius must be finite and >= 0 (metres), got {self.radius!r}")
        object.__setattr__(self, "radius", float(self.radius))

    def support(self, directions: object) -> np.ndarray:
        """Support function :math:`S(z) = r \\lVert z \\rVert_2`, vectorised.

        Parameters
        ----------
        directions
            Array of shape ``(..., d)``.

        Returns
        -------
        numpy.ndarray
            Shape ``(...)``, in metres times the length of ``z``.

        Raises
        ------
        InvalidArrayError
            If ``directions`` is a scalar or holds NaN/inf.
        """
        return self.radius * np.linalg.norm(_directions(directions, None), axis=-1)

    def reflected(self) -> Disc:
        """Return :math:`-\\mathcal{B}_r`, which is the disc itself."""
        return self


@dataclass(frozen=True)
class ConvexPolygon:
    """A convex polygon in the plane, given by its vertices in order.

    The vertices may be listed clockwise or counter-clockwise; they are stored
    counter-clockwise (``vertices`` is a tuple of ``(x, y)`` tuples, in metres).
    The support function is the largest projection of a vertex,

    .. math::

        S_{\\mathcal{P}}(z) = \\max_{j} \\, z \\cdot v_j .

    Parameters
    ----------
    vertices
        Array-like of shape ``(n, 2)`` with ``n >= 3``.

    Raises
    ------
    InvalidShapeError
        If there are fewer than 3 vertices, a vertex is repeated, three
        consecutive vertices are collinear (a degenerate or zero-area polygon),
        or the polygon is not convex (including self-intersecting stars).
    InvalidArrayError
        If ``vertices`` is not a finite ``(n, 2)`` array.
    """

    vertices: tuple[tuple[float, float], ...]
    _array: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        array = finite_array("ConvexPolygon vertices", self.vertices, (None, 2))
        _check_convex(array)
        if _signed_area(array) < 0.0:
            array = array[::-1].copy()
        array.setflags(write=False)
        object.__setattr__(self, "vertices", tuple((float(x), float(y)) for x, y in array))
        object.__setattr__(self, "_array", array)

    @classmethod
    def box(cls, width: float, height: float) -> ConvexPolygon:
        """Axis-aligned rectangle of size ``width`` x ``height`` (metres) centred at the origin.

        Raises
        ------
        InvalidShapeError
            If ``width`` or ``height`` is not a finite positive number.
        """
        for name, value in (("width", width), ("height", height)):
            if not (isinstance(value, numbers.Real) and 0 < value < math.inf):
                raise InvalidShapeError(
                    f"ConvexPolygon.box {name} must be finite and > 0 (metres), got {value!r}")
        w, h = float(width) / 2.0, float(height) / 2.0
        return cls(((-w, -h), (w, -h), (w, h), (-w, h)))

    @property
    def vertex_array(self) -> np.ndarray:
        """Read-only ``(n, 2)`` array of the vertices, counter-clockwise."""
        return self._array

    def support(self, directions: object) -> np.ndarray:
        """Support function :math:`S(z) = \\max_j z \\cdot v_j`, vectorised.

        Parameters
        ----------
        directions
            Array of shape ``(..., 2)``.

        Returns
        -------
        numpy.ndarray
            Shape ``(...)``.

        Raises
        ------
        InvalidArrayError
            If ``directions`` does not end in an axis of length 2 or holds NaN/inf.
        """
        return np.max(_directions(directions, 2) @ self._array.T, axis=-1)

    def reflected(self) -> ConvexPolygon:
        """Return the point reflection :math:`-\\mathcal{P} = \\{-x : x \\in \\mathcal{P}\\}`."""
        return ConvexPolygon(tuple((-x, -y) for x, y in self.vertices))


#: A shape accepted by :func:`collision_margin` and :func:`filters.halfspaces.safe_halfspaces`.
Shape = Disc | ConvexPolygon


def collision_margin(ego_shape: Shape, obstacle_shape: Shape, directions: object) -> np.ndarray:
    """Collision margin :math:`r(h) = S_{\\mathcal{O}}(h) + S_{-\\mathcal{A}}(h)` (paper eq. (2)).

    For two discs of radii :math:`r_{\\mathcal{O}}` and :math:`r_{\\mathcal{A}}`
    and a unit ``h`` it is :math:`r_{\\mathcal{O}} + r_{\\mathcal{A}}`. The ego is
    collision free if :math:`h \\cdot (p - y) \\ge r(h)` with ``h`` a unit vector
    pointing from the ego position ``y`` to the obstacle position ``p``.

    Parameters
    ----------
    ego_shape
        Ego geometry :math:`\\mathcal{A}` (body frame).
    obstacle_shape
        Obstacle geometry :math:`\\mathcal{O}` (body frame).
    directions
        Array of shape ``(..., d)``; usually unit normals.

    Returns
    -------
    numpy.ndarray
        Shape ``(...)``, in metres for unit directions.

    Raises
    ------
    InvalidTypeError
        If a shape is not a :class:`Disc` or :class:`ConvexPolygon`.
    InvalidArrayError
        If ``directions`` is malformed.
    """
    ego = check_shape("ego_shape", ego_shape).reflected()
    obstacle = check_shape("obstacle_shape", obstacle_shape)
    return obstacle.support(directions) + ego.support(directions)


def check_shape(name: str, shape: object) -> Shape:
    """Return ``shape`` if it is a :class:`Disc` or :class:`ConvexPolygon`.

    Raises
    ------
    InvalidTypeError
        Naming ``name`` and the type it got, otherwise.
    """
    if not isinstance(shape, (Disc, ConvexPolygon)):
        raise InvalidTypeError(
            f"{name} must be a Disc or ConvexPolygon, got {type(shape).__name__}")
    return shape


def _signed_area(vertices: np.ndarray) -> float:
    """Shoelace signed area (positive for counter-clockwise order)."""
    x, y = vertices[:, 0], vertices[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _check_convex(vertices: np.ndarray) -> None:
    """Raise ``InvalidShapeError`` unless ``vertices`` is a strictly convex simple polygon."""
    n = len(vertices)
    if n < 3:
        raise InvalidShapeError(
            f"ConvexPolygon needs at least 3 vertices, got {n}: {vertices.tolist()}")
    edges = np.roll(vertices, -1, axis=0) - vertices
    lengths = np.linalg.norm(edges, axis=1)
    scale = max(float(np.max(np.abs(vertices))), 1.0)
    if np.any(lengths <= _COLLINEAR_RTOL * scale) or len(np.unique(vertices, axis=0)) < n:
        raise InvalidShapeError(f"ConvexPolygon vertices must be distinct, got {vertices.tolist()}")
    following = np.roll(edges, -1, axis=0)
    cross = edges[:, 0] * following[:, 1] - edges[:, 1] * following[:, 0]
    dot = np.sum(edges * following, axis=1)
    if np.any(np.abs(cross) <= _COLLINEAR_RTOL * lengths * np.roll(lengths, -1)):
        raise InvalidShapeError(
            "ConvexPolygon vertices must not have three consecutive collinear points "
            f"(degenerate polygon), got {vertices.tolist()}")
    turning = float(np.sum(np.arctan2(cross, dot)))
    same_sign = np.all(cross > 0) or np.all(cross < 0)
    if not same_sign or not math.isclose(abs(turning), 2.0 * math.pi, rel_tol=1e-6):
        raise InvalidShapeError(
            f"ConvexPolygon vertices must form a convex polygon in order, got {vertices.tolist()}")

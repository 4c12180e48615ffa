"""Input checks of :func:`filters.safe_halfspaces` and its relatives.

Every public entry of :mod:`filters.halfspaces` and :mod:`filters.intersample` validates
its inputs here, once, and raises the project's errors (:mod:`filters.errors`) naming the
value and what was expected; the closed forms then run on checked arrays.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from filters._validation import finite_array, finite_scalar
from filters.errors import InvalidArrayError, InvalidParameterError, InvalidTypeError
from filters.geometry import ConvexPolygon, Shape, check_shape
from filters.risk import check_alpha, check_epsilon_array, check_margins, check_risk
from filters.support import check_support

__all__ = ["DEGENERATE_DISTANCE"]

#: Below this distance (metres) between the sample mean and the ego reference the
#: normal ``h`` is undefined and a fallback direction is used.
DEGENERATE_DISTANCE = 1e-9


class _Inputs(NamedTuple):
    """The checked inputs of :func:`safe_halfspaces` (see its parameters); a named tuple,
    built every control step (the cheapest immutable record to make)."""

    risk: str
    alpha: float
    delta: float
    y_ref: np.ndarray
    points: np.ndarray
    epsilon: float | np.ndarray
    margins: np.ndarray | None
    shapes: list[Shape]
    polytope: tuple[np.ndarray, np.ndarray] | None
    previous: np.ndarray | None
    velocity: np.ndarray | None
    given: np.ndarray | None


def _checked_inputs(reference_positions: object, samples: object, ego_shape: Shape,
                    obstacle_shapes: Sequence[Shape], risk: str, alpha: float, delta: float,
                    epsilon: float | object, support: tuple[object, object] | None,
                    previous_normals: object | None, ego_velocity: object | None,
                    normals: object | None, conformal_margins: object | None) -> _Inputs:
    """Every check of :func:`safe_halfspaces` (raises what it documents)."""
    risk = check_risk(risk)
    alpha = check_alpha(alpha, risk)
    delta = finite_scalar("delta (metres)", delta)
    y_ref, points = _check_positions(reference_positions, samples)
    n_obstacles, _, horizon, dim = points.shape
    epsilon = check_epsilon_array(epsilon, horizon)
    margins = check_margins(conformal_margins, (n_obstacles, horizon)) if (
        risk == "conformal") else None
    shapes = _check_shapes(ego_shape, obstacle_shapes, n_obstacles, dim)
    polytope = None if support is None else check_support(support, points)
    previous = None if previous_normals is None else finite_array(
        "previous_normals", previous_normals, (n_obstacles, horizon, dim))
    velocity = None if ego_velocity is None else _check_velocity(ego_velocity, horizon, dim)
    given = None if normals is None else _unit_normals(
        finite_array("normals", normals, (n_obstacles, horizon, dim)))
    return _Inputs(risk, alpha, delta, y_ref, points, epsilon, margins, shapes, polytope,
                   previous, velocity, given)


def warn_deprecated_backend(backend: object, caller: str) -> None:
    """Warn that ``backend=`` is ignored (raise on a value it never accepted)."""
    if backend is None:
        return
    if backend not in ("auto", "numba", "numpy"):
        raise InvalidParameterError(f"{caller}: backend must be 'auto', 'numba' or 'numpy' "
                                    f"(deprecated, ignored), got {backend!r}")
    warnings.warn(f"{caller}: backend={backend!r} is deprecated and ignored: the "
                  "halfspaces have one implementation", DeprecationWarning, stacklevel=3)


def _check_positions(reference: object, samples: object) -> tuple[np.ndarray, np.ndarray]:
    y_ref = finite_array("reference_positions", reference, ndim=2)
    horizon, dim = y_ref.shape
    if horizon == 0 or dim == 0:
        raise InvalidArrayError(
            f"reference_positions must have shape (T, d) with T, d >= 1, got {y_ref.shape}")
    try:  # finiteness is checked on the (much smaller) result, see _check_finite_result
        points = np.asarray(samples, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidArrayError(f"samples must be a numeric array, got {samples!r}") from exc
    if points.ndim != 4 or points.shape[2:] != (horizon, dim) or points.shape[1] == 0:
        raise InvalidArrayError(
            "samples must have shape (n_obstacles, n_samples >= 1, T, d) = "
            f"(n_obstacles, n_samples, {horizon}, {dim}) to match reference_positions, "
            f"got {points.shape}")
    return y_ref, points


def _check_finite_result(samples: object, normals: np.ndarray, offsets: np.ndarray) -> None:
    """Raise ``InvalidArrayError`` if the halfspaces are not finite.

    Any NaN/inf sample makes its sample mean, hence its normal or offset, non-finite,
    so checking the ``(n, T)`` result replaces a pass over every sample.
    """
    if math.isfinite(offsets.sum() + normals.sum()) or (
            np.isfinite(offsets).all() and np.isfinite(normals).all()):
        return  # (finite entries whose sum overflowed pass too)
    finite_array("samples", samples)  # names the first non-finite sample
    raise InvalidArrayError(
        "samples are too large: the safe halfspaces overflowed (positions are in metres)")


def _check_shapes(
    ego_shape: object, obstacle_shapes: object, n_obstacles: int, dim: int
) -> list[Shape]:
    if isinstance(obstacle_shapes, (str, bytes)) or not isinstance(obstacle_shapes, Sequence):
        raise InvalidTypeError(
            f"obstacle_shapes must be a sequence of shapes, got {type(obstacle_shapes).__name__}")
    shapes = list(obstacle_shapes)
    if len(shapes) != n_obstacles:
        raise InvalidParameterError(
            f"obstacle_shapes must hold one shape per obstacle ({n_obstacles} from samples), "
            f"got {len(shapes)}")
    for name, shape in [("ego_shape", ego_shape),
                        *((f"obstacle_shapes[{i}]", shape) for i, shape in enumerate(shapes))]:
        if isinstance(check_shape(name, shape), ConvexPolygon) and dim != 2:
            raise InvalidArrayError(
                f"{name} is a ConvexPolygon, which needs d = 2 positions, got d = {dim}")
    return shapes


def _unit_normals(array: np.ndarray) -> np.ndarray:
    """``array / |array|`` along the last axis; raises on a zero or non-finite normal."""
    size = np.sqrt(np.add.reduce(array * array, axis=-1))
    if size.size and not (size.min() >= DEGENERATE_DISTANCE  # NaN fails too
                          and math.isfinite(size.max())):
        finite_array("normals", array)  # names the first non-finite entry
        raise InvalidArrayError("normals must be non-zero vectors, got a zero normal")
    return array / size[..., None]


def _check_velocity(ego_velocity: object, horizon: int, dim: int) -> np.ndarray:
    """The ego velocity as given, ``(d,)`` or ``(T, d)``; broadcast only when a fallback
    needs it (this check runs every control step, the fallback rarely)."""
    velocity = finite_array("ego_velocity", ego_velocity)
    if velocity.shape not in ((dim,), (horizon, dim)):
        raise InvalidArrayError(
            f"ego_velocity must have shape ({dim},) or ({horizon}, {dim}), got {velocity.shape}")
    return velocity

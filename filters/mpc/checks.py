"""Input checks of the MPC safety filter: constructor arguments and per-step arrays.

Integers, weight matrices, input/position boxes, the per-step arrays and the
halfspaces in any accepted form (:func:`parse_halfspaces`). Errors are the project's
(:mod:`filters.errors`).
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from filters._validation import finite_array, integer_at_least
from filters.errors import InvalidArrayError, InvalidParameterError, InvalidTypeError

__all__ = ["all_finite", "box", "finite_step_array", "integer", "parse_halfspaces", "step_arrays",
           "weight"]


#: The per-step arrays of :class:`filters.mpc.MPCSafetyFilter` are checked by
#: :func:`filters._validation.finite_array` (one reduction for a finite float64 array).
finite_step_array = finite_array


def integer(name: str, value: object, *, low: int) -> int:
    """``value`` as an int ``>= low``: ``InvalidTypeError`` for a non-integer."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise InvalidTypeError(f"{name} must be an integer, got {value!r}")
    return integer_at_least(name, value, low=low)


def weight(name: str, value: object, size: int, *, definite: bool) -> np.ndarray:
    matrix = finite_array(name, value, shape=(size, size))
    scale = max(1.0, float(np.max(np.abs(matrix))))
    if not np.allclose(matrix, matrix.T, rtol=0.0, atol=1e-10 * scale):
        raise InvalidParameterError(
            f"{name} must be symmetric, got max |{name} - {name}.T| = "
            f"{np.max(np.abs(matrix - matrix.T)):.3g}; pass ({name} + {name}.T) / 2")
    matrix = 0.5 * (matrix + matrix.T)
    smallest = float(np.linalg.eigvalsh(matrix)[0]) if size else 0.0
    if definite and smallest <= 1e-12 * scale:
        raise InvalidParameterError(
            f"{name} must be positive definite (it keeps the QP strictly convex and "
            f"the filtered input unique), got smallest eigenvalue {smallest:.3g}")
    if not definite and smallest < -1e-10 * scale:
        raise InvalidParameterError(
            f"{name} must be positive semidefinite, got smallest eigenvalue {smallest:.3g}")
    return matrix


def box(name: str, value: object, size: int) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` broadcast to ``(size,)``; ``None`` means unbounded."""
    if value is None:
        return np.full(size, -np.inf), np.full(size, np.inf)
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
        raise InvalidTypeError(f"{name} must be None or a pair (low, high), got {value!r}")
    sides = []
    for side, raw in zip(("low", "high"), value, strict=True):
        try:
            sides.append(np.array(np.broadcast_to(np.asarray(raw, dtype=np.float64), (size,))))
        except (TypeError, ValueError) as exc:
            raise InvalidArrayError(f"{name} {side} must be a number or an array of shape "
                                    f"({size},), got {raw!r}") from exc
        if np.isnan(sides[-1]).any():
            raise InvalidArrayError(f"{name} {side} must not contain NaN, got {sides[-1]}")
    low, high = sides
    if np.any(low == np.inf) or np.any(high == -np.inf):
        raise InvalidParameterError(
            f"{name} must have low < +inf and high > -inf, got low={low}, high={high}")
    if np.any(low > high):
        index = int(np.argmax(low > high))
        raise InvalidParameterError(f"{name} lower bound exceeds upper bound at index {index}: "
                                    f"{low[index]} > {high[index]}")
    return low, high


def all_finite(array: np.ndarray) -> bool:
    """``np.isfinite(array).all()``, with a one-reduction fast path."""
    return math.isfinite(np.add.reduce(array, axis=None)) or bool(np.isfinite(array).all())


def parse_halfspaces(halfspaces: object, horizon: int, dim: int, n_obstacles: int
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Validate halfspaces given as an object, a pair, or ``None``.

    Parameters
    ----------
    halfspaces
        ``None`` (no obstacle), a pair ``(normals, offsets)``, or any object with
        ``.normals`` of shape ``(k, T, d)`` and ``.offsets`` of shape ``(k, T)``.
    horizon, dim, n_obstacles
        ``T``, ``d`` and the largest ``k`` accepted.

    Returns
    -------
    normals, offsets
        Finite arrays of shapes ``(k, T, d)`` and ``(k, T)``.

    Raises
    ------
    InvalidTypeError
        If ``halfspaces`` is none of the accepted forms.
    InvalidArrayError
        On a wrong shape, NaN or infinite entries, or ``k > n_obstacles``.
    """
    if halfspaces is None:
        return np.zeros((0, horizon, dim)), np.zeros((0, horizon))
    if isinstance(halfspaces, (tuple, list)) and len(halfspaces) == 2:
        raw_normals, raw_offsets = halfspaces
    elif hasattr(halfspaces, "normals") and hasattr(halfspaces, "offsets"):
        raw_normals, raw_offsets = halfspaces.normals, halfspaces.offsets
    else:
        raise InvalidTypeError(
            "halfspaces must be None, a pair (normals, offsets) or an object with "
            f".normals and .offsets, got {type(halfspaces).__name__}")
    normals = finite_array("halfspaces.normals", raw_normals, (None, horizon, dim))
    offsets = finite_array("halfspaces.offsets", raw_offsets, (normals.shape[0], horizon))
    if normals.shape[0] > n_obstacles:
        raise InvalidArrayError(
            f"halfspaces has {normals.shape[0]} obstacle rows but the filter was built "
            f"for n_obstacles={n_obstacles}; build it with a larger n_obstacles")
    return normals, offsets


def step_arrays(
    x0: object, reference_states: object, reference_inputs: object, halfspaces: object,
    horizon: int, n: int, m: int, dim: int, n_obstacles: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
    """The checked per-step arrays of :meth:`filters.mpc.MPCSafetyFilter.solve`.

    Returns ``(x0, reference_states, reference_inputs, normals, offsets)`` of shapes
    ``(n,)``, ``(T + 1, n)``, ``(T, m)`` (or ``None``), ``(k, T, d)``, ``(k, T)``, each
    finite, checked by :func:`finite_step_array` and :func:`parse_halfspaces` (which name
    the bad one; a float64 array of the right shape costs one reduction).

    Raises
    ------
    InvalidArrayError, InvalidTypeError
        As :func:`finite_step_array` and :func:`parse_halfspaces`.
    """
    x0 = finite_step_array("x0", x0, (n,))
    reference_states = finite_step_array("reference_states", reference_states, (horizon + 1, n))
    if reference_inputs is not None:
        reference_inputs = finite_step_array("reference_inputs", reference_inputs, (horizon, m))
    normals, offsets = parse_halfspaces(halfspaces, horizon, dim, n_obstacles)
    return x0, reference_states, reference_inputs, normals, offsets

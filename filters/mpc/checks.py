"""Input checks of the MPC safety filter: constructor arguments and per-step arrays.

Integers, weight matrices, input/position boxes, the per-step arrays (with a
one-reduction fast path for the common case) and the halfspaces in any accepted
form (:func:`parse_halfspaces`). Errors are the project's (:mod:`filters.errors`);
the per-step fast path :func:`finite_step_array` raises exactly what
:func:`filters._validation.finite_array` raises.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from filters._validation import finite_array
from filters.errors import InvalidArrayError, InvalidParameterError, InvalidTypeError

__all__ = ["all_finite", "box", "finite_step_array", "integer", "parse_halfspaces", "weight"]

_FLOAT64 = np.dtype(np.float64)  # a singleton: ``dtype is _FLOAT64`` is the cheap test


def finite_step_array(name: str, value: object, shape: tuple[int, ...]) -> np.ndarray:
    """Fast path of :func:`finite_array` for the per-step arrays (same errors).

    A float64 array of the right shape is accepted when its sum is finite (one
    reduction instead of two passes and a temporary). A sum that overflows, or any
    NaN/inf, takes the full check, which raises only if an entry is really not finite.
    """
    if type(value) is np.ndarray and value.dtype is _FLOAT64 and value.shape == shape:
        if math.isfinite(np.add.reduce(value, axis=None)):
            return value
        array = value
    elif isinstance(value, np.ndarray) and value.dtype == np.float64:
        array = value
    else:
        try:
            array = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            return finite_array(name, value, shape=shape)  # raises with the message
    if array.shape == shape and np.isfinite(array).all():
        return array
    return finite_array(name, value, shape=shape)  # raises with the message


def integer(name: str, value: object, *, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise InvalidTypeError(f"{name} must be an integer, got {value!r}")
    if int(value) < low:
        raise InvalidParameterError(f"{name} must be >= {low}, got {value!r}")
    return int(value)


def weight(name: str, value: object, size: int, *, definite: bool) -> np.ndarray:
    matrix = finite_array(name, value, shape=(size, size))
    scale = max(1.0, float(np.max(np.abs(matrix))))
    if not np.allclose(matrix, matrix.T, rtol=0.0, atol=1e-10 * scale):
        raise InvalidParameterError(
            f"{name} must be symmetric, got max |{name} - {name}.T| = "
            f"{np.max(np.abs(matrix - matrix.T)):.3g}; pass ({name} + {name}.T) / 2"
        )
    matrix = 0.5 * (matrix + matrix.T)
    smallest = float(np.linalg.eigvalsh(matrix)[0]) if size else 0.0
    if definite and smallest <= 1e-12 * scale:
        raise InvalidParameterError(
            f"{name} must be positive definite (it keeps the QP strictly convex and "
            f"the filtered input unique), got smallest eigenvalue {smallest:.3g}"
        )
    if not definite and smallest < -1e-10 * scale:
        raise InvalidParameterError(
            f"{name} must be positive semidefinite, got smallest eigenvalue {smallest:.3g}"
        )
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
            array = np.asarray(raw, dtype=np.float64)
            array = np.array(np.broadcast_to(array, (size,)))
        except (TypeError, ValueError) as exc:
            raise InvalidArrayError(
                f"{name} {side} must be a number or an array of shape ({size},), got {raw!r}"
            ) from exc
        if np.any(np.isnan(array)):
            raise InvalidArrayError(f"{name} {side} must not contain NaN, got {array}")
        sides.append(array)
    low, high = sides
    if np.any(low == np.inf) or np.any(high == -np.inf):
        raise InvalidParameterError(
            f"{name} must have low < +inf and high > -inf, got low={low}, high={high}"
        )
    if np.any(low > high):
        index = int(np.argmax(low > high))
        raise InvalidParameterError(
            f"{name} lower bound exceeds upper bound at index {index}: "
            f"{low[index]} > {high[index]}"
        )
    return low, high


def all_finite(array: np.ndarray) -> bool:
    """``np.isfinite(array).all()``, with a one-reduction fast path."""
    return math.isfinite(np.add.reduce(array, axis=None)) or bool(np.isfinite(array).all())


def parse_halfspaces(
    halfspaces: object, horizon: int, dim: int, n_obstacles: int
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
    if type(halfspaces) is tuple and len(halfspaces) == 2:  # no .normals: the pair
        raw_normals, raw_offsets = halfspaces
    elif hasattr(halfspaces, "normals") and hasattr(halfspaces, "offsets"):
        raw_normals, raw_offsets = halfspaces.normals, halfspaces.offsets
    elif isinstance(halfspaces, (tuple, list)) and len(halfspaces) == 2:
        raw_normals, raw_offsets = halfspaces
    else:
        raise InvalidTypeError(
            "halfspaces must be None, a pair (normals, offsets) or an object with "
            f".normals and .offsets, got {type(halfspaces).__name__}"
        )
    if (  # fast path: valid float64 arrays pass with one reduction each (same answer)
        type(raw_normals) is np.ndarray and type(raw_offsets) is np.ndarray
        and raw_normals.dtype is _FLOAT64 and raw_offsets.dtype is _FLOAT64
        and raw_normals.ndim == 3 and raw_normals.shape[1:] == (horizon, dim)
        and raw_offsets.shape == (raw_normals.shape[0], horizon)
        and raw_normals.shape[0] <= n_obstacles
        and math.isfinite(np.add.reduce(raw_normals, axis=None))
        and math.isfinite(np.add.reduce(raw_offsets, axis=None))
    ):
        return raw_normals, raw_offsets
    try:
        normals = np.asarray(raw_normals, dtype=np.float64)
    except (TypeError, ValueError):
        normals = None
    if normals is None or normals.ndim != 3:  # let finite_array raise the message
        normals = finite_array("halfspaces.normals", raw_normals, shape=(None, horizon, dim))
    normals = finite_step_array("halfspaces.normals", normals, (normals.shape[0], horizon, dim))
    offsets = finite_step_array("halfspaces.offsets", raw_offsets, (normals.shape[0], horizon))
    if normals.shape[0] > n_obstacles:
        raise InvalidArrayError(
            f"halfspaces has {normals.shape[0]} obstacle rows but the filter was built "
            f"for n_obstacles={n_obstacles}; build it with a larger n_obstacles"
        )
    return normals, offsets

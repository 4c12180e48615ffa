"""Small input checks shared by the modules of :mod:`filters`.

They turn bad input into :mod:`filters.errors` exceptions whose message names
the argument, what it was, and what was expected.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from filters.errors import InvalidArrayError, InvalidParameterError


def finite_array(
    name: str, value: object, shape: Sequence[int | None] | None = None, *, ndim: int | None = None
) -> np.ndarray:
    """Return ``value`` as a finite float64 array, or raise ``InvalidArrayError``.

    A float64 array is returned as it is (``numpy.asarray`` makes no copy); its
    finiteness is checked with one reduction (the per-step arrays of the control loop pass
    here), and only an overflowing or non-finite sum takes the entry-wise check.

    Parameters
    ----------
    name
        Name of the argument, used in the error message.
    value
        Anything ``np.asarray`` accepts.
    shape
        Required shape; ``None`` entries match any length.
    ndim
        Required number of dimensions, if any.
    """
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidArrayError(f"{name} must be a numeric array, got {value!r}") from exc
    if ndim is not None and array.ndim != ndim:
        raise InvalidArrayError(f"{name} must have {ndim} dimension(s), got shape {array.shape}")
    if shape is not None and array.shape != shape and (array.ndim != len(shape) or any(
            want not in (None, got) for got, want in zip(array.shape, shape, strict=True))):
        expected = tuple("any" if s is None else s for s in shape)
        raise InvalidArrayError(f"{name} must have shape {expected}, got {array.shape}")
    if not math.isfinite(np.add.reduce(array, axis=None)) and not np.isfinite(array).all():
        bad = np.argwhere(~np.isfinite(array))[0]
        raise InvalidArrayError(f"{name} must be finite, got {array[tuple(bad)]} at index "
                                f"{tuple(int(i) for i in bad)}")
    return array


def scalar_in_range(name: str, value: object, *, low: float = -np.inf, high: float = np.inf,
                    low_inclusive: bool = True, high_inclusive: bool = True) -> float:
    """Return ``value`` as a float inside the given interval, or raise ``InvalidParameterError``."""
    if isinstance(value, bool | np.bool_ | str | bytes):  # float() would take True, "0.1"
        raise InvalidParameterError(f"{name} must be a real number, got {value!r}")
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError) as exc:
        raise InvalidParameterError(f"{name} must be a real number, got {value!r}") from exc
    above = number >= low if low_inclusive else number > low
    below = number <= high if high_inclusive else number < high
    # an infinite number passes only as an inclusive infinite upper bound
    if not (above and below and (math.isfinite(number) or (number == high and high_inclusive))):
        raise InvalidParameterError(f"{name} must lie in {'[' if low_inclusive else '('}{low}, "
                                    f"{high}{']' if high_inclusive else ')'}, got {value!r}")
    return number


def finite_scalar(name: str, value: object, *, low: float = -math.inf,
                  strict: bool = False) -> float:
    """``value`` as a finite float ``>= low`` (``> low`` if ``strict``), or
    ``InvalidParameterError``."""
    return scalar_in_range(name, value, low=low, low_inclusive=not strict, high=math.inf,
                           high_inclusive=False)


def lookahead_index(lookahead: object, horizon: int) -> int:
    """The 0-based index of look-ahead ``k`` in ``1..horizon``, or ``InvalidParameterError``."""
    k = integer_at_least("lookahead", lookahead)
    if k > horizon:
        raise InvalidParameterError(f"lookahead must be in 1..{horizon}, got {k}")
    return k - 1


def integer_at_least(name: str, value: object, *, low: int = 1) -> int:
    """Return ``value`` as an int ``>= low``, or raise ``InvalidParameterError``."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low:
        raise InvalidParameterError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


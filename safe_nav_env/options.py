"""The validators shared by :mod:`safe_nav_env`: numbers, named choices, mappings of fields.

Every bad value raises a :class:`~safe_nav_env.errors.ConfigError` (an environment
option) or a :class:`~safe_nav_env.errors.ScenarioError` (scenario data) whose message
names the option or field path, the value it got and what was expected.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import fields
from typing import Any

import numpy as np

from safe_nav_env.errors import ConfigError, ScenarioError


def _option(
    name: str, value: Any, *, low: float = 0.0, high: float = math.inf, strict: bool = False,
    integer: bool = False, allow_inf: bool = False, error: type[ValueError] = ConfigError,
) -> Any:
    """``value`` as a float (an int with ``integer``) in ``[low, high]`` (``(low, high]`` if
    ``strict``), finite unless ``allow_inf``; else ``error`` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise error(f"{name} must be a number, got {value!r}")
    finite = math.isfinite(value)
    bounds = (f"in {'(' if strict else '['}{low:g}, {high:g}]" if high < math.inf
              else f"{'>' if strict else '>='} {low:g}" if low > -math.inf else "")
    if integer and not (finite and int(value) == value):
        raise error(f"{name} must be an integer {bounds}".rstrip() + f", got {value!r}")
    if (math.isnan(value) or not (finite or allow_inf) or value > high
            or (value <= low if strict else value < low)):
        need = " and ".join(w for w in ("" if finite or allow_inf else "finite", bounds) if w)
        raise error(f"{name} must be {need}, got {value!r}")
    return int(value) if integer else float(value)


def _finite_array(path: str, value: Any, what: str, expected: str,
                  shape_ok: Callable[[tuple[int, ...]], bool],
                  error: type[ValueError] = ConfigError) -> np.ndarray:
    """``value`` as a finite float64 array whose shape passes ``shape_ok``; else ``error``
    naming ``path``, the kind of value expected (``what``) and its shape (``expected``)."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise error(f"{path} must be a numeric {what}, got the non-numeric {value!r}") from exc
    if not shape_ok(array.shape):
        raise error(f"{path} must have shape {expected}, got shape {array.shape}")
    if not np.isfinite(array).all():
        raise error(f"{path} must be finite (no NaN or inf), got {value!r}")
    return array


def _named(table: Mapping[str, Any], value: str, path: str, what: str,
           error: type[ValueError] = ScenarioError) -> Any:
    """``table[value]``, or ``error`` listing the names of ``table``."""
    if value not in table:
        raise error(f"{path}: unknown {what} {value!r}; choose one of {sorted(table)}")
    return table[value]


def _from_fields(cls: type, value: Mapping[str, Any], path: str,
                 error: type[ValueError] = ScenarioError, names: Mapping[str, Any] | None = None
                 ) -> Any:
    """``cls(**value)`` for a mapping of the dataclass ``cls``'s fields (a ``cls`` is returned
    as it is; anything else raises ``error``, listing ``names`` if the caller also takes one).

    An unknown or missing field raises ``error`` naming it; an ``error`` of ``cls`` whose
    message starts with ``"<cls name>."`` is raised again starting with ``path``
    (``"ObstacleSpec.radius ..."`` -> ``"obstacles[1].radius ..."``).
    """
    if isinstance(value, cls):
        return value
    if not isinstance(value, Mapping):
        named = "" if names is None else f", a name in {sorted(names)}"
        raise error(f"{path} must be a {cls.__name__}{named} or a mapping, got {value!r}")
    allowed = sorted(f.name for f in fields(cls) if f.init)
    unknown = sorted(set(value) - set(allowed))
    if unknown:
        raise error(f"{path}: unknown field(s) {unknown} of {cls.__name__}; the fields are "
                    f"{allowed}")
    try:
        return cls(**value)
    except TypeError as exc:  # a missing field
        raise error(f"{path}: missing field(s) ({exc}); got {sorted(value)}") from exc
    except error as exc:
        message, prefix = str(exc), f"{cls.__name__}."
        raise error(path + message[len(prefix) - 1:] if message.startswith(prefix)
                    else message) from None

"""The settings of :class:`filters.wrapper.SafetyFilterWrapper` and their checks.

The choices each option accepts (:data:`RISKS`, :data:`OBJECTIVES`, ...) and the checks
that turn a bad option, a bad action or a bad wrapper stack into a clear error.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np

from filters.errors import InvalidArrayError, InvalidParameterError, InvalidTypeError
from filters.protocol import FilterableEnv
from filters.risk import RISKS as _METRICS

RISKS: tuple[str, ...] = ("none", *_METRICS)
"""Risk settings accepted by :class:`filters.wrapper.SafetyFilterWrapper` (``"none"``:
pass-through)."""

OBJECTIVES = ("first_input", "trajectory")
"""Filter objectives: the predictive safety filter's, or the paper's Problem 2."""

NORMAL_SOURCES = ("paper", "ego", "nearside", "previous_plan", "clearest")
"""Where the halfspace normals start (they end at the obstacles' sample means)."""

FALLBACKS = ("soft", "brake", "paper")
"""What the filter does when the hard QP is infeasible (see
:class:`filters.wrapper.SafetyFilterWrapper`)."""

_PROTOCOL_ATTRIBUTES = (*FilterableEnv.__annotations__, "observe")
"""Everything :class:`filters.protocol.FilterableEnv` asks of ``env.unwrapped``."""


def _choice(name: str, value: object, choices: tuple[str, ...]) -> str:
    """``value`` if it is one of ``choices``, else a clear error naming both."""
    if not isinstance(value, str):
        raise InvalidTypeError(f"{name} must be a string, one of {choices}, got {value!r}")
    if value not in choices:
        raise InvalidParameterError(f"{name} must be one of {choices}, got {value!r}")
    return value


def _count(name: str, value: object) -> int:
    """``value`` as an int if it is an integer ``>= 0`` (not a bool), else a clear error."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
        raise InvalidParameterError(f"{name} must be an integer >= 0, got {value!r}")
    return int(value)


def _action_array(action: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``action`` as a flat float array of ``prod(shape)`` entries, else a clear error.

    A scalar is not broadcast to every axis, and an action of another size is refused,
    as the base environment's ``step`` does (NaN and infinite entries pass: the filter
    answers them with its fallback).

    Raises
    ------
    InvalidArrayError
        If ``action`` is not numeric or does not have ``prod(shape)`` entries.
    """
    try:
        raw = np.asarray(action, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise InvalidArrayError(
            f"action must be a numeric array of shape {shape} (accelerations in m/s²), "
            f"got {action!r}") from exc
    if raw.size != math.prod(shape):
        raise InvalidArrayError(
            f"action must have shape {shape} (one acceleration per axis, in m/s²), got shape "
            f"{np.shape(action)}: {action!r}")
    return raw


def _check_no_action_wrapper(env: gym.Env) -> None:
    """Raise if a wrapper between ``env`` and its base environment changes actions.

    The filter computes the applied action in the base environment's units; a
    ``RescaleAction`` (or any ``ActionWrapper``) in between would transform it again.
    The message says which order works: the action wrapper outside the filter.
    """
    base = env.unwrapped
    layer = env
    while layer is not base:
        changes_space = getattr(layer, "action_space", None) != base.action_space
        if isinstance(layer, gym.ActionWrapper) or changes_space:
            name = type(layer).__name__
            example = {"RescaleAction": "RescaleAction(SafetyFilterWrapper(env), -1.0, 1.0)",
                       "ClipAction": "ClipAction(SafetyFilterWrapper(env))"}.get(
                           name, f"{name}(SafetyFilterWrapper(env), ...)")
            raise InvalidTypeError(
                f"{name} sits between SafetyFilterWrapper and the base environment: put it "
                f"outside the filter instead, {example}. Why: the filter checks and applies "
                "its action in the base environment's physical units (m/s², clipped to the "
                f"input bounds), so a wrapper below it would transform the checked action "
                "again and the applied action would not be the one proved safe; above it, the "
                "wrapper maps the policy's action to m/s² before the filter sees it"
                + (" (SafetyFilterWrapper already clips to the input bounds, so ClipAction "
                   "is not needed at all)" if name == "ClipAction" else ""))
        layer = layer.env

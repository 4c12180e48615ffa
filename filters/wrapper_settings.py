"""The checks of :class:`filters.wrapper.SafetyFilterWrapper` that need the environment.

They turn a bad action or a bad wrapper stack into a clear error. The settings and their
checks are :class:`filters.config.FilterConfig`.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np

from filters.errors import InvalidArrayError, InvalidTypeError
from filters.protocol import FilterableEnv

_PROTOCOL_ATTRIBUTES = (*FilterableEnv.__annotations__, "observe")
"""Everything :class:`filters.protocol.FilterableEnv` asks of ``env.unwrapped``."""


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

"""Validation of the environments' constructor options: numbers and the scenario.

Shared by :class:`safe_nav_env.env.SafeNavEnv` and the environments built on it
(crowd, pedestrians); every bad value raises a :class:`~safe_nav_env.errors.ConfigError`
or :class:`~safe_nav_env.errors.ScenarioError` naming the option and what was expected.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from safe_nav_env.errors import ConfigError, ScenarioError
from safe_nav_env.scenarios import SCENARIOS, Scenario, ScenarioFactory


def _option(
    name: str, value: Any, *, low: float = 0.0, strict: bool = False, integer: bool = False
) -> Any:
    """Validate a numeric constructor option; raise :class:`ConfigError` naming it."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ConfigError(f"{name} must be a number, got {value!r}")
    if integer and int(value) != value:
        raise ConfigError(f"{name} must be an integer, got {value!r}")
    if not math.isfinite(value) or (value <= low if strict else value < low):
        relation = ">" if strict else ">="
        raise ConfigError(f"{name} must be finite and {relation} {low}, got {value!r}")
    return int(value) if integer else float(value)


def _speed_option(value: Any) -> float:
    """Validate ``max_speed`` (m/s): a number ``> 0``; ``inf`` or ``None`` (JSON's
    ``null``, for the command line) for no speed limit."""
    if value is None or (not isinstance(value, bool) and value == math.inf
                         and isinstance(value, int | float | np.integer | np.floating)):
        return math.inf
    try:
        return _option("max_speed", value, strict=True)
    except ConfigError:
        raise ConfigError(f"max_speed must be a number > 0 (in m/s), or inf or None (no speed "
                          f"limit), "
                          f"got {value!r}") from None


def _check_start_speed(name: str, state: np.ndarray, max_speed: float) -> None:
    """Raise :class:`ScenarioError` if the ego starts (``state = [p, v]``) faster than
    ``max_speed`` (m/s)."""
    speed = math.hypot(state[2], state[3])
    if speed > max_speed:
        raise ScenarioError(
            f"scenario {name!r}: the ego starts at {speed:g} m/s, above "
            f"max_speed={max_speed:g} m/s; pass a larger max_speed (inf: no limit)")


def _resolve_scenario(value: Any, path: str = "scenario") -> Scenario | ScenarioFactory:
    """The scenario (or factory ``rng -> Scenario``) named or described by ``value``.

    Parameters
    ----------
    value
        A :class:`Scenario`, a function ``rng -> Scenario``, a name in ``SCENARIOS``, or a
        mapping of :class:`Scenario` fields.
    path
        The option's name in error messages.

    Raises
    ------
    ConfigError
        If ``value`` is None (the scenario is required).
    ScenarioError
        If ``value`` is an unknown name, a mapping with missing or unknown fields, or of
        another type.
    """
    if isinstance(value, Scenario) or (callable(value) and not isinstance(value, type)):
        return value
    if isinstance(value, str):
        if value not in SCENARIOS:
            raise ScenarioError(
                f"{path}: unknown scenario {value!r}; choose one of {sorted(SCENARIOS)} or pass "
                "a Scenario"
            )
        return SCENARIOS[value]
    if isinstance(value, Mapping):
        try:
            return Scenario(**value)
        except TypeError as exc:  # a missing or unknown field
            raise ScenarioError(f"{path}: {exc}; got fields {sorted(value)}") from exc
    if value is None:
        raise ConfigError(
            f"{path} is required: pass scenario=safe_nav_env.Scenario(...), a name in "
            f"{sorted(SCENARIOS)}, or a function rng -> Scenario, e.g. "
            "gym.make('SafeNav/Custom-v0', scenario=my_scenario)"
        )
    raise ScenarioError(
        f"{path} must be a Scenario, a scenario name, a mapping or a function rng -> Scenario, "
        f"got {value!r}"
    )

"""Exceptions raised by :mod:`safe_nav_env`.

Every error subclasses :class:`ValueError`, so ``except ValueError`` keeps
working, and every message names the offending field or option, the value it
got, and what was expected.
"""

from __future__ import annotations


class SafeNavEnvError(Exception):
    """Base class of the errors raised by :mod:`safe_nav_env`."""


class ScenarioError(SafeNavEnvError, ValueError):
    """Scenario data is invalid: a bad shape, a non-finite value, a bad noise law.

    The message starts with the path of the offending field, for example
    ``"obstacles[1].radius must be > 0, got -0.3"``.
    """


class ConfigError(SafeNavEnvError, ValueError):
    """An environment option passed to :class:`~safe_nav_env.SafeNavEnv` (or through
    ``gym.make``) is invalid, for example ``n_samples=0``."""


class InvalidActionError(SafeNavEnvError, ValueError):
    """An action passed to :meth:`~safe_nav_env.SafeNavEnv.step` has the wrong size or
    holds NaN or infinite entries."""

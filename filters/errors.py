"""Exceptions raised by :mod:`filters`.

Every error subclasses a builtin (``ValueError`` or ``TypeError``) so that
``except ValueError`` keeps working, and every message names the offending
value and what was expected.
"""

from __future__ import annotations


class SafeNavError(Exception):
    """Base class of the errors raised by safe-nav's filters."""


class InvalidParameterError(SafeNavError, ValueError):
    """A scalar parameter is outside its domain (alpha, epsilon, delta, weights, ...)."""


class InvalidArrayError(SafeNavError, ValueError):
    """An array has the wrong shape, or holds NaN or infinite entries."""


class InvalidShapeError(SafeNavError, ValueError):
    """A geometric shape is invalid (negative radius, non-convex polygon, ...)."""


class InvalidTypeError(SafeNavError, TypeError):
    """An argument has the wrong type."""

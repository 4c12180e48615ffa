"""Exceptions raised by :mod:`agents` (the evaluation, its records and its outputs).

Like :mod:`filters.errors` and :mod:`safe_nav_env.errors`, every error subclasses a
builtin (``ValueError``), so ``except ValueError`` keeps working, and every message
names the offending value and what to do about it.
"""

from __future__ import annotations


class AgentsError(Exception):
    """Base class of the errors raised by :mod:`agents`."""


class PolicyFileError(AgentsError, ValueError):
    """A PPO policy file is missing, unreadable or not a Stable-Baselines3 zip."""


class RecordsFileError(AgentsError, ValueError):
    """A results CSV (or its run key) is not one this version of safe-nav wrote."""


class RunMismatchError(AgentsError, ValueError):
    """An output folder holds the results of a run with other settings."""


class OutputPathError(AgentsError, ValueError):
    """An output path cannot be used (e.g. a folder is asked for and a file is there)."""


class WorkersLostError(AgentsError, RuntimeError):
    """Evaluation workers (local processes, Ray nodes) keep dying or cannot be reached.

    The episodes that finished are saved; running the same command again resumes.
    """


class MissingExtraError(AgentsError, ImportError):
    """An optional feature was asked for without its extra installed (the message names
    the extra and the command that installs it)."""

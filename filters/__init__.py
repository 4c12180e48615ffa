"""Risk-based safe halfspaces and the MPC safety filter (Safaoui & Summers, ICRA 2024).

* :func:`safe_halfspaces` — mean, CVaR and DR-CVaR safe halfspaces for every obstacle
  and predicted step in one vectorised call (safe side: ``normals @ y <= offsets``).
* :class:`MPCSafetyFilter` — Problem 2 of the paper (or the predictive safety filter),
  built once, solved with Clarabel, with a recovery that never raises.
* :func:`intersample_rows` — the rows that keep a plan safe between the samples too.
* :class:`SafetyFilterWrapper` — a Gymnasium wrapper that filters any policy's actions,
  with its settings in one :class:`FilterConfig`;
  :class:`FilterReport` is its ``info["filter"]``, :class:`FilterableEnv` the protocol it
  needs of ``env.unwrapped``, :func:`hold_action_reference` and
  :class:`PolicyRolloutReference` its reference makers.
* :class:`Disc`, :class:`ConvexPolygon` — shapes with support functions.

The halfspaces have one (numpy) implementation, checked against the CVXPY formulation
of :mod:`filters.halfspace_cvxpy` by tolerance.

``import filters`` imports neither CVXPY (only :mod:`filters.halfspace_cvxpy` and
:mod:`filters.mpc.backends.cvxpy`, the readable reference formulations, do; reach
``filters.CVXPYSafetyFilter`` lazily) nor matplotlib.
"""

from typing import Any

from filters.config import FilterConfig
from filters.errors import (
    InvalidArrayError,
    InvalidParameterError,
    InvalidShapeError,
    InvalidTypeError,
    SafeNavError,
)
from filters.geometry import ConvexPolygon, Disc, collision_margin
from filters.halfspaces import Halfspaces, safe_halfspaces
from filters.intersample import intersample_rows
from filters.mpc import (
    FilterResult,
    FilterStatus,
    MPCProblem,
    MPCSafetyFilter,
    stopping_terminal_set,
)
from filters.protocol import FilterableEnv
from filters.references import PolicyRolloutReference, hold_action_reference
from filters.risk import empirical_cvar
from filters.wrapper import FilterReport, SafetyFilterWrapper

__all__ = [
    "CVXPYSafetyFilter",
    "ConvexPolygon",
    "Disc",
    "FilterConfig",
    "FilterReport",
    "FilterResult",
    "FilterStatus",
    "FilterableEnv",
    "Halfspaces",
    "InvalidArrayError",
    "InvalidParameterError",
    "InvalidShapeError",
    "InvalidTypeError",
    "MPCProblem",
    "MPCSafetyFilter",
    "PolicyRolloutReference",
    "SafeNavError",
    "SafetyFilterWrapper",
    "collision_margin",
    "empirical_cvar",
    "hold_action_reference",
    "intersample_rows",
    "safe_halfspaces",
    "stopping_terminal_set",
]


def __getattr__(name: str) -> Any:
    if name == "CVXPYSafetyFilter":  # the CVXPY reference: resolved on first use
        from filters.mpc.cvxpy_filter import CVXPYSafetyFilter

        return CVXPYSafetyFilter
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

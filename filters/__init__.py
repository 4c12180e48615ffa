"""Risk-based safe halfspaces and the MPC safety filter (Safaoui & Summers, ICRA 2024).

* :func:`safe_halfspaces` — mean, CVaR and DR-CVaR safe halfspaces for every obstacle
  and predicted step in one vectorised call (safe side: ``normals @ y <= offsets``).
* :class:`MPCSafetyFilter` — Problem 2 of the paper, built once, solved with Clarabel.
* :class:`SafetyFilterWrapper` — a Gymnasium wrapper that filters any policy's actions.
* :class:`Disc`, :class:`ConvexPolygon` — shapes with support functions.

``import filters`` imports neither CVXPY (only :mod:`filters.halfspace_cvxpy` and
:mod:`filters.mpc_cvxpy`, the readable reference formulations, do) nor matplotlib.
"""

from filters.errors import (
    InvalidArrayError,
    InvalidParameterError,
    InvalidShapeError,
    InvalidTypeError,
    SafeNavError,
)
from filters.geometry import ConvexPolygon, Disc, collision_margin
from filters.halfspaces import Halfspaces, safe_halfspaces
from filters.mpc import FilterResult, FilterStatus, MPCSafetyFilter
from filters.risk import empirical_cvar
from filters.wrapper import SafetyFilterWrapper

__all__ = [
    "ConvexPolygon",
    "Disc",
    "FilterResult",
    "FilterStatus",
    "Halfspaces",
    "InvalidArrayError",
    "InvalidParameterError",
    "InvalidShapeError",
    "InvalidTypeError",
    "MPCSafetyFilter",
    "SafeNavError",
    "SafetyFilterWrapper",
    "collision_margin",
    "empirical_cvar",
    "safe_halfspaces",
]

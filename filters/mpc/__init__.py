"""The MPC safety filter, from composed parts (in the shape of qpmpc).

* :mod:`filters.mpc.problem`: :class:`MPCProblem`, the frozen, validated QP definition
  (model, horizon, objective, bounds, terminal set, soft rows, penalty).
* :mod:`filters.mpc.terminal`: :func:`stopping_terminal_set` (recursive feasibility
  against the arena for the double integrator).
* :mod:`filters.mpc.backends`: DAQP (whitened condensed QP, dual active set, lazy rows),
  Clarabel (sparse, built once, updated per step) and CVXPY (reference);
  ``backend="auto"`` picks per QP (DAQP for hard QPs; DAQP or Clarabel for soft ones, by
  size).
* :mod:`filters.mpc.condensed`: the whitened condensed QP (identity Hessian, row bank).
* :mod:`filters.mpc.filter`: :class:`MPCSafetyFilter`, the step: validation, shortcut,
  QP, recovery.
* :mod:`filters.mpc.acceptance`: the per-step roll-out, row excesses, acceptance check
  and cost of a plan.
* :mod:`filters.mpc.cvxpy_filter`: :class:`CVXPYSafetyFilter`, the same filter on the
  CVXPY back end (the reference in tests and benchmarks).
* :mod:`filters.mpc.recovery`: the paper's Remark (shift the last plan, then brake).
* :mod:`filters.mpc.result`: :class:`FilterStatus`, :class:`FilterResult`.

``import filters.mpc`` does not import CVXPY; ``filters.mpc.CVXPYSafetyFilter`` is
resolved lazily.
"""

from __future__ import annotations

from typing import Any

from filters.mpc.filter import MPCSafetyFilter
from filters.mpc.problem import MPCProblem
from filters.mpc.result import FilterResult, FilterStatus
from filters.mpc.terminal import stopping_terminal_set

__all__ = [
    "CVXPYSafetyFilter",
    "FilterResult",
    "FilterStatus",
    "MPCProblem",
    "MPCSafetyFilter",
    "stopping_terminal_set",
]


def __getattr__(name: str) -> Any:
    if name == "CVXPYSafetyFilter":
        from filters.mpc.cvxpy_filter import CVXPYSafetyFilter

        return CVXPYSafetyFilter
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

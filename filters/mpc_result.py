"""Value objects of the MPC safety filter: what a step returns, and what a back end reports.

* :class:`FilterStatus` and :class:`FilterResult` are the public result of
  :meth:`filters.mpc.MPCSafetyFilter.solve` (and of the CVXPY reference filter).
* :class:`_QPAttempt` is what a QP back end's ``_solve_qp`` hands back to
  :class:`filters.mpc_base.SafetyFilterBase`, which turns it into a
  :class:`FilterResult` (or a fallback).

:class:`FilterStatus` and :class:`FilterResult` are re-exported by :mod:`filters.mpc`
and :mod:`filters`.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import NamedTuple

import numpy as np

__all__ = ["FilterResult", "FilterStatus"]


class FilterStatus(str, Enum):
    """What the safety filter returned, and which fallback (if any) was used."""

    OPTIMAL = "optimal"
    """Problem 2 was solved; the inputs are its minimiser."""
    SOFT = "soft"
    """Soft mode: solved, but some halfspace is violated (``slack > 0``)."""
    SHIFTED = "shifted"
    """The QP failed; the last optimal plan, shifted, was used (paper's Remark)."""
    BRAKE = "brake"
    """The QP failed and no stored plan was left: braking inputs."""


@dataclass(frozen=True)
class FilterResult:
    """Result of one safety-filter step, in the spirit of qpsolvers' ``Solution``.

    Attributes
    ----------
    status
        What was returned (see :class:`FilterStatus`).
    inputs
        Input sequence :math:`u_0, \\dots, u_{T-1}`, shape ``(T, m)`` (e.g. m/s²).
        ``inputs[0]`` is the input to apply now.
    states
        States :math:`x_0, \\dots, x_T` rolled out from the actual ``x0`` with
        ``inputs``, shape ``(T + 1, n)``.
    solve_time
        Wall time of the QP solver call, in s.
    total_time
        Wall time of the whole :meth:`~filters.mpc.MPCSafetyFilter.solve` call (validation,
        data update, solver, roll-out), in s.
    slack
        Soft mode: halfspace violations :math:`s_{i,t} \\ge 0` in m, shape
        ``(k, T)`` for the ``k`` halfspace rows given (entries
        ``<= filters.mpc_base.SLACK_TOLERANCE`` are reported as 0). On a fallback it is the
        violation :math:`\\max(0, a^\\top C x_t - b)` of the returned trajectory.
        ``None`` in hard mode.
    solver_status
        The solver's own status (Clarabel's ``SolverStatus`` name, or the CVXPY
        status), or a short description of why a solution was rejected
        (exception, NaN, constraint violation).
    iterations
        Interior-point iterations of the solver call (0 if it did not run).
    objective
        When solved, the optimal value reported by the solver: the cost (8)
        (plus :math:`\\rho \\sum s` in soft mode). On a fallback, the cost (8) of
        the returned trajectory.
    consecutive_failures
        Number of failed solves in a row, this one included (0 on success). On
        ``SHIFTED`` it is the shift applied to the stored plan.
    """

    status: FilterStatus
    inputs: np.ndarray
    states: np.ndarray
    solve_time: float
    total_time: float
    slack: np.ndarray | None
    solver_status: str
    iterations: int
    objective: float
    consecutive_failures: int = 0

    @property
    def first_input(self) -> np.ndarray:
        """The input to apply now, ``inputs[0]``, shape ``(m,)``."""
        return self.inputs[0]

    @property
    def solved(self) -> bool:
        """Whether the QP was solved (``OPTIMAL`` or ``SOFT``)."""
        return self.status in (FilterStatus.OPTIMAL, FilterStatus.SOFT)

    @property
    def fallback(self) -> bool:
        """Whether a fallback (``SHIFTED`` or ``BRAKE``) was returned."""
        return not self.solved


class _QPAttempt(NamedTuple):
    """What a QP back end reports to :class:`~filters.mpc_base.SafetyFilterBase`."""

    inputs: np.ndarray | None  # (T, m) if the solver claims a solution
    slack: np.ndarray | None  # (n_obstacles, T) in soft mode
    solver_status: str
    iterations: int
    solve_time: float
    solved: bool  # the solver's status says "solved"
    objective: float = float("nan")  # the solver's optimal value: cost (8) [+ rho sum(s)]
    # Rows the QP left out (MPCSafetyFilter, lazy constraints): (input box included,
    # position-box faces included (bool per finite face), obstacles included (K,)
    # bool); None: the full QP.
    relaxed: tuple[bool, np.ndarray, np.ndarray] | None = None

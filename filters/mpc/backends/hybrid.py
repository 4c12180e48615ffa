r"""Soft QPs of long horizons: DAQP within an iteration budget, else an interior-point method.

A QP with soft rows (the recovery QP, and the primary QP of ``soft=True``) is the exact
L1 penalty problem

.. math::

    \min_u\; J(u) + \rho \sum_i \max\big(0,\; g_i^\top u - h_i\big)
    \quad \text{s.t. the input box},

whose optimum is unique (``J`` is strictly convex). Which solver is faster depends on
how many soft rows the optimum violates, which is known only after the solve:

* a dual active-set method (DAQP, the lazy whitened condensed QP of
  :mod:`filters.mpc.backends.daqp`) adds one row to its working set per iteration, and
  every violated row ends in it: a step that violates a few rows takes tens of
  iterations and is far faster than any interior-point method, a strongly infeasible
  long-horizon step that violates hundreds takes hundreds to thousands;
* an interior-point method takes about twenty iterations whatever the number of
  violated rows, each linear in the horizon and the rows: the compiled Riccati method of
  :mod:`filters.mpc.backends.riccati` when every row is soft (the recovery QP), PIQP on
  the sparse QP of :mod:`filters.mpc.backends.piqp` otherwise (``soft=True``, whose
  arena rows stay hard).

:class:`ActiveSetThenInteriorPoint` therefore gives DAQP a budget of
:data:`ITERATION_BUDGET` iterations over the relaxed QPs of one solve; a solve
that runs out of it (or fails otherwise) is solved again by the interior-point method.
In a closed loop an infeasible step is usually followed by another with as many
violated rows, so after an interior-point answer that violates more than
:data:`RETRY_ROWS` soft rows the next step goes to it directly; the first step whose
answer violates fewer goes back to DAQP, and so does every episode's first step
(:meth:`reset`).

Both solve the same QP, so the choice changes only the work and the answer within the
solvers' tolerances (the back-end suite checks both against the CVXPY reference). The
choice depends only on the steps of the episode so far: the same episode gives the same
answers.
"""

from __future__ import annotations

import numpy as np

from filters.errors import InvalidParameterError
from filters.mpc.backends.daqp import DAQPBackend
from filters.mpc.backends.piqp import PIQPBackend
from filters.mpc.backends.riccati import RiccatiBackend, every_row_soft
from filters.mpc.filter import SLACK_TOLERANCE
from filters.mpc.problem import MPCProblem
from filters.mpc.result import QPSolution, StepData

__all__ = ["ITERATION_BUDGET", "RETRY_ROWS", "ActiveSetThenInteriorPoint"]

#: DAQP iterations (over the relaxed QPs of one solve) before the QP goes to the
#: interior-point method. On the scaling grid's recovery QPs one DAQP iteration cost
#: 5-30 µs (T = 40-80), one PIQP solve 2-7 ms (250-800 DAQP iterations) and one Riccati
#: solve 0.6-2.5 ms; budgets of 30, 80, 150 and 250 gave step times within the noise
#: of each other (±15 %) at the T = 40 and 80 points of both instance families.
ITERATION_BUDGET = 250
#: After an interior-point answer that violates more soft rows than this, the next step
#: goes to the interior-point method directly. DAQP took 10-60 iterations per violated
#: row on the scaling grid's recovery QPs (up to 330 iterations with 6 violated rows,
#: 450-1700 with 10-40).
RETRY_ROWS = 8


class ActiveSetThenInteriorPoint:
    """A QP with soft rows: DAQP within :data:`ITERATION_BUDGET`, else an interior-point method.

    The interior-point method is :class:`~filters.mpc.backends.riccati.RiccatiBackend`
    when every row of ``problem`` is soft (:attr:`name` ``"daqp+riccati"``), else
    :class:`~filters.mpc.backends.piqp.PIQPBackend` (``"daqp+piqp"``); module docstring.

    Parameters
    ----------
    problem
        The problem (with soft rows; a hard one works too, but the budget then only
        turns DAQP's infeasibility detection over to PIQP).
    iteration_budget
        DAQP iterations (over the relaxed QPs of one solve) before the interior-point
        method takes over, ``>= 1``.
    """

    def __init__(self, problem: MPCProblem, *, iteration_budget: int = ITERATION_BUDGET) -> None:
        if iteration_budget is None:  # DAQPBackend checks the rest
            raise InvalidParameterError("iteration_budget must be an integer >= 1, got None")
        self.active_set = DAQPBackend(problem, lazy=True, iteration_budget=iteration_budget)
        self.problem = problem
        self.iteration_budget = int(iteration_budget)
        if every_row_soft(problem):
            self.interior_point: RiccatiBackend | PIQPBackend = RiccatiBackend(problem)
        else:
            self.interior_point = PIQPBackend(problem)
        #: ``"daqp+riccati"`` or ``"daqp+piqp"``.
        self.name = f"daqp+{self.interior_point.name}"
        self._skip_active_set = False
        #: Which back end answered the last solve (``"daqp"``, ``"riccati"``, ``"piqp"``
        #: or ``""``).
        self.last_used = ""

    def reset(self) -> None:
        """A new episode: forget the warm start and go back to DAQP first."""
        self.active_set.reset()
        self._skip_active_set = False

    def solve(self, step: StepData) -> QPSolution:
        """DAQP within the budget, else the interior-point method; never raises on failure."""
        iterations, solve_time = 0, 0.0
        if not self._skip_active_set:
            first = self.active_set.solve(step)
            if first.found:
                self.last_used = "daqp"
                return first
            iterations, solve_time = first.iterations, first.solve_time
        answer = self.interior_point.solve(step)
        self.last_used = self.interior_point.name
        self._skip_active_set = answer.found and _violated_rows(answer) > RETRY_ROWS
        return QPSolution(answer.found, answer.status, answer.inputs, answer.halfspace_slack,
                          answer.bound_slack, iterations + answer.iterations,
                          solve_time + answer.solve_time)


def _violated_rows(solution: QPSolution) -> int:
    """Soft rows the answer violates (slack above the filter's ``SLACK_TOLERANCE``)."""
    count = 0
    for slack in (solution.halfspace_slack, solution.bound_slack):
        if slack is not None:
            count += int(np.count_nonzero(slack > SLACK_TOLERANCE))
    return count


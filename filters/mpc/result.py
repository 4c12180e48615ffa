"""Value objects of the MPC safety filter: what one step returns, and what a back end reports.

* :class:`FilterStatus` and :class:`FilterResult` are the public result of
  :meth:`filters.mpc.MPCSafetyFilter.solve`.
* :class:`QPSolution` is what every back end's ``solve(step)`` hands back to the filter,
  which checks it and turns it into a :class:`FilterResult` (or a recovery).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from filters.constants import DISABLED_OFFSET

__all__ = ["FilterResult", "FilterStatus", "QPSolution", "StepData"]


class FilterStatus(str, Enum):
    """What the safety filter returned, and which recovery (if any) produced it.

    The hard QP (every halfspace, arena and terminal row hard; halfspace rows soft
    only with ``soft=True``) is always solved first.
    """

    OPTIMAL = "optimal"
    """Problem 2 was solved and every row holds (to 1e-6): the inputs are its minimiser.
    Also returned when no QP was needed (the unconstrained optimum was feasible), and by
    the recovery QP when all its slacks are ~0."""
    SOFT = "soft"
    """Solved with some halfspace row violated (``slack > 1e-6``), the arena and the
    terminal set held: by ``soft=True``, or by the recovery QP of ``fallback="soft"``."""
    RECOVERY = "recovery"
    """``fallback="soft"``: the hard QP failed and the recovery QP (every halfspace,
    arena and terminal row softened with the exact L1 penalty) had to violate an arena
    or terminal row (``bound_slack > 1e-6``): the ego is being brought back."""
    SHIFTED = "shifted"
    """``fallback="paper"``: the QP failed; the last stored plan, shifted by the number
    of consecutive failures, padded with braking (the paper's Remark)."""
    BRAKE = "brake"
    """Last resort: the QP (and the recovery QP) failed and no stored plan was usable:
    braking inputs (``brake_gain``) from ``x0`` over the whole horizon."""
    ERROR = "error"
    """Bad data (NaN, wrong shapes) reached the filter: the filter raises, and
    :class:`filters.SafetyFilterWrapper` brakes and reports this status with the reason."""


@dataclass(frozen=True)
class FilterResult:
    """Result of one safety-filter step, in the spirit of qpsolvers' ``Solution``.

    Attributes
    ----------
    status
        What was returned (see :class:`FilterStatus`).
    inputs
        Inputs :math:`u_0, \\dots, u_{T-1}`, shape ``(T, m)`` (m/s²); ``inputs[0]``
        is the one to apply now.
    states
        States :math:`x_0, \\dots, x_T` rolled out from the actual ``x0`` with
        ``inputs``, shape ``(T + 1, n)``.
    solve_time
        Wall time of the solver calls of this step, in s (0 when no QP was solved).
    total_time
        Wall time of the whole :meth:`~filters.mpc.MPCSafetyFilter.solve` call, in s.
    slack
        Halfspace violations :math:`\\max(0, a_{i,t}^\\top C x_t - b_{i,t})` of the
        returned trajectory in m, shape ``(k, T)`` for the ``k`` rows given (entries
        ``<= 1e-6`` reported as 0). ``None`` when the filter is hard (``soft=False``)
        and the hard QP answered; always an array after a recovery or fallback.
    bound_slack
        Total violation, in m, of the arena rows and the terminal rows by the
        returned trajectory (0 unless the ego is outside, or brought back).
    solver_status
        The back end's status (Clarabel's ``SolverStatus`` name, CVXPY's status), with
        the reason a solution was rejected, and which QP answered.
    iterations
        Interior-point iterations of this step (every QP solved, added up).
    objective
        The cost (8) of the returned trajectory (the recovery's L1 penalty not included).
    consecutive_failures
        Steps in a row, this one included, whose hard QP failed (0 when it answered).
        On ``SHIFTED`` it is the shift applied to the stored plan.
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
    bound_slack: float = 0.0

    @property
    def first_input(self) -> np.ndarray:
        """The input to apply now, ``inputs[0]``, shape ``(m,)``."""
        return self.inputs[0]

    @property
    def solved(self) -> bool:
        """Whether a QP answer was returned (``OPTIMAL``, ``SOFT`` or ``RECOVERY``)."""
        return self.status in (FilterStatus.OPTIMAL, FilterStatus.SOFT, FilterStatus.RECOVERY)

    @property
    def fallback(self) -> bool:
        """Whether a fallback without QP answer (``SHIFTED`` or ``BRAKE``) was returned."""
        return not self.solved


@dataclass(frozen=True)
class QPSolution:
    """What a back end's ``solve(step)`` reports (it never raises on a failed solve).

    Attributes
    ----------
    found
        Whether the solver says it solved the QP (Clarabel "Solved"/"AlmostSolved",
        CVXPY "optimal"/"optimal_inaccurate") and returned finite inputs.
    status
        The solver's status, or ``"exception: ..."``.
    inputs
        ``(T, m)`` when ``found``, else ``None``.
    halfspace_slack
        The solver's slacks of the (padded) halfspace rows, ``(K, T)``, when they are soft.
    bound_slack
        The solver's slacks of the arena and terminal rows, 1-D, when they are soft.
    iterations
        Interior-point iterations.
    solve_time
        Wall time of the solver call, in s.
    """

    found: bool
    status: str
    inputs: np.ndarray | None = None
    halfspace_slack: np.ndarray | None = None
    bound_slack: np.ndarray | None = None
    iterations: int = 0
    solve_time: float = 0.0


@dataclass(frozen=True)
class StepData:
    """One step's numbers, as every back end's ``solve`` takes them.

    Attributes
    ----------
    x0
        Current state, ``(n,)``.
    ref_states
        Reference states :math:`x^r_1..x^r_T`, ``(T, n)``.
    ref_inputs
        Reference inputs :math:`u^r_0..u^r_{T-1}`, ``(T, m)``.
    normals, offsets
        Halfspaces padded to the problem's ``n_obstacles`` rows, ``(K, T, d)`` and ``(K, T)``
        (unused rows read ``0 @ y <= 1``).
    """

    x0: np.ndarray
    ref_states: np.ndarray
    ref_inputs: np.ndarray
    normals: np.ndarray
    offsets: np.ndarray


class PaddedSteps:
    """The back ends' step data, halfspaces padded to ``K`` rows.

    The ``k`` rows given are copied into new ``(K, T, d)`` and ``(K, T)`` arrays (copies
    of templates) whose other rows read ``0 @ y <= DISABLED_OFFSET`` (always met).
    """

    def __init__(self, K: int, T: int, d: int) -> None:
        self._normals = np.zeros((K, T, d))
        self._offsets = np.full((K, T), DISABLED_OFFSET)

    def __call__(self, x0: np.ndarray, ref_states: np.ndarray, ref_inputs: np.ndarray,
                 normals: np.ndarray, offsets: np.ndarray) -> StepData:
        k = normals.shape[0]
        padded_normals, padded_offsets = self._normals.copy(), self._offsets.copy()
        padded_normals[:k] = normals
        padded_offsets[:k] = offsets
        step = object.__new__(StepData)  # the frozen __init__ costs a call per field
        step.__dict__.update(x0=x0, ref_states=ref_states, ref_inputs=ref_inputs,
                             normals=padded_normals, offsets=padded_offsets)
        return step


def filter_result(
    status: FilterStatus, inputs: np.ndarray, states: np.ndarray, slack: np.ndarray | None,
    bound_slack: float, solver_status: str, iterations: int, solve_time: float,
    objective: float, total_time: float, failures: int,
) -> FilterResult:
    """A :class:`FilterResult` with its arrays made read-only (built without the frozen
    ``__init__``, which costs a call per field: this runs every filter step)."""
    for array in (inputs, states, slack):
        if array is not None:
            array.setflags(write=False)
    result = object.__new__(FilterResult)
    result.__dict__.update(
        status=status, inputs=inputs, states=states, solve_time=solve_time, total_time=total_time,
        slack=slack, solver_status=solver_status, iterations=iterations, objective=objective,
        consecutive_failures=failures, bound_slack=bound_slack)
    return result


def recovery_status(slack: np.ndarray, bound_total: float) -> FilterStatus:
    """The status of an accepted recovery answer: ``"recovery"`` if it used arena or
    terminal slack (``bound_total > 0``), ``"soft"`` if only halfspace slack (``slack``,
    already zeroed below the tolerance), else ``"optimal"`` (the hard QP was feasible
    after all: the exact penalty returned its solution)."""
    if bound_total > 0.0:
        return FilterStatus.RECOVERY
    return FilterStatus.SOFT if slack.any() else FilterStatus.OPTIMAL

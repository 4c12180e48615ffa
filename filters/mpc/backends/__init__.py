"""QP back ends of the MPC safety filter, one signature: ``backend.solve(step) -> QPSolution``.

* :mod:`filters.mpc.backends.daqp`: the whitened condensed (inputs-only) QP in DAQP, a
  dual active-set solver, with lazy rows for long horizons; soft rows as DAQP soft
  constraints (exact L1 penalty). ``"auto"`` uses it for every hard QP and for the soft
  QPs of short horizons.
* :mod:`filters.mpc.backends.clarabel`: the sparse QP built once, updated per step
  (``"auto"`` uses it for the soft QPs of long horizons).
* :mod:`filters.mpc.backends.cvxpy`: the same QP in CVXPY (the readable reference, for
  tests and benchmarks; imports CVXPY).

Each is built for one :class:`~filters.mpc.MPCProblem` and takes a
:class:`~filters.mpc.result.StepData`; it never raises on a failed solve.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from filters.errors import InvalidParameterError
from filters.mpc.problem import MPCProblem

__all__ = ["AUTO_DAQP_MAX_INPUTS", "BACKENDS", "REMOVED_BACKENDS", "auto_backend",
           "check_backend", "make_backend"]

#: Back ends by name: DAQP (the fast default), Clarabel (the design card's solver) and
#: CVXPY (the readable reference, for tests and benchmarks; imports CVXPY when built);
#: ``"auto"`` picks DAQP or Clarabel per QP (see :func:`auto_backend`).
BACKENDS = ("auto", "daqp", "clarabel", "cvxpy")
#: Back-end names of earlier releases that are no longer accepted (a clear error names
#: :data:`BACKENDS`).
REMOVED_BACKENDS = ("piqp", "daqp+piqp", "daqp+riccati", "riccati", "hybrid")
#: ``backend="auto"`` solves QPs with soft rows with DAQP while the condensed QP has at
#: most this many inputs ``T m``, with Clarabel above (see :func:`auto_backend`).
AUTO_DAQP_MAX_INPUTS = 40


def check_backend(name: object) -> None:
    """Raise :class:`~filters.errors.InvalidParameterError` unless ``name`` is in
    :data:`BACKENDS`; a name of :data:`REMOVED_BACKENDS` is told so."""
    if name in REMOVED_BACKENDS:
        raise InvalidParameterError(
            f"backend {name!r} was removed (one implementation of the filter step); "
            f"use one of {BACKENDS} (\"auto\": DAQP, Clarabel for long soft QPs)")
    if name not in BACKENDS:
        raise InvalidParameterError(f"backend must be one of {BACKENDS}, got {name!r}")


def auto_backend(problem: MPCProblem) -> str:
    r"""The back end ``backend="auto"`` picks for one QP of the filter.

    * A QP without soft rows (the hard QP): ``"daqp"`` at every size. DAQP solves the
      whitened condensed QP (identity Hessian), and above
      :data:`~filters.mpc.backends.daqp.LAZY_MIN_INPUTS` inputs with lazy (screened)
      rows warm-started from the previous step, so its work grows with the rows that
      matter, not with all of them; an infeasible hard QP is detected in a few
      iterations.
    * A QP with soft rows (``soft=True``, and the recovery QP): ``"daqp"`` while
      :math:`T m \le` :data:`AUTO_DAQP_MAX_INPUTS`, else ``"clarabel"``. An active-set
      method adds every violated soft row to its working set, one per iteration, so a
      strongly infeasible long-horizon QP costs it hundreds of iterations, while an
      interior-point method's iteration count hardly depends on how many rows end up
      violated.

    ``safe-nav bench --scaling`` prints the times of each explicit back end.
    """
    if problem.soft_rows and problem.horizon * problem.m > AUTO_DAQP_MAX_INPUTS:
        return "clarabel"
    return "daqp"


def make_backend(name: str, problem: MPCProblem, settings: Mapping[str, Any] | None) -> Any:
    """The back end ``name`` (``"daqp"``, ``"clarabel"`` or ``"cvxpy"``) built for ``problem``."""
    if name == "clarabel":
        from filters.mpc.backends.clarabel import ClarabelBackend

        return ClarabelBackend(problem, solver_settings=settings)
    if name == "daqp":
        from filters.mpc.backends.daqp import DAQPBackend

        return DAQPBackend(problem, solver_settings=settings)
    from filters.mpc.backends.cvxpy import CVXPYBackend  # imports cvxpy

    return CVXPYBackend(problem, solver_settings=settings)

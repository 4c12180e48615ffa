"""QP back ends of the MPC safety filter, one signature: ``backend.solve(step) -> QPSolution``.

* :mod:`filters.mpc.backends.daqp`: the condensed (inputs-only) QP in DAQP, a dual
  active-set solver; soft rows as DAQP soft constraints (exact L1 penalty). The
  default (``backend="auto"``) for short horizons.
* :mod:`filters.mpc.backends.clarabel`: the sparse QP built once, updated per step.
* :mod:`filters.mpc.backends.cvxpy`: the same QP in CVXPY (the reference; imports CVXPY).

Each is built for one :class:`~filters.mpc.MPCProblem` and takes a
:class:`~filters.mpc.result.StepData`; it never raises on a failed solve.
"""

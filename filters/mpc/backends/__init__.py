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

"""QP back ends of the MPC safety filter, one signature: ``backend.solve(step) -> QPSolution``.

* :mod:`filters.mpc.backends.daqp`: the whitened condensed (inputs-only) QP in DAQP, a
  dual active-set solver, with lazy rows for long horizons; soft rows as DAQP soft
  constraints (exact L1 penalty). ``"auto"`` uses it for every hard QP.
* :mod:`filters.mpc.backends.clarabel`: the sparse QP built once, updated per step.
* :mod:`filters.mpc.backends.piqp`: the same sparse QP in PIQP (proximal interior point).
* :mod:`filters.mpc.backends.riccati`: a QP whose every row is soft (the recovery QP)
  by a compiled primal-dual interior-point method whose Newton steps are Riccati
  recursions over the horizon.
* :mod:`filters.mpc.backends.hybrid`: DAQP within an iteration budget, then an
  interior-point method (Riccati when every row is soft, else PIQP); ``"auto"`` uses it
  for the QPs with soft rows of long horizons.
* :mod:`filters.mpc.backends.cvxpy`: the same QP in CVXPY (the reference; imports CVXPY).

Each is built for one :class:`~filters.mpc.MPCProblem` and takes a
:class:`~filters.mpc.result.StepData`; it never raises on a failed solve.
"""

"""``safe-nav bench``'s QP passes: ours against CVXPY on the same recorded steps."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.filter_qp import (
    TS,
    agreement,
    benchmark_filter_qp,
    double_integrator,
    filter_kwargs,
    make_instances,
    max_input_gap,
    solver_passes,
)


@pytest.mark.slow
def test_every_pass_solves_the_same_steps_and_ours_agrees_with_cvxpy():
    instances = make_instances(15, 3, 10, np.random.default_rng(1))
    passes, ours = solver_passes(*double_integrator(TS), filter_kwargs(10, 3), instances,
                                 zero_inputs=True)
    assert set(passes) == {"ours", "cvxpy", "daqp", "clarabel", "zero_inputs"}
    assert all(len(p.ms) == 15 and (p.ms > 0).all() for p in passes.values())
    assert ours.backend in ("daqp", "clarabel")
    assert agreement(passes["ours"], passes["cvxpy"]) == 1.0
    assert max_input_gap(passes["ours"].results, passes["cvxpy"].results) < 1e-4
    assert (passes["cvxpy"].qp_solves >= 1).all()  # the reference never skips the QP


@pytest.mark.slow
def test_the_report_names_every_measurement():
    text = benchmark_filter_qp(n_steps=15, seed=1)
    for words in ("15 steps", "solver calls", "first compile", "steps that needed a QP",
                  "recovery QP solved on", "reference_inputs = 0", "same as CVXPY's on 100.0%",
                  "daqp      QP", "clarabel  QP"):
        assert words in text

"""``backend="auto"``'s soft QPs of long horizons: DAQP within a budget, else an
interior-point method (the Riccati one for the recovery QP, PIQP for ``soft=True``).

:class:`filters.mpc.backends.hybrid.ActiveSetThenInteriorPoint` must return DAQP's
answer bit for bit when DAQP finishes within the budget, the interior-point method's
when it does not, go to it directly after a strongly infeasible step and back to DAQP
after a mildly infeasible one or a reset; and the filter that uses it must agree with
the CVXPY reference. The instances are the scaling benchmark's strongly infeasible crossings
(the ``straight`` family at T = 40: the reference leaves the arena, 10 obstacles).
"""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.filter_qp import RADIUS, double_integrator, filter_kwargs
from benchmarks.scaling import make_scaling_instances
from filters import Disc, safe_halfspaces
from filters.errors import InvalidParameterError
from filters.mpc import FilterStatus, MPCSafetyFilter

pytest.importorskip("daqp")
pytest.importorskip("piqp")

from filters.mpc.backends.daqp import DAQPBackend  # noqa: E402
from filters.mpc.backends.hybrid import (  # noqa: E402
    RETRY_ROWS,
    ActiveSetThenInteriorPoint,
    _violated_rows,
)
from filters.mpc.backends.piqp import PIQPBackend  # noqa: E402
from filters.mpc.backends.riccati import RiccatiBackend  # noqa: E402
from filters.mpc.result import StepData  # noqa: E402

A, B, C = double_integrator()
T, K, N_S = 40, 10, 20


@pytest.fixture(scope="module")
def episode() -> list[tuple[object, object]]:
    """Recorded steps ``(instance, halfspaces)`` of strongly infeasible crossings."""
    rng = np.random.default_rng(7)
    instances = make_scaling_instances(24, K, T, N_S, rng, family="straight")
    shapes = [Disc(RADIUS)] * K
    return [(i, safe_halfspaces(i.reference_states[1:, :2], i.samples, ego_shape=Disc(RADIUS),
                                obstacle_shapes=shapes, risk="dr_cvar",
                                ego_velocity=i.x0[2:])) for i in instances]


def recovery_problem():
    return MPCSafetyFilter(A, B, C, **filter_kwargs(T, K))._recovery.problem


def steps(episode) -> list[tuple[bool, StepData]]:
    zero = np.zeros((T, 2))
    return [(i.new_episode, StepData(i.x0, i.reference_states[1:], zero,
                                     np.asarray(hs.normals), np.asarray(hs.offsets)))
            for i, hs in episode]


def test_auto_builds_it_for_the_recovery_qp_of_long_horizons():
    mpc = MPCSafetyFilter(A, B, C, **filter_kwargs(T, K))
    assert isinstance(mpc._recovery, ActiveSetThenInteriorPoint)
    assert mpc.recovery_backend == "daqp+riccati"
    assert isinstance(mpc._recovery.interior_point, RiccatiBackend)
    soft = MPCSafetyFilter(A, B, C, soft=True, **filter_kwargs(T, K))  # arena rows hard
    assert soft.backend == "daqp+piqp"
    assert isinstance(soft._primary.interior_point, PIQPBackend)
    for bad in (0, -1, 1.5, True, None):
        with pytest.raises(InvalidParameterError, match="iteration_budget"):
            ActiveSetThenInteriorPoint(recovery_problem(), iteration_budget=bad)


def test_within_the_budget_it_is_daqp_bit_for_bit_and_else_the_interior_point(episode):
    problem = recovery_problem()
    roomy = ActiveSetThenInteriorPoint(problem, iteration_budget=10**6)
    daqp = DAQPBackend(problem, lazy=True)
    starved = ActiveSetThenInteriorPoint(problem, iteration_budget=1)
    riccati = RiccatiBackend(problem)
    violated = 0
    for new, step in steps(episode):
        if new:
            roomy.reset()
            daqp.reset()
            starved.reset()
        ours, theirs = roomy.solve(step), daqp.solve(step)
        assert roomy.last_used == "daqp" and ours.found and theirs.found
        np.testing.assert_array_equal(ours.inputs, theirs.inputs)
        assert ours.iterations == theirs.iterations
        ours, theirs = starved.solve(step), riccati.solve(step)
        assert starved.last_used == "riccati" and ours.found and theirs.found
        np.testing.assert_array_equal(ours.inputs, theirs.inputs)
        violated = max(violated, _violated_rows(theirs))
    assert violated > RETRY_ROWS  # the episode has strongly infeasible steps


def test_a_strongly_infeasible_step_sends_the_next_to_the_interior_point_until_few_rows(
        episode):
    hybrid = ActiveSetThenInteriorPoint(recovery_problem())
    calls = []
    solve = hybrid.active_set.solve
    hybrid.active_set.solve = lambda step: calls.append(1) or solve(step)
    sequence = steps(episode)
    previous_skip = False
    for new, step in sequence:
        if new:
            hybrid.reset()
            previous_skip = False
        before = len(calls)
        answer = hybrid.solve(step)
        assert answer.found
        tried_daqp = len(calls) > before
        assert tried_daqp == (not previous_skip)
        if hybrid.last_used == "riccati":
            previous_skip = _violated_rows(answer) > RETRY_ROWS
        else:
            previous_skip = False
    assert hybrid.last_used in ("daqp", "riccati")
    # reset: DAQP first again
    hybrid.reset()
    before = len(calls)
    hybrid.solve(sequence[0][1])
    assert len(calls) == before + 1


def test_the_filter_with_it_agrees_with_the_cvxpy_reference(episode):
    pytest.importorskip("cvxpy")
    kwargs = filter_kwargs(T, K)
    ours = MPCSafetyFilter(A, B, C, **kwargs)
    reference = MPCSafetyFilter(A, B, C, backend="cvxpy", skip_feasible_reference=False,
                                **kwargs)
    used = set()
    for instance, hs in episode[:12]:
        if instance.new_episode:
            ours.reset()
            reference.reset()
        mine = ours.solve(instance.x0, instance.reference_states, hs)
        theirs = reference.solve(instance.x0, instance.reference_states, hs)
        assert mine.status == theirs.status
        if mine.status in (FilterStatus.SOFT, FilterStatus.RECOVERY):
            used.add(ours._recovery.last_used)
            # the L1 penalty dwarfs the quadratic cost: the violations and the first
            # input agree, the later inputs only loosely (see tests/test_mpc_backends.py)
            assert mine.slack.sum() == pytest.approx(theirs.slack.sum(), rel=1e-4, abs=1e-4)
            assert mine.bound_slack == pytest.approx(theirs.bound_slack, rel=1e-5, abs=1e-4)
            np.testing.assert_allclose(mine.inputs[0], theirs.inputs[0], atol=3e-3)
        elif mine.status == FilterStatus.OPTIMAL:  # the hard QP (DAQP), not this back end;
            # a far reference (costs ~1e4) leaves Clarabel's answer ~1e-4 off
            assert mine.objective == pytest.approx(theirs.objective, rel=1e-6)
            np.testing.assert_allclose(mine.inputs, theirs.inputs, atol=1e-3)
    assert used  # the recovery QP was solved

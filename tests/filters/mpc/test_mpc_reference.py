"""The MPC step against its readable CVXPY formulation, by tolerance (DESIGN §6).

* the filter's default step (``backend="auto"``: DAQP) and Clarabel against the same QP
  in CVXPY solved to tight tolerances, on seeded random instances: the same status
  (hard optimal, or infeasible and then the recovery QP), inputs within
  :data:`INPUT_TOLERANCE` when the hard QP answered;
* the recovery QP (every row softened, exact L1 penalty) against its CVXPY formulation:
  the same penalised objective and total violation;
* *update equals rebuild* (qpmpc's invariant): a back end whose data were updated step
  after step answers as one built for that step alone;
* a failed solve (a back end that raises, returns NaN or refuses) returns a status and a
  fallback, never raises.
"""

from __future__ import annotations

import numpy as np
import pytest

from filters.errors import InvalidParameterError
from filters.mpc import FilterStatus, MPCSafetyFilter
from filters.mpc.backends.cvxpy import CVXPYBackend
from filters.mpc.filter import BACKENDS, REMOVED_BACKENDS
from filters.mpc.result import QPSolution, StepData
from tests.builders import (
    KWARGS,
    TERMINAL,
    A,
    B,
    C,
    infeasible_halfspaces,
    make_filter,
    random_instance,
    solve,
)

#: Largest difference of the inputs (m/s²) between a back end and the CVXPY reference.
INPUT_TOLERANCE = 1e-6
#: Clarabel settings of the reference: gaps and feasibility far below INPUT_TOLERANCE.
TIGHT = {name: 1e-12 for name in ("tol_feas", "tol_gap_abs", "tol_gap_rel")}
OBJECTIVES = ["trajectory", "first_input"]


def _reference(objective: str, **change) -> MPCSafetyFilter:
    return make_filter("cvxpy", objective=objective, solver_settings=TIGHT, **change)


def _instances(rng: np.random.Generator, count: int) -> list[dict]:
    """Random crossings, some with reference inputs, some with an unreachable wall."""
    out = []
    for index in range(count):
        case = random_instance(rng, int(rng.integers(1, 4)), with_inputs=bool(index % 2))
        if index % 4 == 3:  # the hard QP is infeasible: the recovery QP answers
            case["halfspaces"] = infeasible_halfspaces()
        out.append(case)
    return out


@pytest.mark.parametrize("backend", ["auto", "clarabel"])
@pytest.mark.parametrize("objective", OBJECTIVES)
def test_the_step_equals_the_cvxpy_formulation(backend, objective):
    ours = make_filter(backend, objective=objective, skip_feasible_reference=False,
                       terminal_set=TERMINAL)
    if backend == "clarabel":
        ours = make_filter(backend, objective=objective, skip_feasible_reference=False,
                           terminal_set=TERMINAL, solver_settings=TIGHT)
    reference = _reference(objective, terminal_set=TERMINAL)
    rng = np.random.default_rng([23, OBJECTIVES.index(objective)])
    seen = set()
    for case in _instances(rng, 16):
        mine, theirs = solve(ours, case), solve(reference, case)
        assert mine.status == theirs.status, (mine.solver_status, theirs.solver_status)
        assert ours.last_qp_solves == reference.last_qp_solves
        seen.add(mine.status)
        if ours.last_qp_solves == 1:  # the hard QP answered: its unique minimiser
            np.testing.assert_allclose(mine.inputs, theirs.inputs, rtol=0,
                                       atol=INPUT_TOLERANCE)
            assert mine.objective == pytest.approx(theirs.objective, rel=1e-7, abs=1e-7)
        else:  # the recovery QP: the same total violation (1e-5 relative: sums of 2 T rows)
            assert mine.bound_slack == pytest.approx(theirs.bound_slack, rel=1e-5, abs=1e-6)
            np.testing.assert_allclose(mine.slack.sum(), theirs.slack.sum(), rtol=1e-5, atol=1e-6)
    assert FilterStatus.OPTIMAL in seen and seen - {FilterStatus.OPTIMAL}


@pytest.mark.parametrize("backend", ["daqp", "clarabel"])
def test_the_recovery_qp_equals_its_cvxpy_formulation(backend):
    """Every row soft: the exact-penalty objective and the violations of the answer agree
    with CVXPY's (the L1 penalty leaves the later inputs weakly determined, so the
    inputs are compared through what they cost and violate)."""
    mpc = make_filter(backend, terminal_set=TERMINAL)
    problem = mpc._rescue.problem  # the second recovery QP: arena and terminal soft too
    assert problem.soft_rows == {"halfspaces", "bounds"}
    assert mpc._recovery.problem.soft_rows == {"halfspaces"}
    reference = CVXPYBackend(problem, solver_settings=TIGHT)
    rng = np.random.default_rng(5)
    rho = problem.slack_penalty
    compared = 0
    for case in _instances(rng, 12):
        normals, offsets = case["halfspaces"]
        normals, offsets = np.array(normals), np.array(offsets) - rng.uniform(0.0, 2.0)
        padded_n, padded_o = np.zeros((3, 10, 2)), np.ones((3, 10))
        padded_n[: len(normals)], padded_o[: len(offsets)] = normals, offsets
        if rng.random() < 0.5:  # outside the arena, moving out: arena slack needed
            case["x0"][0], case["x0"][2] = -5.0 - rng.uniform(0.05, 0.5), -1.0
        inputs = case.get("reference_inputs", np.zeros((10, 2)))
        step = StepData(case["x0"], case["reference_states"][1:], inputs, padded_n, padded_o)
        answers = [backend_.solve(step) for backend_ in (mpc._rescue, reference)]
        assert all(answer.found for answer in answers)
        totals = []
        for answer in answers:
            states = [case["x0"]]
            for u in answer.inputs:
                states.append(A @ states[-1] + B @ u)
            states = np.array(states)
            positions = states[1:] @ C.T
            excess = np.einsum("ktd,td->kt", padded_n, positions) - padded_o
            arena = np.maximum(np.abs(positions) - 5.0, 0.0).sum()
            G, g = TERMINAL
            terminal = np.maximum(G @ states[-1] - g, 0.0).sum()
            violation = np.maximum(excess, 0.0).sum() + arena + terminal
            cost = problem.cost(answer.inputs, states, step.ref_states, inputs)
            totals.append((violation, cost + rho * violation))
        (violation, penalised), (violation_ref, penalised_ref) = totals
        assert violation == pytest.approx(violation_ref, abs=1e-6)
        assert penalised == pytest.approx(penalised_ref, rel=1e-7, abs=1e-3)
        compared += violation_ref > 1e-3
    assert compared >= 3


@pytest.mark.parametrize(("backend", "horizon", "mode"), [
    ("daqp", 10, "hard"), ("daqp", 10, "recovery"), ("daqp", 30, "hard"),
    ("daqp", 30, "recovery"), ("clarabel", 10, "hard"), ("clarabel", 10, "recovery"),
])
def test_update_equals_rebuild(backend, horizon, mode):
    """A back end updated step after step (the filter's: built once, data written per
    step) answers as one built for that step alone, on a closed-loop sequence with
    infeasible steps (``mode="recovery"``: the recovery QP). ``reset()`` before each step
    drops DAQP's warm start (the previous answer and active set), which changes the
    work, not the data."""
    from benchmarks.filter_qp import filter_kwargs

    kwargs = {**filter_kwargs(horizon, 3), "skip_feasible_reference": False}

    def build() -> MPCSafetyFilter:
        return MPCSafetyFilter(A, B, C, backend=backend, **kwargs)

    kept = build()
    x = np.array([-4.0, 0.0, 1.0, 0.0])
    rng = np.random.default_rng([horizon, len(mode)])
    for step in range(12):
        reference = np.zeros((horizon + 1, 4))
        reference[:, 0] = x[0] + 1.0 * 0.2 * np.arange(horizon + 1)
        reference[:, 2] = 1.0
        obstacle = x[:2] + np.array([rng.uniform(1.0, 3.0), rng.uniform(-0.5, 0.5)])
        direction = np.tile(obstacle - reference[1:, :2], (1, 1, 1))
        normals = direction / np.linalg.norm(direction, axis=-1, keepdims=True)
        offsets = np.einsum("ktd,d->kt", normals, obstacle) - 0.6
        if mode == "recovery" and step % 3 == 2:
            normals, offsets = infeasible_halfspaces()
            normals, offsets = normals[:, :1].repeat(horizon, 1), offsets[:, :1].repeat(horizon, 1)
        kept.reset()  # forget the warm start (tests/filters/mpc/test_mpc_lazy.py checks it)
        updated = kept.solve(x, reference, (normals, offsets))
        rebuilt = build().solve(x, reference, (normals, offsets))
        assert updated.status == rebuilt.status
        assert kept.last_qp_solves == 1 + (mode == "recovery" and step % 3 == 2)
        np.testing.assert_allclose(updated.inputs, rebuilt.inputs, rtol=0, atol=1e-9)
        x = A @ x + B @ updated.inputs[0]


@pytest.mark.parametrize("backend", ["auto", "daqp", "clarabel", "cvxpy"])
@pytest.mark.parametrize("failure", ["raises", "nan", "refuses"])
def test_a_failed_solve_returns_a_status_never_raises(backend, failure):
    mpc = make_filter(backend, skip_feasible_reference=False)
    rng = np.random.default_rng(3)
    case = random_instance(rng, 2)

    def broken(step):
        if failure == "raises":
            raise RuntimeError("solver crashed")
        if failure == "nan":
            return QPSolution(True, "Solved", np.full((10, 2), np.nan))
        return QPSolution(False, "PrimalInfeasible")

    for backend_ in (mpc._primary, mpc._recovery, mpc._rescue):
        backend_.solve = broken
    result = solve(mpc, case)
    assert result.status is FilterStatus.BRAKE
    assert result.inputs.shape == (10, 2) and np.isfinite(result.inputs).all()
    assert mpc.last_qp_solves == 3  # the hard QP and both recovery QPs
    assert "hard QP" in result.solver_status


@pytest.mark.parametrize("name", REMOVED_BACKENDS)
def test_a_removed_backend_names_the_accepted_ones(name):
    with pytest.raises(InvalidParameterError, match="auto") as error:
        MPCSafetyFilter(A, B, C, backend=name, **KWARGS)
    assert repr(name) in str(error.value) and str(BACKENDS) in str(error.value)


def test_fast_path_is_deprecated_and_changes_nothing():
    rng = np.random.default_rng(9)
    case = random_instance(rng, 3)
    with pytest.warns(DeprecationWarning, match="fast_path"):
        old = MPCSafetyFilter(A, B, C, fast_path=True, **KWARGS)
    new = MPCSafetyFilter(A, B, C, **KWARGS)
    np.testing.assert_allclose(solve(old, case).inputs, solve(new, case).inputs, atol=1e-12)

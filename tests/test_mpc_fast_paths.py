"""The fast paths of MPCSafetyFilter give the same answers as the full QP.

* ``skip_feasible_reference``: with reference inputs, the unconstrained minimiser of
  the cost is returned without a QP when it meets every constraint exactly.
* ``lazy_constraints``: a condensed QP with the rows that may be active, checked
  exactly against the rows left out, solved again when it missed one.
"""

from __future__ import annotations

import numpy as np
import pytest

import filters.mpc as mpc_module
from filters.benchmarks.filter_qp import make_instances
from filters.errors import InvalidTypeError
from filters.mpc import FilterStatus, MPCSafetyFilter
from tests.test_mpc import KWARGS, A, B, C, T, cvxpy_filter, infeasible_halfspaces, random_instance

NO_QP = "unconstrained optimum feasible (no QP needed)"


def make(**extra) -> MPCSafetyFilter:
    return MPCSafetyFilter(A, B, C, **{**KWARGS, **extra})


def consistent_reference(rng: np.random.Generator, k: int, margin: float):
    """Inputs, the states they generate, and halfspaces the states keep ``margin`` from."""
    x0 = np.array([rng.uniform(-2, 0), rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-1, 1)])
    inputs = rng.uniform(-1.0, 1.0, (T, 2))
    states = [x0]
    for u in inputs:
        states.append(A @ states[-1] + B @ u)
    states = np.array(states)
    normals = rng.normal(size=(k, T, 2))
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    offsets = np.einsum("ktd,td->kt", normals, states[1:, :2]) + margin
    return x0, inputs, states, (normals, offsets)


def assert_same_answer(ours, theirs, atol=1e-6):
    assert ours.status == theirs.status
    if ours.solved:
        np.testing.assert_allclose(ours.inputs, theirs.inputs, atol=atol)
        np.testing.assert_allclose(ours.states, theirs.states, atol=10 * atol)
        assert ours.objective == pytest.approx(theirs.objective, rel=1e-6, abs=atol)


# --------------------------------------------------------------------------- shortcut
@pytest.mark.parametrize("soft", [False, True])
def test_feasible_reference_skips_the_qp_and_equals_the_qp_answer(soft):
    rng = np.random.default_rng(20)
    fast = make(soft=soft)
    slow = make(soft=soft, skip_feasible_reference=False, lazy_constraints=False)
    for _ in range(30):
        k = int(rng.integers(0, 4))
        x0, inputs, states, halfspaces = consistent_reference(rng, k, rng.uniform(1e-3, 1.0))
        ours = fast.solve(x0, states, halfspaces, reference_inputs=inputs)
        assert ours.status is FilterStatus.OPTIMAL
        assert ours.iterations == 0 and ours.solver_status == NO_QP
        assert fast.last_qp_solves == 0 and ours.solve_time == 0.0
        np.testing.assert_allclose(ours.inputs, inputs, rtol=0, atol=1e-12)  # exact pass-through
        np.testing.assert_allclose(ours.states, states, rtol=0, atol=1e-12)
        assert ours.objective == pytest.approx(0.0, abs=1e-20)
        if soft:
            np.testing.assert_array_equal(ours.slack, 0.0)
            assert ours.slack.shape == (k, T)
        qp = slow.solve(x0, states, halfspaces, reference_inputs=inputs)
        assert slow.last_qp_solves >= 1 and qp.iterations > 0
        assert_same_answer(ours, qp)
        assert not ours.inputs.flags.writeable and not ours.states.flags.writeable


def test_shortcut_returns_the_unconstrained_minimiser_for_an_inconsistent_reference():
    """Reference states that the reference inputs do not generate: not a cost-0 point,
    but the minimiser without constraints is still the QP's answer if it is feasible."""
    rng = np.random.default_rng(21)
    fast, slow = make(), make(skip_feasible_reference=False)
    taken = 0
    for _ in range(20):
        instance = random_instance(rng, 1, with_inputs=True)
        normals, offsets = instance["halfspaces"]
        instance["halfspaces"] = (normals, offsets + 3.0)  # far away
        x0, reference = instance["x0"], instance["reference_states"]
        inputs = 0.3 * instance["reference_inputs"]
        ours = fast.solve(x0, reference, instance["halfspaces"], reference_inputs=inputs)
        theirs = slow.solve(x0, reference, instance["halfspaces"], reference_inputs=inputs)
        reference_solver = cvxpy_filter().solve(
            x0, reference, instance["halfspaces"], reference_inputs=inputs
        )
        taken += fast.last_qp_solves == 0
        assert_same_answer(ours, theirs)
        np.testing.assert_allclose(ours.inputs, reference_solver.inputs, atol=1e-4)
    assert taken >= 15


def _violate_by(x0, inputs, states, halfspaces, which: str):
    """Filter keywords and halfspaces under which exactly one row is violated by 1e-9."""
    normals, offsets = halfspaces
    kwargs = {}
    if which == "halfspace":
        offsets = offsets.copy()
        positions = states[1:, :2]
        offsets[0, 4] = normals[0, 4] @ positions[4] - 1e-9
    elif which == "position":
        kwargs["position_bounds"] = (-5.0, [states[1:, 0].max() - 1e-9, 5.0])
    elif which == "input":
        kwargs["input_bounds"] = (-5.0, [inputs[:, 0].max() - 1e-9, 5.0])
    return kwargs, (normals, offsets)


@pytest.mark.parametrize("which", ["halfspace", "position", "input"])
@pytest.mark.parametrize("lazy", [True, False])
def test_shortcut_is_not_taken_when_one_row_is_violated_by_1e_9(which, lazy):
    rng = np.random.default_rng(22)
    for _ in range(5):
        x0, inputs, states, halfspaces = consistent_reference(rng, 2, 0.5)
        kwargs, halfspaces = _violate_by(x0, inputs, states, halfspaces, which)
        fast = make(lazy_constraints=lazy, **kwargs)
        ours = fast.solve(x0, states, halfspaces, reference_inputs=inputs)
        assert fast.last_qp_solves >= 1
        assert ours.solver_status != NO_QP and ours.iterations > 0
        assert ours.status is FilterStatus.OPTIMAL
        slow = make(skip_feasible_reference=False, lazy_constraints=False, **kwargs)
        # The optimum is within about 1e-9 of the reference, but a row that is
        # active with a zero multiplier (degenerate) leaves an interior-point bias
        # of 1e-5..5e-5 in both QPs (measured): the tolerance of the CVXPY tests.
        assert_same_answer(
            ours, slow.solve(x0, states, halfspaces, reference_inputs=inputs), atol=1e-4
        )
        np.testing.assert_allclose(ours.inputs, inputs, atol=1e-4)


def test_shortcut_needs_reference_inputs():
    """Without reference inputs the QP is always solved (zeros give the same QP)."""
    rng = np.random.default_rng(23)
    x0, _, states, halfspaces = consistent_reference(rng, 1, 0.5)
    fast = make()
    without = fast.solve(x0, states, halfspaces)
    assert fast.last_qp_solves >= 1
    zeros = fast.solve(x0, states, halfspaces, reference_inputs=np.zeros((T, 2)))
    if fast.last_qp_solves == 0:
        np.testing.assert_allclose(zeros.inputs, without.inputs, atol=1e-6)


# --------------------------------------------------------------------------- lazy rows
def _instances(seed: int, n: int):
    """Crossing steps (arena and obstacles active now and then) and random instances."""
    rng = np.random.default_rng(seed)
    steps = make_instances(n, 3, T, rng)
    out = [
        {"x0": s.x0, "reference_states": s.reference_states,
         "halfspaces": (s.normals, s.offsets)} for s in steps
    ]
    out += [random_instance(rng, int(rng.integers(0, 4)), with_inputs=True) for _ in range(n)]
    return out


def _solve(mpc, instance):
    return mpc.solve(
        instance["x0"], instance["reference_states"], instance["halfspaces"],
        reference_inputs=instance.get("reference_inputs"),
    )


@pytest.mark.parametrize("soft", [False, True])
def test_lazy_constraints_give_the_full_qp_answer(soft):
    lazy, full = make(soft=soft), make(soft=soft, lazy_constraints=False)
    calls = []
    for instance in _instances(24, 60):
        lazy.reset()
        full.reset()
        ours, theirs = _solve(lazy, instance), _solve(full, instance)
        calls.append(lazy.last_qp_solves)
        assert_same_answer(ours, theirs, atol=2e-5)
        if soft and ours.solved:
            np.testing.assert_allclose(ours.slack, theirs.slack, atol=2e-5)
    assert max(calls) <= 3


@pytest.fixture
def everything_left_out(monkeypatch):
    """Leave every box and obstacle out of the first QP, so that misses happen."""
    monkeypatch.setattr(mpc_module, "BOX_MARGIN", -np.inf)
    monkeypatch.setattr(mpc_module, "HALFSPACE_MARGIN", -np.inf)


@pytest.mark.parametrize("soft", [False, True])
def test_missed_rows_are_added_and_the_answer_is_the_full_qp_answer(soft, everything_left_out):
    lazy, full = make(soft=soft), make(soft=soft, lazy_constraints=False)
    resolved = 0
    for instance in _instances(25, 40):
        lazy.reset()
        full.reset()
        ours, theirs = _solve(lazy, instance), _solve(full, instance)
        resolved += lazy.last_qp_solves >= 2
        assert lazy.last_qp_solves <= 3
        assert_same_answer(ours, theirs, atol=2e-5)
        if ours.status is FilterStatus.OPTIMAL:
            normals, offsets = instance["halfspaces"]
            positions = ours.states[1:] @ C.T
            assert np.max(np.einsum("ktd,td->kt", normals, positions) - offsets,
                          initial=-np.inf) <= 1e-6
            assert np.max(np.abs(positions)) <= 5.0 + 1e-6 and np.max(np.abs(ours.inputs)) <= 5.0
    assert resolved >= 10


def test_left_out_infeasible_rows_still_give_the_fallback(everything_left_out):
    rng = np.random.default_rng(26)
    instance = random_instance(rng, 1)
    lazy, full = make(n_obstacles=1), make(n_obstacles=1, lazy_constraints=False)
    for mpc in (lazy, full):
        assert _solve(mpc, instance).status is FilterStatus.OPTIMAL
    x0, reference = instance["x0"], instance["reference_states"]
    ours = lazy.solve(x0, reference, infeasible_halfspaces())
    theirs = full.solve(x0, reference, infeasible_halfspaces())
    assert ours.status is theirs.status is FilterStatus.SHIFTED
    assert "Infeasible" in ours.solver_status
    np.testing.assert_allclose(ours.inputs, theirs.inputs, atol=1e-6)


def test_lazy_filter_returns_what_a_fresh_one_returns():
    persistent = make()
    for instance in _instances(27, 30):
        persistent.reset()
        used = _solve(persistent, instance)
        fresh = _solve(make(), instance)
        assert used.status == fresh.status
        np.testing.assert_allclose(used.inputs, fresh.inputs, atol=1e-8)


@pytest.mark.parametrize("option", ["skip_feasible_reference", "lazy_constraints"])
def test_fast_path_options_must_be_bools(option):
    with pytest.raises(InvalidTypeError, match=option):
        make(**{option: "yes"})

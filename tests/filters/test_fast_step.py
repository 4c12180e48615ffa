"""The fast filter step (issue 12) against the general path it replaces in the loop.

* the compiled Goldfarb-Idnani solver (:func:`filters.mpc._fast_kernels.ldp_solve`)
  against DAQP and CVXPY on random whitened QPs, feasible and infeasible;
* :class:`filters.mpc.MPCSafetyFilter` with ``fast_path=True`` (the compiled step, with
  the own solver or with DAQP in the middle) against ``fast_path=False`` on sequences of
  random instances: every objective, hard, recovery and the paper's fallback, a
  terminal set or none, with and without reference inputs (the shortcut), fewer rows
  than the QP holds; bad data raises the general path's errors;
* :class:`filters.SafetyFilterWrapper` episodes with ``fast_path`` on and off: the same
  statuses and actions to rounding; the fast path gives the same bits run to run.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401
from benchmarks.filter_qp import double_integrator, filter_kwargs
from filters import SafetyFilterWrapper
from filters.errors import InvalidArrayError
from filters.mpc import FilterStatus, MPCSafetyFilter, stopping_terminal_set
from filters.mpc.fast import INFEASIBLE, SOLVED
from filters.mpc.filter import DISABLED_OFFSET

daqp = pytest.importorskip("daqp")

TS = 0.2
A, B, C = double_integrator(TS)
OBJECTIVES = ["trajectory", "first_input"]
MODES = ["hard", "recovery", "paper"]


# --------------------------------------------------------------------------- the solver
def _kernels():
    from filters.mpc import _fast_kernels

    return _fast_kernels


def _random_qp(rng: np.random.Generator, nu: int, rows: int, infeasible: bool):
    """Rows ``l <= A z <= u`` around a point ``z*`` (so feasible unless made not to be)."""
    matrix = rng.normal(size=(rows, nu))
    matrix[rng.random(rows) < 0.1] *= 1e-3  # badly scaled rows
    if rows > 3:
        matrix[1] = matrix[0]  # a duplicate row
        matrix[2] = -2.0 * matrix[0]  # a parallel one
    inside = rng.normal(size=nu)
    values = matrix @ inside
    upper = values + rng.uniform(0.0, 1.0, rows)
    lower = values - rng.uniform(0.0, 1.0, rows)
    upper[rng.random(rows) < 0.3] = np.inf
    lower[rng.random(rows) < 0.5] = -np.inf
    if infeasible:  # two rows that exclude each other
        matrix[-1] = matrix[-2]
        lower[-1], upper[-1] = upper[-2] + rng.uniform(0.01, 1.0), np.inf
    f = rng.normal(scale=3.0, size=nu)
    return matrix, upper, lower, f


def _daqp(matrix, upper, lower, f):
    nu = f.shape[0]
    x, _, flag, _ = daqp.solve(np.eye(nu), f, matrix, upper, lower,
                               np.zeros(len(upper), dtype=np.intc))
    return np.asarray(x), int(flag)


@pytest.mark.parametrize("nu", [2, 6, 20, 40])
def test_compiled_solver_equals_daqp_and_cvxpy(nu):
    cp = pytest.importorskip("cvxpy")
    kernels = _kernels()
    rng = np.random.default_rng(nu)
    verdicts = {1: 0, -1: 0}
    for case in range(60):
        rows = int(rng.integers(1, 4 * nu + 20))
        infeasible = case % 4 == 3 and rows > 4
        matrix, upper, lower, f = _random_qp(rng, nu, rows, infeasible)
        z = np.empty(nu)
        status, iterations = kernels.ldp_solve(np.ascontiguousarray(matrix.T), upper, lower, f,
                                               z, 1e-9, 10 * (rows + nu))
        theirs, flag = _daqp(matrix, upper, lower, f)
        assert status in (1, -1) and iterations >= 0
        verdicts[status] += 1
        assert (status == 1) == (flag >= 1), (case, status, flag)
        if status != 1:
            continue
        variable = cp.Variable(nu)
        values = matrix @ variable
        rows_cp = ([values[j] <= upper[j] for j in range(rows) if np.isfinite(upper[j])]
                   + [values[j] >= lower[j] for j in range(rows) if np.isfinite(lower[j])])
        cp.Problem(cp.Minimize(0.5 * cp.sum_squares(variable) + f @ variable),
                   rows_cp).solve(solver=cp.CLARABEL, tol_gap_abs=1e-11, tol_gap_rel=1e-11,
                                  tol_feas=1e-11)
        scale = 1.0 + np.abs(z).max()
        np.testing.assert_allclose(z, theirs, atol=1e-6 * scale)  # DAQP's primal tolerance
        np.testing.assert_allclose(z, variable.value, atol=1e-6 * scale)
        excess = np.maximum(matrix @ z - upper, lower - matrix @ z)
        assert excess.max() <= 1e-8 * scale  # every row met (to the solver's tolerance)
    assert verdicts[1] >= 30 and verdicts[-1] >= 5, verdicts


def test_compiled_solver_without_rows_and_with_the_optimum_inside():
    kernels = _kernels()
    f = np.array([1.0, -2.0, 0.5])
    z = np.empty(3)
    assert kernels.ldp_solve(np.empty((3, 0)), np.empty(0), np.empty(0), f, z, 1e-9, 10) == (
        1, 0)
    np.testing.assert_array_equal(z, -f)
    matrix = np.eye(3)
    status, iterations = kernels.ldp_solve(matrix.T.copy(), np.full(3, 5.0),
                                           np.full(3, -5.0), f, z, 1e-9, 10)
    assert (status, iterations) == (1, 0)
    np.testing.assert_array_equal(z, -f)
    # an iteration limit reached is a status, not a loop without end
    status, _ = kernels.ldp_solve(matrix.T.copy(), np.full(3, -1.0), np.full(3, -2.0),
                                  f, z, 1e-9, 1)
    assert status == -4


# --------------------------------------------------------------------------- the filter step
def _make(objective: str, mode: str, fast: bool, *, own: bool = True,
          n_obstacles: int = 4) -> MPCSafetyFilter:
    kwargs = filter_kwargs(10, n_obstacles)
    if objective == "first_input":
        kwargs.pop("Q")
        kwargs.pop("Q_terminal")
    kwargs.update(objective=objective, fallback="paper" if mode == "paper" else "soft")
    if mode != "hard":
        kwargs["terminal_set"] = stopping_terminal_set(
            TS, kwargs["input_bounds"], kwargs["position_bounds"])
    mpc = MPCSafetyFilter(A, B, C, backend="daqp", fast_path=fast, **kwargs)
    if fast:
        assert mpc._fast is not None
        assert (mpc._fast.recovery is not None) == (mode != "paper")
        mpc._fast.own_solver = own
    else:
        assert mpc._fast is None
    return mpc


def _step(rng: np.random.Generator, x0: np.ndarray, mode: str, inputs: bool) -> dict:
    """A crossing step from ``x0``: a straight reference, 1 to 3 obstacles ahead (2 rows
    each, as with the inter-sample rows), pushed in now and then (active rows, infeasible
    steps, the recovery)."""
    T = 10
    speed = 1.5
    reference = np.zeros((T + 1, 4))
    reference[:, 0] = x0[0] + speed * TS * np.arange(T + 1)
    reference[:, 1] = x0[1]
    reference[:, 2] = speed
    reference[0] = x0
    k = int(rng.integers(1, 3))
    start = x0[:2] + np.column_stack([rng.uniform(0.5, 3.0, k), rng.uniform(-1.0, 1.0, k)])
    predicted = start[:, None] + rng.normal(0, 0.4, (k, 1, 2)) * TS * np.arange(1, T + 1)[
        None, :, None]
    direction = predicted - reference[None, 1:, :2]
    normals = direction / np.linalg.norm(direction, axis=-1, keepdims=True)
    offsets = np.einsum("ktd,ktd->kt", normals, predicted) - rng.uniform(0.4, 0.8, (k, 1))
    if mode != "hard" and rng.random() < 0.4:
        offsets = offsets - rng.uniform(0.0, 2.0)
    normals = np.concatenate([normals, normals])  # 2 k rows
    offsets = np.concatenate([offsets, offsets - 0.01])
    step = {"x0": x0, "reference_states": reference, "halfspaces": (normals, offsets)}
    if inputs:
        step["reference_inputs"] = np.clip(rng.normal(0.0, 2.0, (T, 2)), -4.0, 4.0)
    return step


def _solve(mpc: MPCSafetyFilter, step: dict):
    return mpc.solve(step["x0"], step["reference_states"], step["halfspaces"],
                     reference_inputs=step.get("reference_inputs"))


def _same(ours, theirs, where: str) -> None:
    assert ours.status is theirs.status, where
    assert ours.consecutive_failures == theirs.consecutive_failures, where
    assert ours.solver_status.split(" (")[0] == theirs.solver_status.split(" (")[0], (
        where, ours.solver_status, theirs.solver_status)
    np.testing.assert_allclose(ours.inputs, theirs.inputs, rtol=0, atol=1e-6, err_msg=where)
    np.testing.assert_allclose(ours.states, theirs.states, rtol=0, atol=1e-6, err_msg=where)
    assert ours.objective == pytest.approx(theirs.objective, rel=1e-6, abs=1e-6), where
    assert ours.bound_slack == pytest.approx(theirs.bound_slack, abs=1e-6), where
    assert (ours.slack is None) == (theirs.slack is None), where
    if ours.slack is not None:
        np.testing.assert_allclose(ours.slack, theirs.slack, rtol=0, atol=1e-6, err_msg=where)
    for array in (ours.inputs, ours.states, ours.slack):
        assert array is None or not array.flags.writeable


@pytest.mark.parametrize("own", [True, False], ids=["own_solver", "daqp"])
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("objective", OBJECTIVES)
def test_fast_step_equals_the_general_path(objective, mode, own):
    """Closed-loop sequences (the fast filter's input drives the ego; both filters see the
    same steps and keep their own plans and failure counts)."""
    fast, general = _make(objective, mode, True, own=own), _make(objective, mode, False)
    rng = np.random.default_rng([OBJECTIVES.index(objective), MODES.index(mode), own])
    seen, solves = set(), set()
    for episode in range(6):
        fast.reset()
        general.reset()
        x0 = np.array([rng.uniform(-4.5, -2.0), rng.uniform(-1.0, 1.0), 1.5, 0.0])
        if mode == "recovery" and episode % 2:  # outside the arena, moving out
            x0[0], x0[2] = -5.0 - rng.uniform(0.05, 0.5), -rng.uniform(0.0, 2.0)
        for index in range(12):
            step = _step(rng, x0, mode, inputs=index % 3 != 2)
            ours, theirs = _solve(fast, step), _solve(general, step)
            _same(ours, theirs, f"{objective} {mode} episode {episode} step {index}")
            assert fast.last_qp_solves == general.last_qp_solves
            seen.add(ours.status)
            solves.add(fast.last_qp_solves)
            x0 = A @ x0 + B @ ours.inputs[0]
    expected_solves = {0, 1} if mode == "paper" else {0, 1, 2}  # 2: the recovery QP
    assert FilterStatus.OPTIMAL in seen and expected_solves <= solves, (seen, solves)
    if mode == "recovery":
        assert {FilterStatus.SOFT, FilterStatus.RECOVERY} <= seen, seen
    if mode == "paper":
        assert seen & {FilterStatus.SHIFTED, FilterStatus.BRAKE}, seen


def test_fast_step_pads_fewer_rows_and_takes_none():
    fast, general = _make("trajectory", "recovery", True), _make("trajectory", "recovery", False)
    rng = np.random.default_rng(5)
    x0 = np.array([-3.0, 0.2, 1.5, 0.0])
    for k in (0, 1, 3, 4):
        step = _step(rng, x0, "hard", inputs=True)
        normals, offsets = step["halfspaces"]
        step["halfspaces"] = (np.ascontiguousarray(normals[:k]),
                              np.ascontiguousarray(offsets[:k]))
        _same(_solve(fast, step), _solve(general, step), f"k = {k}")
        if k:
            padded = fast._last_step
            assert np.all(padded.normals[k:] == 0.0)
            assert np.all(padded.offsets[k:] == DISABLED_OFFSET)
    step["halfspaces"] = None
    _same(_solve(fast, step), _solve(general, step), "no halfspaces")


def test_compact_rows_give_the_full_layout_s_bits():
    """The compiled solver sees the k used halfspace rows per step only (the K - k unused
    ones, ``0 @ z <= disabled``, left out): the same status, iterations and bits as the
    solver on DAQP's full row layout; and DAQP's rows written from the compact ones are
    the rows :meth:`FastHardStep.prepare` writes."""
    kernels = _kernels()
    mpc = _make("trajectory", "recovery", True, n_obstacles=6)
    fast = mpc._fast
    qp_A, upper, lower = fast.backend.row_buffers
    rng = np.random.default_rng(11)
    verdicts = set()
    for case in range(120):
        x0 = np.array([rng.uniform(-4.5, -2.0), rng.uniform(-1.0, 1.0), 1.5, 0.0])
        step = _step(rng, x0, "recovery", inputs=True)
        normals, offsets = step["halfspaces"]
        k = int(rng.integers(0, normals.shape[0] + 1))
        normals, offsets = np.ascontiguousarray(normals[:k]), np.ascontiguousarray(offsets[:k])
        args = (step["x0"], step["reference_states"], step["reference_inputs"], normals,
                offsets, False)
        code = fast.solve_hard(*args, np.empty(20), np.empty((11, 4)))
        if code not in (SOLVED, INFEASIBLE):
            continue
        verdicts.add(code)
        z, iterations = fast.z.copy(), int(fast.info[4])
        fast.write_daqp_rows(k)
        written = qp_A.copy()
        full = np.empty(20)
        status, full_iterations = kernels.ldp_solve(
            np.ascontiguousarray(written.T), upper.copy(), lower.copy(), fast.f.copy(), full,
            fast.primal_tolerance, fast.max_iterations)
        assert (status, full_iterations) == ((1 if code == SOLVED else -1), iterations), case
        if code == SOLVED:
            np.testing.assert_array_equal(z, full, err_msg=f"case {case}")
        fast.prepare(*args, np.empty(20), np.empty((11, 4)))  # writes DAQP's rows itself
        np.testing.assert_array_equal(written, qp_A, err_msg=f"case {case}")
    assert verdicts == {SOLVED, INFEASIBLE}


def test_fast_step_leaves_other_arrays_to_the_general_path():
    """Lists, float32, non-contiguous arrays: the same answers (the general path runs)."""
    fast, general = _make("trajectory", "recovery", True), _make("trajectory", "recovery", False)
    step = _step(np.random.default_rng(8), np.array([-3.0, 0.0, 1.5, 0.0]), "hard", True)
    normals, offsets = step["halfspaces"]
    wide = np.zeros((11, 8))
    wide[:, ::2] = step["reference_states"]
    for variant in ({"x0": list(step["x0"])},
                    {"reference_states": wide[:, ::2]},
                    {"halfspaces": (normals.astype(np.float32), offsets)},
                    {"halfspaces": [normals, offsets]}):
        case = {**step, **variant}
        _same(_solve(fast, case), _solve(general, step), str(list(variant)))


@pytest.mark.parametrize("where", ["x0", "reference_states", "reference_inputs", "normals",
                                   "offsets"])
def test_fast_step_raises_the_general_path_s_errors(where):
    step = _step(np.random.default_rng(2), np.array([-3.0, 0.0, 1.5, 0.0]), "hard", True)
    normals, offsets = (a.copy() for a in step["halfspaces"])
    step = {key: np.array(value) if isinstance(value, np.ndarray) else value
            for key, value in step.items()}
    if where == "normals":
        normals[1, 3, 0] = np.nan
    elif where == "offsets":
        offsets[0, 2] = np.inf
    else:
        step[where].reshape(-1)[3] = np.nan
    step["halfspaces"] = (normals, offsets)
    messages = []
    for fast in (True, False):
        mpc = _make("trajectory", "recovery", fast)
        with pytest.raises(InvalidArrayError) as error:
            _solve(mpc, step)
        messages.append(str(error.value))
    assert messages[0] == messages[1]


def test_a_fast_result_is_its_own():
    """Results keep their arrays: later steps do not change them; a fresh filter answers the
    same bits."""
    mpc = _make("first_input", "recovery", True)
    rng = np.random.default_rng(4)
    x0 = np.array([-3.0, 0.0, 1.5, 0.0])
    first_step = _step(rng, x0, "hard", True)
    first = _solve(mpc, first_step)
    kept = (first.inputs.copy(), first.states.copy())
    for _ in range(10):
        _solve(mpc, _step(rng, x0, "recovery", True))
    assert np.array_equal(first.inputs, kept[0]) and np.array_equal(first.states, kept[1])
    again = _solve(_make("first_input", "recovery", True), first_step)
    assert np.array_equal(again.inputs, first.inputs)
    assert np.array_equal(again.states, first.states)


# --------------------------------------------------------------------------- the wrapper
def _episode(scenario: str, seed: int, fast: bool, steps: int = 40, **kwargs):
    env = SafetyFilterWrapper(gym.make(f"SafeNav/{scenario}-v0"), fast_path=fast, **kwargs)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    reports = []
    for _ in range(steps):
        action = np.clip(rng.normal(0.0, 6.0, 2), -10, 10).astype(np.float32)
        _, _, terminated, truncated, info = env.step(action)
        reports.append(info["filter"])
        if terminated or truncated:
            break
    return env, reports


@pytest.mark.parametrize(("scenario", "kwargs"), [
    ("RandomCrossing", {}),
    ("HeadOn", {"intersample": False}),
    ("MultiObstacle", {"normals": "paper", "objective": "trajectory"}),
    ("Intersection", {"fallback": "paper"}),
])
def test_wrapper_episodes_fast_and_general_agree(scenario, kwargs):
    statuses = set()
    for seed in range(3):
        fast_env, fast = _episode(scenario, seed, True, **kwargs)
        assert fast_env._mpc._fast is not None
        general_env, general = _episode(scenario, seed, False, **kwargs)
        assert general_env._mpc._fast is None
        assert len(fast) == len(general)
        for index, (ours, theirs) in enumerate(zip(fast, general, strict=True)):
            where = f"{scenario} seed {seed} step {index}"
            assert ours.status == theirs.status, where
            np.testing.assert_allclose(ours.applied_action, theirs.applied_action, atol=1e-6,
                                       err_msg=where)
            np.testing.assert_allclose(ours.normals, theirs.normals, atol=1e-9, err_msg=where)
            np.testing.assert_allclose(ours.offsets, theirs.offsets, atol=1e-9, err_msg=where)
            statuses.add(ours.status)
        again = _episode(scenario, seed, True, **kwargs)[1]
        assert again == fast  # the same bits run to run (timings aside)
        for ours, theirs in zip(again, fast, strict=True):
            assert np.array_equal(ours.applied_action, theirs.applied_action)
    assert len(statuses) >= 2, statuses

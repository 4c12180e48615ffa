"""Every fast back end (Clarabel and PIQP sparse, DAQP condensed, ``"auto"``) equals the CVXPY
reference at T = 10, 20, 40 and 80, for every objective and mode; DAQP's warm-started
model returns what a fresh one returns; infeasible QPs give Clarabel's statuses.

The instances are horizon-generic crossings (the ego at the left, a straight
reference slow enough to stay in the arena, obstacles ahead with halfspaces toward
their predicted positions), drawn from seeded generators.
"""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.filter_qp import double_integrator, filter_kwargs
from filters.mpc import FilterStatus, MPCSafetyFilter, stopping_terminal_set
from filters.mpc.filter import AUTO_DAQP_MAX_INPUTS, auto_backend

pytest.importorskip("cvxpy")
pytest.importorskip("daqp")
pytest.importorskip("piqp")

TS = 0.2
A, B, C = double_integrator(TS)
ARENA = 5.0
FAST = ["clarabel", "daqp", "piqp", "auto"]
OBJECTIVES = ["trajectory", "first_input"]
MODES = ["hard", "soft", "recovery", "paper"]
HORIZONS = [10, 20, pytest.param(40, marks=pytest.mark.slow),
            pytest.param(80, marks=pytest.mark.slow)]
K = 3


def make(backend: str, horizon: int, objective: str, mode: str, **extra) -> MPCSafetyFilter:
    kwargs = filter_kwargs(horizon, K)
    if objective == "first_input":
        kwargs.pop("Q")
        kwargs.pop("Q_terminal")
    kwargs.update(objective=objective, soft=mode == "soft",
                  fallback="paper" if mode == "paper" else "soft")
    if mode == "recovery":
        kwargs["terminal_set"] = stopping_terminal_set(
            TS, kwargs["input_bounds"], kwargs["position_bounds"])
    if backend == "cvxpy":
        extra.setdefault("skip_feasible_reference", False)
    return MPCSafetyFilter(A, B, C, backend=backend, **kwargs, **extra)


def instance(rng: np.random.Generator, horizon: int, mode: str) -> dict:
    """A crossing at horizon ``T``; tightened halfspaces (soft, recovery), the ego outside
    the arena moving out (recovery), an unreachable wall now and then (paper)."""
    speed = min(1.5, 8.0 / (horizon * TS))
    x0 = np.array([rng.uniform(-4.5, -2.0), rng.uniform(-1.0, 1.0), speed, rng.normal(0, 0.2)])
    steps = np.arange(horizon + 1)
    reference = np.zeros((horizon + 1, 4))
    reference[:, 0] = x0[0] + speed * TS * steps
    reference[:, 1] = x0[1] + rng.normal(0, 0.2)
    reference[:, 2] = speed
    k = int(rng.integers(1, K + 1))
    start = x0[:2] + np.column_stack([rng.uniform(1.0, 4.0, k), rng.uniform(-1.0, 1.0, k)])
    velocity = rng.normal(0.0, 0.4, (k, 2))
    predicted = start[:, None] + velocity[:, None] * TS * steps[None, 1:, None]
    direction = predicted - reference[None, 1:, :2]
    normals = direction / np.linalg.norm(direction, axis=-1, keepdims=True)
    offsets = np.einsum("ktd,ktd->kt", normals, predicted) - rng.uniform(0.5, 0.8, (k, 1))
    if mode in ("soft", "recovery"):
        offsets = offsets - rng.uniform(0.0, 2.0)
    if mode == "recovery" and rng.random() < 0.7:
        x0[0], x0[2] = -ARENA - rng.uniform(0.05, 0.5), -rng.uniform(0.0, 1.0)
    if mode == "paper" and rng.random() < 0.4:
        normals = np.zeros_like(normals)
        normals[..., 0] = 1.0
        offsets = np.full_like(offsets, -100.0)  # x <= -100 m: infeasible
    out = {"x0": x0, "reference_states": reference, "halfspaces": (normals, offsets)}
    if rng.random() < 0.5:
        out["reference_inputs"] = rng.normal(0.0, 1.0, (horizon, 2))
    return out


def solve(mpc: MPCSafetyFilter, case: dict):
    return mpc.solve(case["x0"], case["reference_states"], case["halfspaces"],
                     reference_inputs=case.get("reference_inputs"))


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("objective", OBJECTIVES)
@pytest.mark.parametrize("horizon", HORIZONS)
def test_every_backend_equals_the_cvxpy_reference(horizon, objective, mode):
    reference = make("cvxpy", horizon, objective, mode)
    fast = {name: make(name, horizon, objective, mode, skip_feasible_reference=False)
            for name in FAST}
    rng = np.random.default_rng([horizon, OBJECTIVES.index(objective), MODES.index(mode)])
    statuses = set()
    for _ in range(4 if horizon <= 20 else 3):
        case = instance(rng, horizon, mode)
        theirs = solve(reference, case)
        statuses.add(theirs.status)
        for name, mpc in fast.items():
            ours = solve(mpc, case)
            assert ours.status == theirs.status, (name, ours.solver_status, theirs.solver_status)
            violated = (ours.slack is not None and ours.slack.sum() > 1e-6
                        or ours.bound_slack > 1e-6)
            if ours.fallback:  # shifted plan or brake: the same plan, exactly
                np.testing.assert_allclose(ours.inputs, theirs.inputs, atol=1e-4, err_msg=name)
            elif not violated and (objective == "trajectory" or mode in ("hard", "paper")):
                np.testing.assert_allclose(ours.inputs, theirs.inputs, atol=2e-4, err_msg=name)
                assert ours.objective == pytest.approx(theirs.objective, rel=1e-5, abs=1e-4)
            elif not violated:
                # first_input with slack rows (both QPs are Clarabel's, at the gap 1e-10 of
                # a cost ~rho): u_0 is pinned, the later inputs, weighted 1e-2, only to ~1e-2.
                np.testing.assert_allclose(ours.inputs[0], theirs.inputs[0], atol=1e-3,
                                           err_msg=name)
                np.testing.assert_allclose(ours.inputs, theirs.inputs, atol=5e-2, err_msg=name)
                assert ours.objective == pytest.approx(theirs.objective, abs=1e-3)
            else:  # the L1 penalty dwarfs the quadratic cost (see tests/test_mpc.py)
                np.testing.assert_allclose(ours.inputs[0], theirs.inputs[0], atol=3e-3,
                                           err_msg=name)
            if ours.slack is not None and theirs.slack is not None:
                np.testing.assert_allclose(ours.slack, theirs.slack, atol=1e-4, err_msg=name)
            # a sum of up to 2 T arena violations (tens of m for a braking plan outside
            # the arena at T = 80): 1e-5 relative on top of the 1e-4 m absolute
            assert ours.bound_slack == pytest.approx(theirs.bound_slack, rel=1e-5, abs=1e-4)
    assert statuses  # something was compared
    if mode == "hard":
        assert FilterStatus.OPTIMAL in statuses


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("objective", OBJECTIVES)
@pytest.mark.parametrize("horizon", [10, 20])
@pytest.mark.parametrize("warm", [False, True])
def test_daqp_update_equals_rebuild(horizon, objective, mode, warm):
    """A used DAQP model gives bit for bit what a fresh one gives (the default cold
    start), and to 1e-8 when warm-started from the previous solve's active set; the
    sequence includes infeasible steps."""
    persistent = make("daqp", horizon, objective, mode, skip_feasible_reference=False)
    assert persistent.backend == "daqp"
    persistent._primary._warm_start = warm
    rng = np.random.default_rng([7, horizon])
    for _ in range(10):
        case = instance(rng, horizon, mode)
        persistent.reset()
        updated = solve(persistent, case)
        rebuilt = solve(make("daqp", horizon, objective, mode, skip_feasible_reference=False),
                        case)
        assert updated.status == rebuilt.status
        assert updated.solver_status == rebuilt.solver_status
        np.testing.assert_allclose(updated.inputs, rebuilt.inputs, rtol=0,
                                   atol=1e-7 if warm else 0.0)
        if not warm:
            assert updated.iterations == rebuilt.iterations


@pytest.mark.parametrize("fallback", ["soft", "paper"])
def test_infeasible_qp_gives_clarabels_status(fallback):
    statuses = {}
    for name in ("clarabel", "daqp", "piqp"):
        mpc = make(name, 10, "trajectory", "paper" if fallback == "paper" else "hard")
        rng = np.random.default_rng(3)
        case = instance(rng, 10, "hard")
        first = solve(mpc, case)
        wall = np.zeros((1, 10, 2))
        wall[..., 0] = 1.0
        infeasible = {**case, "halfspaces": (wall, np.full((1, 10), -100.0))}
        second = solve(mpc, infeasible)
        assert "PrimalInfeasible" in second.solver_status
        statuses[name] = (first.status, second.status, second.consecutive_failures)
        if fallback == "paper":
            assert second.status is FilterStatus.SHIFTED
        else:
            assert second.status in (FilterStatus.SOFT, FilterStatus.RECOVERY)
    assert statuses["daqp"] == statuses["clarabel"] == statuses["piqp"]


def test_piqp_settings_are_checked():
    from filters.errors import InvalidParameterError, InvalidTypeError

    tuned = make("piqp", 10, "trajectory", "hard", solver_settings={"max_iter": 100})
    assert tuned._primary.solver.settings.max_iter == 100
    with pytest.raises(InvalidParameterError, match="no_such"):
        make("piqp", 10, "trajectory", "hard", solver_settings={"no_such": 1})
    with pytest.raises(InvalidParameterError, match="max_iter"):
        make("piqp", 10, "trajectory", "hard", solver_settings={"max_iter": "many"})
    with pytest.raises(InvalidTypeError, match="solver_settings"):
        make("piqp", 10, "trajectory", "hard", solver_settings=[("max_iter", 3)])


def test_auto_picks_daqp_for_hard_qps_and_daqp_then_an_interior_point_for_long_soft_ones():
    for horizon in (10, 20, 21, 40, 80):
        for mode in ("hard", "soft", "recovery"):
            mpc = make("auto", horizon, "trajectory", mode)
            long = horizon * 2 > AUTO_DAQP_MAX_INPUTS
            assert mpc.backend == ("daqp+piqp" if mode == "soft" and long else "daqp")
            # the recovery QP (every row soft): the Riccati method; soft=True: PIQP
            assert mpc.recovery_backend == ("daqp+riccati" if long else "daqp")
            assert auto_backend(mpc.problem) == mpc.backend
    assert AUTO_DAQP_MAX_INPUTS == 40
    assert make("auto", 80, "trajectory", "paper").recovery_backend is None
    # the lazy rows start above LAZY_MIN_INPUTS inputs
    assert not make("auto", 20, "trajectory", "hard")._primary.lazy
    assert make("auto", 21, "trajectory", "hard")._primary.lazy
    # Clarabel settings with "auto" mean Clarabel.
    tuned = make("auto", 10, "trajectory", "hard", solver_settings={"max_iter": 50})
    assert tuned.backend == tuned.recovery_backend == "clarabel"
    # The default is "auto".
    kwargs = filter_kwargs(10, 1)
    assert MPCSafetyFilter(A, B, C, **kwargs).backend == "daqp"


def test_daqp_solves_soft_rows_itself_and_bad_settings_raise():
    from filters.errors import InvalidParameterError, InvalidTypeError
    from filters.mpc.backends.daqp import DAQPBackend

    for mode in ("hard", "soft"):
        mpc = make("daqp", 10, "trajectory", mode)
        assert isinstance(mpc._primary, DAQPBackend)
        assert isinstance(mpc._recovery, DAQPBackend)
        assert mpc._recovery.problem.soft_rows == {"halfspaces", "bounds"}
    with pytest.raises(InvalidParameterError, match="no_such"):
        make("daqp", 10, "trajectory", "hard", solver_settings={"no_such": 1})
    with pytest.raises(InvalidTypeError, match="solver_settings"):
        make("daqp", 10, "trajectory", "hard", solver_settings=[("iter_limit", 3)])
    with pytest.raises(InvalidParameterError, match="iter_limit"):
        make("daqp", 10, "trajectory", "hard", solver_settings={"iter_limit": "many"})


def test_daqp_soft_qp_is_never_worse_than_the_reference_in_its_own_objective():
    """The exact-penalty objective (cost + rho * total violation) of DAQP's soft answer
    is at most CVXPY's (+1e-6 relative): the quadratic term of DAQP's soft constraints
    does not move the answer off the L1 optimum."""
    for mode in ("soft", "recovery"):
        fast = make("daqp", 10, "trajectory", mode, skip_feasible_reference=False)
        reference = make("cvxpy", 10, "trajectory", mode)
        rng = np.random.default_rng(11)
        rho = fast.slack_penalty
        for _ in range(6):
            case = instance(rng, 10, mode)
            ours, theirs = solve(fast, case), solve(reference, case)
            penalised = [r.objective + rho * (0.0 if r.slack is None else r.slack.sum())
                         + rho * r.bound_slack for r in (ours, theirs)]
            assert penalised[0] <= penalised[1] * (1 + 1e-6) + 1e-6


def test_daqp_iteration_budget_is_checked_and_spent_over_the_rounds():
    from filters.errors import InvalidParameterError
    from filters.mpc.backends.daqp import DAQPBackend
    from filters.mpc.result import StepData

    problem = make("auto", 40, "trajectory", "recovery")._recovery.problem
    for bad in (0, -3, 2.5, True, "10"):
        with pytest.raises(InvalidParameterError, match="iteration_budget"):
            DAQPBackend(problem, lazy=True, iteration_budget=bad)
    rng = np.random.default_rng(11)
    spent = 0
    for _ in range(6):
        case = instance(rng, 40, "recovery")
        normals, offsets = case["halfspaces"]
        padded_n, padded_o = np.zeros((K, 40, 2)), np.ones((K, 40))
        padded_n[: len(normals)], padded_o[: len(offsets)] = normals, offsets
        step = StepData(case["x0"], case["reference_states"][1:], np.zeros((40, 2)),
                        padded_n, padded_o)
        answer = DAQPBackend(problem, lazy=True).solve(step)  # fresh: no warm start
        assert answer.found
        if answer.iterations < 3:
            continue
        budget = answer.iterations // 2
        capped = DAQPBackend(problem, lazy=True, iteration_budget=budget).solve(step)
        assert not capped.found and capped.status == "MaxIterations"
        assert capped.iterations <= budget
        # DAQP's limit counts the iteration that finds the optimum, which it does not report
        enough = DAQPBackend(problem, lazy=True,
                             iteration_budget=answer.iterations + 1).solve(step)
        assert enough.found
        np.testing.assert_array_equal(enough.inputs, answer.inputs)  # the same solves
        spent += 1
    assert spent  # some instance needed iterations


def test_daqp_iteration_limit_is_a_failure_not_an_exception():
    mpc = make("daqp", 10, "trajectory", "paper", solver_settings={"iter_limit": 1},
               skip_feasible_reference=False)
    rng = np.random.default_rng(5)
    for _ in range(5):
        case = instance(rng, 10, "hard")
        result = solve(mpc, case)
        if result.iterations and "MaxIterations" in result.solver_status:
            assert result.fallback
            return
    pytest.fail("no step hit DAQP's iteration limit of 1")


@pytest.mark.parametrize("mode", ["hard", "soft", "recovery"])
def test_piqp_update_equals_rebuild(mode):
    """A PIQP solver updated step after step answers as one set up for that step alone
    (to 1e-8 m/s²: piqp 0.7's update path differs from a fresh set-up by up to 2e-9)."""
    persistent = make("piqp", 20, "trajectory", mode, skip_feasible_reference=False)
    rng = np.random.default_rng([9, MODES.index(mode)])
    for _ in range(6):
        case = instance(rng, 20, mode)
        persistent.reset()
        updated = solve(persistent, case)
        rebuilt = solve(make("piqp", 20, "trajectory", mode, skip_feasible_reference=False),
                        case)
        assert updated.status == rebuilt.status
        np.testing.assert_allclose(updated.inputs, rebuilt.inputs, rtol=0, atol=1e-8)


@pytest.mark.parametrize("horizon", [20, pytest.param(80, marks=pytest.mark.slow)])
def test_piqp_hard_infeasibility_tolerance_keeps_clarabels_status_at_the_boundary(horizon):
    """Shift a hard QP's halfspace offsets by ``lam`` (m): bisect with Clarabel at 1e-12
    where it turns infeasible, then PIQP (hard-QP tolerance) must say what Clarabel says
    10 µm to 1 cm on either side of that boundary."""
    from filters.mpc.backends.piqp import HARD_PRIMAL_INFEASIBILITY_TOLERANCE

    tight = {name: 1e-12 for name in ("tol_feas", "tol_gap_abs", "tol_gap_rel",
                                      "tol_infeas_abs", "tol_infeas_rel")}
    reference = make("clarabel", horizon, "trajectory", "paper", solver_settings=tight,
                     skip_feasible_reference=False)
    piqp_filter = make("piqp", horizon, "trajectory", "paper", skip_feasible_reference=False)
    settings = piqp_filter._primary.solver.settings
    assert settings.eps_primal_inf == HARD_PRIMAL_INFEASIBILITY_TOLERANCE
    soft = make("piqp", horizon, "trajectory", "soft")
    assert soft._primary.solver.settings.eps_primal_inf != HARD_PRIMAL_INFEASIBILITY_TOLERANCE

    def shifted(case: dict, lam: float) -> dict:
        normals, offsets = case["halfspaces"]
        return {**case, "halfspaces": (normals, offsets + lam)}

    def feasible(mpc: MPCSafetyFilter, case: dict) -> bool:
        mpc.reset()
        return solve(mpc, case).status is FilterStatus.OPTIMAL

    rng = np.random.default_rng([7, horizon])
    checked = 0
    while checked < 3:
        case = instance(rng, horizon, "hard")
        low, high = -20.0, 5.0
        if feasible(reference, shifted(case, low)) or not feasible(reference, shifted(case, high)):
            continue
        for _ in range(30):  # to 2e-8 m
            middle = 0.5 * (low + high)
            if feasible(reference, shifted(case, middle)):
                high = middle
            else:
                low = middle
        for delta in (1e-2, 1e-3, 1e-4, 1e-5):
            assert feasible(reference, shifted(case, high + delta))
            assert not feasible(reference, shifted(case, low - delta))
            assert feasible(piqp_filter, shifted(case, high + delta)), delta
            assert not feasible(piqp_filter, shifted(case, low - delta)), delta
        checked += 1

"""Every back end (Clarabel sparse, DAQP condensed, ``"auto"``) equals the CVXPY reference
at T = 10, 20, 40 and 80, for every objective and mode (by tolerance); DAQP's
warm-started model returns what a fresh one returns; infeasible QPs give Clarabel's
statuses.

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

TS = 0.2
A, B, C = double_integrator(TS)
ARENA = 5.0
FAST = ["clarabel", "daqp", "auto"]
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
            else:  # the L1 penalty dwarfs the quadratic cost (see tests/filters/mpc/test_mpc.py)
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
    """A used DAQP model gives what a fresh one gives (to 1e-9 m/s² with the default cold
    start, to 1e-7 when warm-started from the previous solve's active set); the
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
                                   atol=1e-7 if warm else 1e-9)


@pytest.mark.parametrize("fallback", ["soft", "paper"])
def test_infeasible_qp_gives_clarabels_status(fallback):
    statuses = {}
    for name in ("clarabel", "daqp"):
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
    assert statuses["daqp"] == statuses["clarabel"]


def test_auto_picks_daqp_for_hard_qps_and_clarabel_for_long_soft_ones():
    for horizon in (10, 20, 21, 40, 80):
        for mode in ("hard", "soft", "recovery"):
            mpc = make("auto", horizon, "trajectory", mode)
            long = horizon * 2 > AUTO_DAQP_MAX_INPUTS
            assert mpc.backend == ("clarabel" if mode == "soft" and long else "daqp")
            assert mpc.recovery_backend == ("clarabel" if long else "daqp")
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
        assert isinstance(mpc._recovery, DAQPBackend) and isinstance(mpc._rescue, DAQPBackend)
        assert mpc._recovery.problem.soft_rows == {"halfspaces"}
        assert mpc._rescue.problem.soft_rows == {"halfspaces", "bounds"}
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
def test_clarabel_update_equals_rebuild(mode):
    """A Clarabel solver updated step after step (``b`` and the halfspace entries of
    ``A``) answers as one set up for that step alone (to 1e-9 m/s²)."""
    persistent = make("clarabel", 20, "trajectory", mode, skip_feasible_reference=False)
    rng = np.random.default_rng([9, MODES.index(mode)])
    for _ in range(6):
        case = instance(rng, 20, mode)
        persistent.reset()
        updated = solve(persistent, case)
        rebuilt = solve(make("clarabel", 20, "trajectory", mode, skip_feasible_reference=False),
                        case)
        assert updated.status == rebuilt.status
        np.testing.assert_allclose(updated.inputs, rebuilt.inputs, rtol=0, atol=1e-9)

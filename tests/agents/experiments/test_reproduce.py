"""``safe-nav reproduce`` like for like: windows, presets, episode lengths, the report."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agents.experiments.encounters import (
    EncounterJob,
    EncounterRecord,
    make_encounter_env,
    paper_monte_carlo,
    run_encounter,
)
from agents.experiments.paper_settings import (
    PAPER_WINDOWS,
    PRESETS,
    paper_duration,
)
from agents.experiments.reproduce import compare_with_paper, reproduce
from agents.experiments.windows import (
    closest_approach_window,
    resolve_windows,
    summarise_windows,
    window_minimum,
)
from agents.planners import MPCReferencePlanner
from filters import InvalidArrayError, InvalidParameterError
from safe_nav_env import double_integrator
from safe_nav_env.collision import swept_clearance


# ---------------------------------------------------------------------------- windows
def test_closest_approach_window_is_centred_on_the_median_closest_step():
    samples = np.arange(16)
    # Episodes closest at samples 6, 7, 9: median 7, window 7-2 .. 7+1.
    series = np.stack([np.abs(samples - k) + 0.1 * k for k in (6, 7, 9)]).astype(float)
    assert closest_approach_window(series) == (5, 8)
    assert closest_approach_window(series, before=0, after=0) == (7, 7)
    # Clipped at both ends of the series.
    assert closest_approach_window(series[:, :8], before=9, after=9) == (0, 7)


def test_closest_approach_window_ignores_the_nan_tail_of_short_episodes():
    series = np.full((2, 10), np.nan)
    series[0, :4] = [3.0, 2.0, 1.0, 2.0]  # ended after 3 steps, closest at 2
    series[1] = np.abs(np.arange(10) - 2.0)
    assert closest_approach_window(series) == (0, 3)


def test_window_rejects_bad_series():
    with pytest.raises(InvalidArrayError, match="shape"):
        closest_approach_window(np.zeros(5))
    with pytest.raises(InvalidArrayError, match="finite"):
        closest_approach_window(np.array([[np.nan, np.nan], [1.0, 2.0]]))
    with pytest.raises(InvalidParameterError, match="before"):
        closest_approach_window(np.ones((1, 4)), before=-1)
    with pytest.raises(InvalidParameterError, match="window"):
        window_minimum(np.ones((1, 4)), (3, 2))


def test_window_minimum_is_the_minimum_over_the_included_samples():
    rng = np.random.default_rng(0)
    series = rng.normal(size=(50, 16))
    series[3, 9:] = np.nan  # an episode that ended early
    series[4, 5:9] = np.nan  # nothing in the window
    got = window_minimum(series, (5, 8))
    for i in range(50):
        part = series[i, 5:9]
        part = part[np.isfinite(part)]
        expected = part.min() if part.size else np.nan
        np.testing.assert_equal(got[i], expected)
    assert np.isnan(got[4])


def test_paper_windows_are_the_authors_slices():
    # multi_exp_sim.py: start=6, end=9 (HeadOn, Intersection) and start=3, end=6
    # (Overtaking), sliced [start - 1 : end] from a series whose entry 0 is the start.
    for scenario, (start, end) in {"SafeNav/HeadOn-v0": (6, 9), "SafeNav/Overtaking-v0": (3, 6),
                                   "SafeNav/Intersection-v0": (6, 9)}.items():
        indices = np.arange(20)[start - 1:end]
        assert PAPER_WINDOWS[scenario] == (indices[0], indices[-1])


def _record(scenario: str, risk: str, seed: int, distances, swept=None,
            error: str = "") -> EncounterRecord:
    distances = np.asarray(distances, dtype=float).reshape(-1, 1)
    steps = distances.shape[0] - 1
    swept = (np.minimum(distances[1:], distances[:-1]) if swept is None
             else np.asarray(swept, dtype=float).reshape(-1, 1))
    return EncounterRecord(
        preset="paper", scenario=scenario, risk=risk, seed=seed, dt=0.2, ego_radius=0.3,
        ego=np.zeros((steps + 1, 2)), halfspaces=[], frames=[],
        obstacle_radii=np.array([0.3]), goal=np.zeros(2), ego_states=np.zeros((steps + 1, 4)),
        inputs=np.zeros((steps, 2)), obstacles=np.zeros((steps + 1, 1, 2)), distances=distances,
        swept=swept, statuses=("optimal",) * steps, filter_times=np.full(steps, 1e-3),
        error=error, collision=bool(swept.min() <= 0), sampled_collision=bool(distances.min() <= 0))


def test_window_statistics_on_synthetic_distance_series():
    head_on = "SafeNav/HeadOn-v0"
    base = np.linspace(2.0, 0.5, 16)
    dip_in = base.copy()
    dip_in[6] = -0.3   # a sampled collision inside the window 5-8
    dip_out = base.copy()
    dip_out[12] = -0.5  # one outside it
    between = base.copy()
    swept = np.minimum(between[1:], between[:-1])
    swept[6] = -0.1     # between samples 6 and 7 only: continuous time, in the window
    records = [
        _record(head_on, "cvar", 0, dip_in), _record(head_on, "cvar", 1, dip_out),
        _record(head_on, "cvar", 2, between, swept),
        _record(head_on, "cvar", 3, base, error="FloatingPointError: x"),
        _record(head_on, "none", 0, np.abs(np.arange(16) - 10.0) - 0.2),
    ]
    rows = {r.risk: r for r in summarise_windows(records)}
    row = rows["cvar"]
    assert (row.episodes, row.failed, row.window) == (4, 1, (5, 8))
    assert row.window_sampled_collisions == 1
    assert row.sampled_collisions == 2
    assert row.collisions == 3            # every sampled collision is a swept one, + one more
    assert row.window_collisions == 2     # dip_in and the between-samples one
    assert row.window_worst == pytest.approx(-0.3)
    assert row.episode_worst == pytest.approx(-0.5)
    assert row.window_worst_swept == pytest.approx(-0.3)
    # The unfiltered run is closest at sample 10: encounter window 8-11.
    assert row.encounter_window == (8, 11)
    assert row.encounter_worst == pytest.approx(min(base[8:12]))
    lines = "\n".join(compare_with_paper(list(rows.values())))
    assert "paper about -0.22 m, here -0.300 m" in lines and "match" in lines


def test_collision_causes_follow_the_evaluation_rule():
    from agents.evaluation.runner import collision_cause

    assert collision_cause([False, False], [False, False], ["optimal", "soft"]) == ""
    assert collision_cause([False, True], [False, True], ["optimal", "optimal"]) == "noise"
    assert collision_cause([False, True], [False, False], ["optimal", "optimal"]) == \
        "inter_sample"
    # a fallback at the colliding step or in the two before it takes the blame
    for where in (0, 1, 2):
        statuses = ["optimal"] * 3
        statuses[where] = "soft"
        assert collision_cause([False, False, True], [False, False, True], statuses) == \
            "fallback"
    assert collision_cause([False] * 3 + [True], [False] * 3 + [True],
                           ["brake"] + ["optimal"] * 3) == "noise"  # three steps before


def test_scenarios_without_a_paper_window_use_the_unfiltered_closest_approach():
    multi = "SafeNav/MultiObstacle-v0"
    records = [_record(multi, "none", s, np.abs(np.arange(26) - k) - 0.1)
               for s, k in enumerate((11, 12, 14))]
    (window, source), = resolve_windows(records).values()
    assert window == (10, 13) and "unfiltered" in source
    with pytest.raises(InvalidParameterError, match="mode"):
        resolve_windows(records, mode="whole")


# ---------------------------------------------------------------------------- presets
def test_presets_carry_the_documented_effective_weights():
    authors = PRESETS["authors_code"]
    assert authors.filter_weights == (4.0, 25.0, 1.0)
    assert PRESETS["paper"].filter_weights == (4.0, 25.0, 1.0)
    assert (authors.noise, authors.max_acceleration, authors.delta_for("mean"),
            authors.delta_for("cvar")) == ("authors_code", 100.0, 0.0, 0.1)
    assert PRESETS["paper"].delta_for("mean") == 0.1

    env, planner = make_encounter_env(EncounterJob(authors, "SafeNav/HeadOn-v0", "dr_cvar", 0))
    try:
        weights = planner.effective_weights()
        np.testing.assert_array_equal(weights["Q"], np.eye(4))
        np.testing.assert_array_equal(weights["Q_terminal"], 9.0 * np.eye(4))
        np.testing.assert_array_equal(weights["R"][0], np.zeros((2, 2)))
        np.testing.assert_array_equal(weights["R"][1:], np.tile(np.eye(2), (9, 1, 1)))
        np.testing.assert_array_equal(env.unwrapped.input_bounds[1], [100.0, 100.0])
        filter_weights = env._weights
        for matrix, value in zip(filter_weights, (4.0, 25.0, 1.0), strict=True):
            np.testing.assert_array_equal(matrix, value * np.eye(matrix.shape[0]))
        # Problem 2's input cost u'Ru (zero reference inputs) and the paper's fallback.
        assert env.fallback == "paper"
        env.reset(seed=0)
        states, inputs = env.reference(env.unwrapped, np.zeros(2), 10)
        assert states.shape == (11, 4) and np.all(inputs == 0.0)
        assert np.any(planner.plan(env.unwrapped.ego_state, env.unwrapped.goal)[1] != 0.0)
    finally:
        env.close()

    env, planner = make_encounter_env(EncounterJob(PRESETS["paper"], "SafeNav/HeadOn-v0",
                                                   "cvar", 0))
    try:
        weights = planner.effective_weights()
        np.testing.assert_array_equal(weights["Q_terminal"], 3.0 * np.eye(4))
        np.testing.assert_array_equal(weights["R"], np.tile(np.eye(2), (10, 1, 1)))
        np.testing.assert_array_equal(env.unwrapped.input_bounds[1], [10.0, 10.0])
    finally:
        env.close()


def test_authors_convention_planner_equals_their_cvxpy_problem_on_random_instances():
    import cvxpy as cp

    rng = np.random.default_rng(7)
    A, B, C = double_integrator(0.2)
    for trial in range(6):
        bound = 100.0 if trial % 2 == 0 else 3.0  # 3 m/s²: the bounds are active
        Q, QT, R = rng.uniform(0.5, 3.0, size=3)
        horizon = int(rng.integers(3, 11))
        x0 = np.concatenate([rng.uniform(-4, 4, 2), rng.uniform(-2, 2, 2)])
        goal = rng.uniform(-4, 4, 2)
        planner = MPCReferencePlanner((A, B, C), input_bounds=(-bound * np.ones(2),
                                                               bound * np.ones(2)),
                                      horizon=horizon, Q=Q, Q_terminal=QT, R=R,
                                      convention="authors_code")
        states, inputs = planner.plan(x0, goal)
        # The authors' MPCReferenceTrajectory, as written.
        x = cp.Variable((4, horizon + 1))
        u = cp.Variable((2, horizon))
        g = np.concatenate([goal, np.zeros(2)])
        cost = cp.sum_squares((x[:, -1] - g) * QT)
        for t in range(1, horizon):
            cost += cp.sum_squares((x[:, t] - g) * Q) + cp.sum_squares(u[:, t] * R)
        constraints = [x[:, 0] == x0, cp.abs(u) <= bound]
        constraints += [x[:, t + 1] == A @ x[:, t] + B @ u[:, t] for t in range(horizon)]
        problem = cp.Problem(cp.Minimize(cost), constraints)
        problem.solve(solver="CLARABEL")
        np.testing.assert_allclose(inputs, u.value.T, atol=2e-5 * max(1.0, bound / 10))
        np.testing.assert_allclose(states, x.value.T, atol=1e-4)
        assert np.all(np.abs(inputs) <= bound + 1e-12)


def test_the_wrapper_rejects_an_unknown_fallback():
    import gymnasium as gym

    from filters import SafetyFilterWrapper

    with pytest.raises(InvalidParameterError, match="fallback"):
        SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), fallback="pray")


def test_authors_convention_rejects_a_position_bound_and_unknown_conventions():
    dynamics = double_integrator(0.2)
    box = (-np.ones(2), np.ones(2))
    with pytest.raises(InvalidParameterError, match="position_bounds"):
        MPCReferencePlanner(dynamics, input_bounds=box, position_bounds=box,
                            convention="authors_code")
    with pytest.raises(InvalidParameterError, match="convention"):
        MPCReferencePlanner(dynamics, input_bounds=box, convention="squared")
    with pytest.raises(InvalidParameterError, match="horizon"):
        MPCReferencePlanner(dynamics, input_bounds=box, horizon=0)
    with pytest.raises(InvalidArrayError, match="finite"):
        MPCReferencePlanner(dynamics, input_bounds=box, Q=math.nan)


# ---------------------------------------------------------------------------- episodes
def test_paper_episode_lengths_come_from_the_scenarios():
    assert [paper_duration(s) for s in ("SafeNav/HeadOn-v0", "SafeNav/Overtaking-v0",
                                        "SafeNav/Intersection-v0",
                                        "SafeNav/MultiObstacle-v0")] == [3.0, 3.0, 3.0, 5.0]
    with pytest.raises(InvalidParameterError, match="RandomCrossing"):
        paper_duration("SafeNav/RandomCrossing-v0")


@pytest.mark.parametrize("preset", ["paper", "authors_code"])
def test_an_encounter_lasts_the_paper_duration_and_records_both_clearances(preset):
    record = run_encounter(EncounterJob(PRESETS[preset], "SafeNav/HeadOn-v0", "cvar", 2))
    assert record.error == ""
    assert record.steps == 15 and record.distances.shape == (16, 1)
    sampled = (np.linalg.norm(record.ego[:, None] - record.obstacles, axis=2)
               - record.ego_radius - record.obstacle_radii)
    np.testing.assert_allclose(record.distances, sampled, atol=1e-12)
    # The swept clearance of a step is never above either end's sampled clearance, and
    # it is the environment's exact arc-against-chord minimum.
    assert np.all(record.swept <= np.minimum(record.distances[1:], record.distances[:-1]) + 1e-12)
    for k in range(record.steps):
        expected = swept_clearance(record.ego_states[k], record.inputs[k], record.dt,
                                   record.obstacles[k], record.obstacles[k + 1],
                                   record.obstacle_radii + record.ego_radius)
        np.testing.assert_allclose(record.swept[k], np.minimum(expected, record.distances[k + 1]),
                                   atol=1e-7)  # the env gets the action as float32
    assert record.collision == bool(record.swept.min() <= 0)  # the runner's values
    first = int(np.argmax(record.swept.min(axis=1) <= 0)) + 1 if record.collision else 0
    assert record.first_collision_step == first
    assert record.sampled_collision == bool(record.distances.min() <= 0)
    assert np.max(np.abs(record.inputs)) <= PRESETS[preset].max_acceleration


def test_a_failing_episode_is_recorded_not_raised():
    record = run_encounter(EncounterJob(PRESETS["paper"], "SafeNav/RandomCrossing-v0", "cvar",
                                        0))
    assert "RandomCrossing" in record.error and record.steps == 0
    (row,) = summarise_windows([record])
    assert (row.episodes, row.failed) == (1, 1) and math.isnan(row.window_worst)


def test_the_authors_planner_takes_a_large_first_step():
    # Their u_0 is unpenalised: with |u| <= 100 the first input is far above 10 m/s².
    record = run_encounter(EncounterJob(PRESETS["authors_code"], "SafeNav/HeadOn-v0", "none",
                                        0))
    assert record.error == "" and abs(record.inputs[0, 0]) > 15.0
    paper = run_encounter(EncounterJob(PRESETS["paper"], "SafeNav/HeadOn-v0", "none", 0))
    assert abs(paper.inputs[0, 0]) <= 10.0


def test_the_monte_carlo_runs_on_the_executors_with_the_same_records_in_job_order():
    # Two local worker processes (the evaluation pipeline's pool) against this process.
    runs = [paper_monte_carlo("paper", ("SafeNav/HeadOn-v0",), ("none", "cvar"), episodes=2,
                              seed=5, workers=workers) for workers in (1, 2)]
    for records in runs:
        assert [(r.risk, r.seed) for r in records] == [("none", 5), ("none", 6), ("cvar", 5),
                                                       ("cvar", 6)]
    for serial, pooled in zip(*runs, strict=True):
        assert pooled.error == serial.error == ""
        for name in ("ego_states", "inputs", "obstacles", "distances", "swept"):
            np.testing.assert_allclose(getattr(pooled, name), getattr(serial, name), rtol=0,
                                       atol=1e-9)  # seeded: the same episode in any process
        assert pooled.statuses == serial.statuses


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"preset": "mine"}, "preset"), ({"risks": ("cvar", "bogus")}, "risk"),
    ({"scenarios": ("SafeNav/RandomCrossing-v0",)}, "RandomCrossing"),
    ({"episodes": 0}, "episodes"), ({"workers": 0}, "workers"),
])
def test_the_monte_carlo_refuses_bad_settings_before_any_episode(kwargs, match):
    with pytest.raises(InvalidParameterError, match=match):
        paper_monte_carlo(**kwargs)


@pytest.mark.slow
def test_reproduce_report_states_window_lengths_presets_and_both_counts(tmp_path):
    report = reproduce(tmp_path, episodes=2, workers=1, timing=False, progress=False,
                       presets=("paper", "authors_code"), scenarios=("SafeNav/HeadOn-v0",))
    for text in ("samples 5-8 (1.0-1.6 s), authors' script", "HeadOn 3 s",
                 "Preset `paper`", "Preset `authors_code`", "collisions, continuous time",
                 "collisions, sampled", "encounter window", "Worst sampled distance in the window"):
        assert text in report
    for folder in ("monte_carlo", "monte_carlo_authors_code"):
        figures = tmp_path / folder / "figures"
        for name in ("distance_boxplots.png", "collision_rates.png",
                     "collision_rates_sampled.png", "trajectories_HeadOn.png", "episode.gif"):
            assert (figures / name).stat().st_size > 1000
        rows = (tmp_path / folder / "episodes.csv").read_text().strip().splitlines()
        assert len(rows) == 1 + 2 * 4
    with pytest.raises(InvalidParameterError, match="presets"):
        reproduce(tmp_path, presets=("paper", "mine"))

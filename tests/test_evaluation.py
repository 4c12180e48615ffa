"""Monte Carlo evaluation: records, determinism across workers, failures, resume."""

from __future__ import annotations

import csv
import math
from dataclasses import replace

import numpy as np
import pytest

from agents.evaluation import (
    RECORD_FIELDS,
    EpisodeSpec,
    episode_specs,
    evaluate,
    read_records,
    run_episode,
)
from agents.summary import lower_tail_mean, markdown_table, summarise, wilson_interval
from filters import InvalidParameterError

MPC = dict(planner="mpc")


def test_episode_record_matches_a_manual_rollout():
    spec = EpisodeSpec("HeadOn", "dr_cvar", 3, **MPC)
    record, trajectory = run_episode(spec, record_trajectory=True)
    assert record.error == ""
    assert record.steps == len(trajectory.statuses) == len(trajectory.ego) - 1
    steps = np.linalg.norm(np.diff(trajectory.ego, axis=0), axis=1)
    assert record.path_length == pytest.approx(steps.sum())
    distances = (np.linalg.norm(trajectory.ego[:, None] - trajectory.obstacles, axis=2)
                 - trajectory.ego_radius - trajectory.obstacle_radii)
    assert record.min_distance == pytest.approx(distances.min())
    assert record.collision == (distances.min() <= 0.0)
    if record.goal_reached:
        assert np.linalg.norm(trajectory.ego[-1] - trajectory.goal) <= 0.3 + 1e-9
        assert record.time_to_goal == pytest.approx(0.2 * record.steps)


def test_same_seed_same_record_whatever_the_worker_count(tmp_path):
    kwargs = dict(episodes=2, seed=7, progress=False, **MPC)
    scenarios = ["HeadOn", "MultiObstacle"]
    serial = evaluate(scenarios, ["none", "dr_cvar"], workers=1, **kwargs)
    parallel = evaluate(scenarios, ["none", "dr_cvar"], workers=2, **kwargs)
    strip = [replace(r, wall_time=0.0, filter_time_median=0.0, filter_time_max=0.0)
             for r in serial]
    assert strip == [replace(r, wall_time=0.0, filter_time_median=0.0, filter_time_max=0.0)
                     for r in parallel]
    assert len(serial) == 8


def test_a_failing_episode_is_recorded_not_raised():
    class BrokenPolicy:
        def predict(self, observation, state=None, episode_start=None, deterministic=True):
            raise RuntimeError("policy exploded")

    spec = EpisodeSpec("HeadOn", "none", 0)
    record, _ = run_episode(spec, policy=BrokenPolicy())
    assert "policy exploded" in record.error
    assert record.steps == 0


def test_non_finite_actions_are_braked_by_the_filter_and_recorded():
    class NaNPolicy:
        def predict(self, observation, state=None, episode_start=None, deterministic=True):
            return np.array([np.nan, np.nan], dtype=np.float32), None

    record, _ = run_episode(EpisodeSpec("HeadOn", "dr_cvar", 0, reference="hold"),
                            policy=NaNPolicy())
    assert record.error == ""
    assert record.statuses.startswith("brake:")


def test_interrupted_run_resumes_from_its_csv(tmp_path):
    path = tmp_path / "episodes.csv"
    first = evaluate(["HeadOn"], ["mean"], episodes=2, csv_path=path,
                     progress=False, **MPC)
    assert len(read_records(path)) == 2
    both = evaluate(["HeadOn"], ["mean"], episodes=3, csv_path=path,
                    progress=False, **MPC)
    rows = list(csv.DictReader(path.open()))
    assert len(rows) == 3  # only the missing episode ran
    assert tuple(rows[0]) == RECORD_FIELDS
    assert both[:2] == first
    assert [r.seed for r in both] == [0, 1, 2]


def test_records_round_trip_through_csv(tmp_path):
    path = tmp_path / "episodes.csv"
    records = evaluate(["Overtaking"], ["cvar"], episodes=1, csv_path=path,
                       progress=False, **MPC)
    assert read_records(path) == records


def test_noise_preset_reaches_the_environment_and_the_record(tmp_path):
    spec = EpisodeSpec("HeadOn", "cvar", 0, planner="mpc", noise="authors_code")
    record, trajectory = run_episode(spec, record_trajectory=True)
    assert record.noise == "authors_code" and record.error == ""
    paper, _ = run_episode(replace(spec, noise=""))
    assert record.min_distance != paper.min_distance
    from agents.evaluation import make_env

    env, _ = make_env(spec)
    env.reset(seed=0)
    assert env.unwrapped.predictions.shape[1] == 20  # the authors' code draws 20 samples
    path = tmp_path / "noise.csv"
    evaluate(["HeadOn"], ["cvar"], episodes=1, csv_path=path, progress=False,
             planner="mpc", noise="authors_code")
    assert read_records(path)[0].noise == "authors_code"


def test_bad_evaluation_arguments_are_named():
    with pytest.raises(InvalidParameterError, match="risk"):
        episode_specs(["HeadOn"], ["maximal"], 1)
    with pytest.raises(InvalidParameterError, match="episodes"):
        episode_specs(["HeadOn"], ["none"], 0)
    with pytest.raises(InvalidParameterError, match="planner"):
        episode_specs(["HeadOn"], ["none"], 1, planner="rrt")
    with pytest.raises(InvalidParameterError, match="noise"):
        episode_specs(["HeadOn"], ["none"], 1, noise="pink")


def test_wilson_interval_brackets_the_rate_and_matches_a_known_value():
    low, high = wilson_interval(0, 100)
    assert low == 0.0 and high == pytest.approx(0.0370, abs=1e-4)
    low, high = wilson_interval(30, 100)
    assert low < 0.3 < high
    assert (low, high) == pytest.approx((0.2189, 0.3958), abs=1e-4)


def test_collision_bars_draw_rates_of_zero_and_one(tmp_path):
    from agents.plots import plot_collision_rates
    from agents.summary import SummaryRow

    rows = []
    for risk, hits in (("none", 300), ("dr_cvar", 0)):
        low, high = wilson_interval(hits, 300)
        rows.append(SummaryRow("HeadOn", "ppo", risk, 300, 0, hits / 300, low, high,
                               0.0, 0.0, 1.0, 2.0, 0.0, 0.0, 0.0))
    assert plot_collision_rates(rows, tmp_path / "bars.png").stat().st_size > 1000


def test_lower_tail_mean_is_the_mean_of_the_worst_share():
    values = np.arange(20.0)
    assert lower_tail_mean(values, 0.1) == pytest.approx(0.5)
    assert math.isnan(lower_tail_mean(np.array([np.nan])))


def test_summary_counts_collisions_and_failures():
    base = EpisodeSpec("HeadOn", "mean", 0)
    from agents.evaluation import EpisodeRecord

    records = [
        EpisodeRecord(base.scenario, "mean", s, "mpc", "rollout", 0.2, 0.1, 0.05, steps=10,
                      collision=s < 2, min_distance=-0.1 if s < 2 else 0.2, goal_reached=True,
                      time_to_goal=2.0)
        for s in range(5)
    ] + [EpisodeRecord(base.scenario, "mean", 9, "mpc", "rollout", 0.2, 0.1, 0.05,
                       error="boom")]
    (row,) = summarise(records)
    assert row.episodes == 6 and row.failed == 1
    assert row.collision_rate == pytest.approx(0.4)
    assert row.worst_distance == pytest.approx(-0.1)
    assert "(1 failed)" in markdown_table([row])

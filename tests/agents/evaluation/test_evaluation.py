"""Monte Carlo evaluation: records, determinism across workers, failures, resume."""

from __future__ import annotations

import csv
import math
from dataclasses import replace

import numpy as np
import pytest

from agents.evaluation.evaluate import episode_specs, evaluate
from agents.evaluation.records import RECORD_FIELDS, EpisodeSpec, read_records
from agents.evaluation.runner import run_episode
from agents.evaluation.summary import lower_tail_mean, markdown_table, summarise, wilson_interval
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
    # The sampled flag is the paper's; a sampled collision is a continuous-time one too.
    assert record.sampled_collision == (distances.min() <= 0.0)
    assert record.collision >= record.sampled_collision
    assert record.collision == any(trajectory.collisions)
    if not np.isnan(record.min_swept_distance):
        assert record.min_swept_distance <= record.min_distance + 1e-12
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
    assert record.share_brake + record.share_error == pytest.approx(1.0)
    assert record.first_error.startswith("step 1: ") and "nan" in record.first_error.lower()


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
    assert (first.reused, both.reused) == (0, 2)


def test_a_resumed_run_says_how_many_episodes_it_reused(tmp_path):
    from agents.evaluation.campaign import run_evaluation

    kwargs = dict(workers=1, plots=False, progress=False, **MPC)
    first = run_evaluation(tmp_path, ["HeadOn"], ["none"], episodes=1, **kwargs)
    assert "reused" not in str(first)
    again = run_evaluation(tmp_path, ["HeadOn"], ["none"], episodes=3, **kwargs)
    assert f"3 episodes (1 reused from {tmp_path / 'episodes.csv'}, 2 run now) in" in str(again)
    assert again.reused == 1


def test_the_interrupted_message_counts_the_reused_episodes(tmp_path):
    from argparse import Namespace

    from agents.cli.main import _interrupted_message
    from agents.evaluation.evaluate import EvaluationInterrupted

    exc = EvaluationInterrupted(3, 5, tmp_path / "episodes.csv", reused=2)
    message = _interrupted_message("safe-nav evaluate", exc, Namespace(output=tmp_path))
    assert "3 of 5 episodes finished (2 of them reused from an earlier run)" in message


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
    from agents.evaluation.runner import make_env

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
    from agents.evaluation.plots import plot_collision_rates
    from agents.evaluation.summary import SummaryRow

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
    from agents.evaluation.records import EpisodeRecord

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
    assert row.arrivals == 5 and "| 2.00 |" in markdown_table([row])


def test_the_summary_prints_a_dash_when_no_episode_arrived():
    from agents.evaluation.records import EpisodeRecord

    records = [EpisodeRecord("HeadOn", "mean", s, "mpc", "rollout", 0.2, 0.1, 0.05, steps=10,
                             min_distance=0.5, min_swept_distance=0.5, goal_reached=False)
               for s in range(3)]
    (row,) = summarise(records)
    header, _, line = markdown_table([row]).splitlines()
    cells = dict(zip(header.split(" | "), line.split(" | "), strict=True))
    assert cells["time to goal (s)"] == "- (0 arrived)"  # was "nan"
    assert row.arrivals == 0 and math.isnan(row.time_to_goal)


def test_a_missing_policy_fails_before_any_episode_runs(tmp_path):
    from agents.errors import PolicyFileError

    path = tmp_path / "episodes.csv"
    with pytest.raises(PolicyFileError, match="no PPO policy file"):
        evaluate(["HeadOn"], ["none"], episodes=1, csv_path=path, progress=False,
                 policy_path=str(tmp_path / "missing.zip"))
    assert not path.exists()


def test_bad_filter_settings_fail_before_any_episode_runs(tmp_path):
    path = tmp_path / "episodes.csv"
    with pytest.raises(InvalidParameterError, match="bogus"):
        evaluate(["HeadOn"], ["cvar"], episodes=1, csv_path=path, progress=False,
                 filter_options={"bogus": 1}, **MPC)
    assert not path.exists()


@pytest.mark.slow
def test_the_cache_refuses_a_different_policy(tmp_path):
    import shutil
    import zipfile

    from agents.errors import RunMismatchError
    from agents.training.ppo import pretrained_policy_path

    policy = tmp_path / "policy.zip"
    shutil.copy(pretrained_policy_path(), policy)
    path = tmp_path / "episodes.csv"
    kwargs = dict(episodes=1, csv_path=path, progress=False, policy_path=str(policy))
    first = evaluate(["Overtaking"], ["none"], **kwargs)
    with zipfile.ZipFile(policy, "a") as archive:
        archive.comment = b"one byte more"
    with pytest.raises(RunMismatchError, match="policy_sha256"):
        evaluate(["Overtaking"], ["none"], **kwargs)
    assert read_records(path) == first  # untouched
    again = evaluate(["Overtaking"], ["none"], overwrite=True, **kwargs)
    assert again[0].policy_sha256 != first[0].policy_sha256
    assert again[0].policy == str(policy)


def test_failed_and_repeated_rows_are_not_reused(tmp_path):
    from agents.evaluation.records import write_records

    path = tmp_path / "episodes.csv"
    good = evaluate(["HeadOn"], ["mean"], episodes=2, csv_path=path, progress=False, **MPC)
    failed = replace(good[1], error="RuntimeError: boom", steps=0)
    write_records(path, [good[0], good[1], failed])  # seed 1: a later failed row wins
    rerun = evaluate(["HeadOn"], ["mean"], episodes=2, csv_path=path, progress=False, **MPC)
    stored = read_records(path)
    assert len(stored) == 2 and not any(r.error for r in stored)
    assert [r.seed for r in rerun] == [0, 1] and rerun[0] == good[0]
    strip = dict(wall_time=0.0, filter_time_median=0.0, filter_time_max=0.0)
    assert replace(rerun[1], **strip) == replace(good[1], **strip)  # ran again, same result


def test_a_sweep_runs_its_whole_grid_on_one_executor(tmp_path):
    from agents.evaluation.campaign import run_sweep
    from agents.evaluation.executors import SerialExecutor

    class Counting(SerialExecutor):
        def __init__(self):
            self.batches = []

        def run(self, specs):
            self.batches.append([(s.delta, s.epsilon) for s in specs])
            yield from super().run(specs)

    executor = Counting()
    outputs = run_sweep(tmp_path / "sweep", ["HeadOn"], epsilons=(0.0, 0.1), deltas=(0.0, 0.1),
                        episodes=1, workers=1, planner="mpc", executor=executor,
                        progress=False)
    assert len(executor.batches) == 1
    assert sorted(executor.batches[0]) == [(0.0, 0.0), (0.0, 0.1), (0.1, 0.0), (0.1, 0.1)]
    assert len(outputs.records) == 4
    # Resuming the sweep with one more epsilon runs only the new points.
    run_sweep(tmp_path / "sweep", ["HeadOn"], epsilons=(0.0, 0.1, 0.2), deltas=(0.0, 0.1),
              episodes=1, workers=1, planner="mpc", executor=executor, progress=False)
    assert sorted(executor.batches[1]) == [(0.0, 0.2), (0.1, 0.2)]


@pytest.mark.slow
def test_a_process_pool_starts_once_for_several_runs():
    from agents.evaluation.executors import ProcessExecutor

    specs = episode_specs(["HeadOn"], ["none", "cvar"], 2, seed=5, **MPC)
    serial = sorted((run_episode(spec)[0] for spec in specs), key=lambda r: r.key())
    strip = dict(wall_time=0.0, filter_time_median=0.0, filter_time_max=0.0)
    with ProcessExecutor(2) as executor:
        first = list(executor.run(specs[:2]))
        second = list(executor.run(specs[2:]))
        assert executor.starts == 1
    pooled = sorted(first + second, key=lambda r: r.key())
    assert [replace(r, **strip) for r in pooled] == [replace(r, **strip) for r in serial]


@pytest.mark.slow
def test_collision_columns_match_the_environment_step_by_step():
    from agents.evaluation.runner import make_env

    # The unfiltered PPO on HeadOn crosses the obstacle between samples in most seeds.
    for seed in range(3):
        spec = EpisodeSpec("HeadOn", "none", seed)
        record, _ = run_episode(spec)
        env, planner = make_env(spec)
        obs, info = env.reset(seed=seed)
        swept, sampled, continuous, done = [info["min_swept_distance_to_collision"]], [], [], False
        while not done:
            action, _ = planner.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            swept.append(info["min_swept_distance_to_collision"])
            sampled.append(info["sampled_collision"])
            continuous.append(info["collision"])
            done = terminated or truncated
        env.close()
        assert record.error == ""
        assert record.min_swept_distance == pytest.approx(min(swept))
        assert record.collision_steps == sum(continuous)
        assert record.sampled_collision_steps == sum(sampled)
        assert record.first_collision_step == (continuous.index(True) + 1 if any(continuous)
                                               else 0)
        if any(continuous):
            first = continuous.index(True)
            assert record.collision_cause == ("noise" if sampled[first] else "inter_sample")
        else:
            assert record.collision_cause == ""


def test_the_evaluation_loads_the_policy_that_sb3_loads():
    """load_policy's numpy export acts as SB3 does (by tolerance, the numpy policy's own
    rule)."""
    import sys

    from agents.evaluation.runner import load_policy
    from agents.training.ppo import load_ppo

    policy, _ = load_policy("")
    assert type(policy).__name__ == "NumpyPolicy"
    model = load_ppo()
    rng = np.random.default_rng(4)
    low, high = model.observation_space.low, model.observation_space.high
    observations = rng.uniform(np.maximum(low, -5.0), np.minimum(high, 5.0),
                               (64, *low.shape)).astype(np.float32)
    for obs in observations:
        expected, _ = model.predict(obs, deterministic=True)
        action, _ = policy.predict(obs, deterministic=True)
        np.testing.assert_allclose(action, expected, rtol=0,
                                   atol=1e-6 * max(1.0, float(np.max(np.abs(expected)))))
    assert "stable_baselines3" in sys.modules  # (this test loaded the model itself)


def test_a_zip_that_holds_no_policy_is_a_policy_file_error(tmp_path):
    import zipfile

    from agents.errors import PolicyFileError
    from agents.evaluation.runner import load_policy

    path = tmp_path / "empty.zip"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("readme.txt", "no policy here")
    with pytest.raises(PolicyFileError, match="cannot load the PPO policy"):
        load_policy(str(path))


def test_the_policy_export_is_cached_on_disk_by_the_files_hash(tmp_path, monkeypatch):
    """The first load saves the numpy export; later processes read it (no torch); an
    unreadable cache file is exported again."""
    import os
    import subprocess
    import sys

    from agents.evaluation import policy_files

    monkeypatch.setenv("SAFE_NAV_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(policy_files, "_POLICY_CACHE", {})
    exported, sha = policy_files.load_policy("")
    saved = tmp_path / "policies" / f"{sha}.npz"
    assert saved.is_file()

    def no_export(path, sha):
        raise AssertionError("exported again instead of reading the cache")

    monkeypatch.setattr(policy_files, "_POLICY_CACHE", {})
    with monkeypatch.context() as patch:
        patch.setattr(policy_files, "_export", no_export)
        cached, _ = policy_files.load_policy("")
    observations = np.random.default_rng(5).standard_normal((50, 26)).astype(np.float32)
    expected = exported.predict_batch(observations)
    np.testing.assert_allclose(cached.predict_batch(observations), expected, rtol=0,
                               atol=1e-6 * max(1.0, float(np.max(np.abs(expected)))))
    code = ("import sys; from agents.evaluation.policy_files import load_policy; "
            "print(type(load_policy('')[0]).__name__, 'torch' in sys.modules)")
    fresh = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           env={**os.environ, "SAFE_NAV_CACHE_DIR": str(tmp_path)}, check=True)
    assert fresh.stdout.split() == ["NumpyPolicy", "False"]
    saved.write_bytes(b"truncated")
    monkeypatch.setattr(policy_files, "_POLICY_CACHE", {})
    again, _ = policy_files.load_policy("")
    np.testing.assert_allclose(again.predict_batch(observations), expected, rtol=0,
                               atol=1e-6 * max(1.0, float(np.max(np.abs(expected)))))
    assert type(again).__name__ == "NumpyPolicy"
    np.load(saved).close()  # rewritten: a valid file again


def _imported_torch(_: object = None) -> bool:
    import sys

    return "torch" in sys.modules


@pytest.mark.slow
def test_pool_workers_take_the_parents_policy_and_import_no_torch():
    from agents.evaluation.executors import ProcessExecutor

    specs = episode_specs(["HeadOn"], ["dr_cvar"], 2, seed=1)
    serial = sorted((run_episode(spec)[0] for spec in specs), key=lambda r: r.key())
    strip = dict(wall_time=0.0, filter_time_median=0.0, filter_time_max=0.0)
    with ProcessExecutor(2) as executor:
        pooled = sorted(executor.run(specs), key=lambda r: r.key())
        assert not any(executor._pool.submit(_imported_torch).result() for _ in range(4))
    assert not any(r.error for r in pooled)
    assert [replace(r, **strip) for r in pooled] == [replace(r, **strip) for r in serial]


def test_a_started_pool_has_its_workers_before_the_first_run():
    from agents.evaluation.executors import ProcessExecutor

    specs = episode_specs(["HeadOn"], ["none"], 2, **MPC)
    with ProcessExecutor(2) as executor:
        executor.start()
        executor.start()  # idempotent
        assert len(executor.worker_pids()) == 2 and executor.starts == 1
        records = list(executor.run(specs))
        assert executor.starts == 1 and len(records) == 2

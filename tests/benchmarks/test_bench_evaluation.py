"""``safe-nav bench --evaluation``: the scaling bookkeeping (no timing asserts)."""

from __future__ import annotations

import csv

import pytest

from agents.cli.main import main
from benchmarks.evaluation import (
    EvaluationRun,
    EvaluationScaling,
    benchmark_evaluation,
    same_rows,
)
from filters.errors import InvalidParameterError


def test_speedup_and_serial_part_follow_their_formulas():
    runs = (EvaluationRun(1, 50.0, 49.0, 0.0, 0.1), EvaluationRun(2, 30.0, 6.0, 48.0, 0.2),
            EvaluationRun(2, 28.0, 6.0, 47.0, 0.3), EvaluationRun(1, 54.0, 50.0, 0.0, 0.1),
            EvaluationRun(1, 52.0, 51.0, 0.0, 0.4), EvaluationRun(2, 40.0, 7.0, 49.0, 0.2))
    result = EvaluationScaling(episodes=4800, runs=runs, same_rows=True)
    assert result.wall(1) == 52.0 and result.wall(2) == 30.0  # medians
    assert result.speedup == pytest.approx(52.0 / 30.0)
    assert result.serial == pytest.approx(2 * 30.0 - 52.0)  # t2 = s + p/2, t1 = s + p
    assert result.cpu(2) == pytest.approx(54.0)  # parent + workers, median over the runs
    text = result.format()
    assert "1.73x" in text and "serial part" in text and "same rows" in text


def _write(path, rows):
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=["scenario", "seed", "wall_time"])
        writer.writeheader()
        writer.writerows(rows)


def test_same_rows_ignores_order_and_timing_columns(tmp_path):
    a = [{"scenario": "HeadOn", "seed": 0, "wall_time": 0.1},
         {"scenario": "HeadOn", "seed": 1, "wall_time": 0.2}]
    _write(tmp_path / "a.csv", a)
    _write(tmp_path / "b.csv", [dict(a[1], wall_time=9.0), a[0]])
    _write(tmp_path / "c.csv", [a[0], dict(a[1], seed=2)])
    assert same_rows(tmp_path / "a.csv", tmp_path / "b.csv")
    assert not same_rows(tmp_path / "a.csv", tmp_path / "c.csv")


def test_bad_arguments_are_named(capsys):
    with pytest.raises(InvalidParameterError, match="runs"):
        benchmark_evaluation(episodes=1, runs=0)
    assert main(["bench", "--evaluation", "0"]) == 2
    assert "--evaluation" in capsys.readouterr().err


@pytest.mark.slow
def test_the_benchmark_runs_safe_nav_evaluate_on_one_and_two_workers():
    result = benchmark_evaluation(episodes=1, runs=1)
    assert result.episodes == 16  # 4 scenarios x 4 risks, 1 episode each
    assert [run.workers for run in result.runs] == [1, 2]
    assert result.same_rows
    one, two = result.runs
    assert one.workers_cpu == 0.0 < two.workers_cpu  # 1 worker runs in the process
    assert all(run.wall > 0 and run.parent_cpu > 0 for run in result.runs)

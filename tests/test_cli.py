"""The ``safe-nav`` command line, end to end into a temporary folder."""

from __future__ import annotations

import csv

import pytest

from agents.cli import main, scenario_id
from agents.evaluation import RECORD_FIELDS


def test_evaluate_writes_csv_summary_and_figures(tmp_path, capsys):
    out = tmp_path / "eval"
    code = main(["evaluate", "--scenarios", "HeadOn", "MultiObstacle", "--risks", "none",
                 "dr_cvar", "--planner", "mpc", "--episodes", "2", "--workers", "1",
                 "--output", str(out), "--no-progress"])
    assert code == 0
    rows = list(csv.DictReader((out / "episodes.csv").open()))
    assert len(rows) == 2 * 2 * 2
    assert tuple(rows[0]) == RECORD_FIELDS
    summary = (out / "summary.md").read_text()
    assert "| HeadOn | mpc | dr_cvar | 2 |" in summary
    assert "| MultiObstacle | mpc | none | 2 |" in summary
    for name in ("trajectories_HeadOn.png", "trajectories_MultiObstacle.png",
                 "distance_boxplots.png", "collision_rates.png", "safe_polytopes.png",
                 "episode.gif"):
        assert (out / "figures" / name).stat().st_size > 1000, name
    assert "episodes in" in capsys.readouterr().out


def test_evaluate_with_the_shipped_policy_by_default(tmp_path):
    out = tmp_path / "ppo"
    assert main(["evaluate", "--scenarios", "Overtaking", "--risks", "none", "dr_cvar",
                 "--episodes", "1", "--workers", "1", "--output", str(out), "--no-plots",
                 "--no-progress"]) == 0
    rows = list(csv.DictReader((out / "episodes.csv").open()))
    assert {r["planner"] for r in rows} == {"ppo"}
    assert all(r["error"] == "" for r in rows)


def test_sweep_writes_its_table_and_plot(tmp_path):
    out = tmp_path / "sweep"
    assert main(["evaluate", "--sweep", "--scenarios", "HeadOn", "--planner", "mpc",
                 "--episodes", "1", "--workers", "1", "--epsilons", "0", "0.1",
                 "--deltas", "0.1", "--output", str(out), "--no-progress"]) == 0
    table = (out / "sweep.md").read_text()
    assert table.count("\n| 0.1 |") == 2
    assert (out / "figures" / "sweep.png").stat().st_size > 1000


def test_reproduce_writes_the_report_and_figures(tmp_path):
    out = tmp_path / "repro"
    assert main(["reproduce", "--episodes", "1", "--workers", "1", "--timing-repeats", "2",
                 "--output", str(out), "--no-progress"]) == 0
    report = (out / "report.md").read_text()
    for heading in ("Example 1", "Table I", "Monte Carlo", "Against the paper"):
        assert heading in report
    assert (out / "figures" / "example1_halfspaces.png").exists()
    assert (out / "figures" / "halfspace_times.png").exists()
    assert (out / "monte_carlo" / "figures" / "distance_boxplots.png").exists()
    assert "b_DR-CVaR = b_CVaR - eps/alpha" in report


def test_unknown_scenario_and_bad_counts_are_rejected(capsys):
    with pytest.raises(SystemExit):
        main(["evaluate", "--scenarios", "Roundabout"])
    assert "Roundabout" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["evaluate", "--episodes", "0"])
    assert scenario_id("HeadOn") == "SafeNav/HeadOn-v0"

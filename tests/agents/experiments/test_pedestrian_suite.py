"""safe-nav evaluate --suite pedestrians: per-scene metrics through the evaluation pipeline."""

from __future__ import annotations

import math

from agents.cli import main
from agents.experiments.pedestrians import pedestrian_rows, run_pedestrians


def test_the_table_has_a_row_per_scene_and_risk_with_its_metrics(tmp_path):
    outputs = run_pedestrians(tmp_path, ["zara1"], ["none", "dr_cvar"], episodes=2, workers=1,
                              planner="mpc", progress=False)
    rows = pedestrian_rows(outputs.records)
    assert [(r.scene, r.risk, r.episodes, r.failed) for r in rows] == [
        ("zara1", "none", 2, 0), ("zara1", "dr_cvar", 2, 0)]
    unfiltered, filtered = rows
    assert math.isnan(unfiltered.infeasible) and 0.0 <= filtered.infeasible <= 1.0
    assert 0.0 <= filtered.miscoverage <= 1.0
    assert filtered.worst_min_distance <= filtered.median_min_distance
    assert all(r.collision_low <= r.collision <= r.collision_high for r in rows)
    assert all(0.0 <= r.standing_collision <= r.collision for r in rows)
    standing = sum(r.collision and r.standing_collision
                   for r in outputs.records if r.risk == "none")
    assert unfiltered.standing_collision == standing / 2
    summary = (tmp_path / "summary.md").read_text()
    assert "Pellegrini" in summary and "Lerner" in summary and "| zara1 | dr_cvar | 2 |" in summary
    assert "| of which standing |" in summary


def test_the_cli_runs_the_suite_with_its_scenes(tmp_path, capsys):
    code = main(["evaluate", "--suite", "pedestrians", "--scenes", "hotel", "eth", "--risks",
                 "none", "--planner", "mpc", "--episodes", "1", "--workers", "1", "--output",
                 str(tmp_path), "--no-progress"])
    assert code == 0
    summary = (tmp_path / "summary.md").read_text()  # two scenes in one run
    assert "| hotel | none | 1 |" in summary and "| eth | none | 1 |" in summary


def test_the_calibrated_filter_runs_on_a_scene_with_empty_slots(tmp_path):
    # eth has moments with nobody near the ego: the calibration (held-out episodes,
    # then the run) must score only the pedestrians present, by identity.
    outputs = run_pedestrians(tmp_path, ["eth"], ["conformal"], episodes=2, workers=1,
                              planner="mpc", progress=False)
    assert [r.error for r in outputs.records] == ["", ""]

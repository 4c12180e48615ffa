"""safe-nav evaluate --suite crowd: CrowdNav's metrics through the evaluation pipeline."""

from __future__ import annotations

import math

import pytest

from agents.cli import main
from agents.experiments.crowd import CROWD_SETTINGS, crowd_rows, run_crowd
from agents.experiments.scenes import scene_setting, scene_specs
from filters.errors import InvalidParameterError


def test_every_setting_and_risk_runs_the_same_test_cases():
    specs = scene_specs("Crowd", CROWD_SETTINGS, ["orca_invisible", "social_force_visible"],
                        ["none", "dr_cvar"], episodes=3, seed=10, planner="mpc")
    assert len(specs) == 2 * 2 * 3
    assert {s.scenario for s in specs} == {"Crowd"}
    for setting in ("orca_invisible", "social_force_visible"):
        for risk in ("none", "dr_cvar"):
            cell = [s for s in specs if s.risk == risk and setting in _name(s)]
            assert [s.seed for s in cell] == [10, 11, 12]
    with pytest.raises(InvalidParameterError, match="boids"):
        scene_specs("Crowd", CROWD_SETTINGS, ["boids"], ["none"], episodes=1, seed=0)


def _name(spec):
    import json

    options = json.loads(spec.env_options)
    visible = "visible" if options["robot_visible"] else "invisible"
    return f"{options['human_policy']}_{visible}"


def test_the_table_counts_success_collision_and_timeout_once_each(tmp_path):
    outputs = run_crowd(tmp_path, ["orca_invisible"], ["none", "dr_cvar"], episodes=3,
                        workers=1, planner="mpc", progress=False)
    rows = crowd_rows(outputs.records)
    assert [(r.setting, r.risk, r.cases) for r in rows] == [
        ("orca_invisible", "none", 3), ("orca_invisible", "dr_cvar", 3)]
    for row in rows:
        assert math.isclose(row.success + row.collision + row.timeout, 1.0)
        assert row.success_low <= row.success <= row.success_high
        assert 0.0 <= row.discomfort <= 1.0
        assert 0.0 <= row.standing_collision <= row.collision
    assert all(scene_setting(r, CROWD_SETTINGS) == "orca_invisible" for r in outputs.records)
    summary = (tmp_path / "summary.md").read_text()
    assert "| orca_invisible | dr_cvar | 3 |" in summary and "discomfort frequency" in summary
    assert "| of which standing |" in summary


def test_the_cli_refuses_scenarios_with_the_crowd_suite(tmp_path, capsys):
    code = main(["evaluate", "--suite", "crowd", "--scenarios", "HeadOn", "--output",
                 str(tmp_path / "out"), "--no-progress"])
    assert code == 2
    assert "--suite crowd sets the scene itself" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()

"""scripts/plot_safe_rl.py: the safe-RL comparison's points come from the records."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from agents.evaluation.records import EpisodeRecord, write_records

_SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "plot_safe_rl.py"


def _load():
    spec = importlib.util.spec_from_file_location("plot_safe_rl", _SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _records(risk: str, collisions: int, n: int, time_to_goal: float, scenario="HeadOn"):
    return [EpisodeRecord(scenario=scenario, risk=risk, seed=s, planner="ppo",
                          reference="rollout", alpha=0.2, delta=0.1, epsilon=0.05,
                          collision=s < collisions, goal_reached=True,
                          time_to_goal=time_to_goal, steps=10)
            for s in range(n)]


def test_points_count_the_records_and_skip_other_risks(tmp_path):
    plot = _load()
    folder = tmp_path / "ppo"
    write_records(folder / "episodes.csv",
                  _records("none", 7, 10, 2.0) + _records("dr_cvar", 1, 10, 2.5)
                  + _records("mean", 0, 10, 9.0))
    panels = plot.panels([("PPO", folder / "episodes.csv")])
    points = {p.label: p for p in panels["HeadOn"]}
    assert set(points) == {"PPO", "PPO + DR-CVaR filter"}
    assert (points["PPO"].collisions, points["PPO"].n) == (7, 10)
    assert points["PPO + DR-CVaR filter"].collisions == 1
    assert points["PPO + DR-CVaR filter"].time_to_goal == pytest.approx(2.5)
    assert plot.main(["--run", f"PPO={folder}", "--output", str(tmp_path / "f.png")]) == 0
    assert (tmp_path / "f.png").stat().st_size > 1000


def test_a_folder_without_records_is_refused(tmp_path, capsys):
    plot = _load()
    with pytest.raises(SystemExit) as exit_info:
        plot.main(["--run", f"PPO={tmp_path}"])
    assert exit_info.value.code == 2
    assert "no episodes.csv" in capsys.readouterr().err

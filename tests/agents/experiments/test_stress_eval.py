"""``safe-nav evaluate --suite stress``: a tiny suite end to end, resume, bad options."""

from __future__ import annotations

import csv

import pytest

from agents.cli.main import main
from agents.evaluation.audit import decode_losses
from agents.evaluation.records import EpisodeSpec
from agents.experiments.stress import STRESS_METHODS, stress_specs
from filters.errors import InvalidParameterError
from safe_nav_env.stress import STRESS_SUITE

TINY = ["evaluate", "--suite", "stress", "--cases", "heavy_tail", "stopping", "--planners",
        "ppo", "goal", "--methods", "none", "default", "dr_cvar_auto", "--episodes", "2",
        "--workers", "1", "--no-progress"]


@pytest.mark.slow
def test_tiny_stress_suite_end_to_end(tmp_path, capsys):
    out = tmp_path / "stress"
    assert main([*TINY, "--output", str(out)]) == 0
    rows = list(csv.DictReader((out / "episodes.csv").open()))
    assert len(rows) == 2 * 2 * 3 * 2
    cells = {(r["case"], r["planner"], r["risk"], r["epsilon"], r["reference"]) for r in rows}
    assert cells == {(case, planner, risk, epsilon, reference)
                     for case in ("heavy_tail", "stopping") for planner in ("ppo", "goal")
                     for risk, epsilon, reference in (("none", "0.05", "rollout"),
                                                      ("dr_cvar", "0.05", "hold"),
                                                      ("dr_cvar", "auto", "rollout"))}
    assert all(r["scenario"] == "Custom" and r["error"] == "" for r in rows)
    for r in rows:
        # The explanation columns: set exactly for the collided episodes.
        collided = r["collision"] == "True"
        assert bool(r["status_at_collision"]) == collided
        if collided and int(r["first_collision_step"]) > 1:
            assert r["status_before_collision"]
        filtered = r["risk"] != "none"
        assert (r["status_at_collision"] == "passthrough") == (collided and not filtered)
        first = int(r["first_infeasible_step"])
        assert 0 <= first <= int(r["steps"])
        assert (first > 0) == (r["statuses"] != "" and any(
            s.split(":")[0] not in ("optimal", "passthrough") for s in r["statuses"].split(";")))
        # The audit columns agree with each other.
        assert int(r["audit_steps"]) == decode_losses(r["audit_losses"]).size
        assert int(r["audit_all_steps"]) == decode_losses(r["audit_all_losses"]).size
        assert (int(r["audit_all_steps"]) > 0) == filtered
    table = list(csv.DictReader((out / "stress_table.csv").open()))
    assert len(table) == 2 * 2 * 3
    assert set(table[0]) >= {"case", "planner", "method", "collisions", "collision_low",
                             "collision_high", "goal_rate", "time_to_goal", "meets_target"}
    for cell in table:
        assert int(cell["episodes"]) == 2
        meets = float(cell["collision_rate"]) <= 0.01 and float(cell["goal_rate"]) >= 0.95
        assert cell["meets_target"] == str(meets)
    summary = (out / "summary.md").read_text()
    assert "## Overview" in summary and "### heavy_tail" in summary and "### stopping" in summary
    assert "| goal | default wrapper (dr_cvar, eps=0.05, hold) | 2 |" in summary
    assert "| ppo | dr_cvar (eps=auto) | 2 |" in summary
    assert "## Explained collisions" in summary and "## Guarantee audit" in summary
    assert (out / "figures" / "pareto.png").stat().st_size > 5000
    capsys.readouterr()
    # The same command resumes: nothing runs again, the CSV keeps its rows.
    assert main([*TINY, "--output", str(out), "--no-plots"]) == 0
    assert len(list(csv.DictReader((out / "episodes.csv").open()))) == 24


def test_stress_rejects_options_it_sets_itself(tmp_path, capsys):
    code = main([*TINY, "--risks", "mean", "--output", str(tmp_path / "x")])
    assert code == 2
    assert "--risks" in capsys.readouterr().err
    code = main([*TINY[:-6], "--methods", "nonsense", "--output", str(tmp_path / "x")])
    assert code == 2
    code = main([*TINY[:-6], "--planners", "robot", "--output", str(tmp_path / "x")])
    assert code == 2


def test_a_bad_reference_is_refused_even_when_every_method_fixes_its_own():
    with pytest.raises(InvalidParameterError, match="reference .*'bogus'"):
        stress_specs(methods=["default"], reference="bogus", episodes=1)


def test_stress_specs_share_seeds_across_cells():
    specs = stress_specs(["biased", "turning"], list(STRESS_METHODS), ["ppo", "goal"],
                         episodes=3, seed=5)
    assert len(specs) == 2 * 2 * len(STRESS_METHODS) * 3
    cells = {}
    for spec in specs:
        key = (spec.case, spec.planner, spec.risk, spec.epsilon, spec.reference)
        cells.setdefault(key, []).append(spec.seed)
    assert len(cells) == 2 * 2 * len(STRESS_METHODS)
    assert all(seeds == [5, 6, 7] for seeds in cells.values())
    assert {spec.epsilon for spec in specs if spec.risk == "dr_cvar"} == {0.05, "auto"}
    # The default wrapper holds the action; every other setting tracks the run's reference.
    assert {spec.reference for spec in specs if spec.risk == "dr_cvar" and spec.epsilon == 0.05
            } == {"hold", "rollout"}
    assert {spec.reference for spec in specs if spec.risk != "dr_cvar"} == {"rollout"}
    assert {spec.case for spec in stress_specs(episodes=1)} == set(STRESS_SUITE)
    with pytest.raises(InvalidParameterError, match="planners must be"):
        stress_specs(planners=["robot"])
    with pytest.raises(InvalidParameterError, match="cases must be"):
        stress_specs(["nope"])
    with pytest.raises(InvalidParameterError, match="sets 'noise'"):
        stress_specs(noise="paper")


def test_episode_spec_case_and_auto_epsilon_validation():
    spec = EpisodeSpec("Custom", "dr_cvar", 0, epsilon="auto", case="biased")
    assert spec.filter_kwargs()["epsilon"] == "auto"
    assert spec.env_kwargs()["scenario"].name == "HeadOn"
    with pytest.raises(InvalidParameterError, match="case must be"):
        EpisodeSpec("Custom", "cvar", 0, case="nope")
    with pytest.raises(InvalidParameterError, match="runs on the scenario 'Custom'"):
        EpisodeSpec("HeadOn", "cvar", 0, case="biased")
    with pytest.raises(InvalidParameterError, match='number or "auto"'):
        EpisodeSpec("HeadOn", "dr_cvar", 0, epsilon="big")

"""``safe-nav evaluate --suite stress``: a tiny suite end to end, resume, bad options."""

from __future__ import annotations

import csv

import pytest

from agents.cli.main import main
from agents.evaluation.audit import decode_losses
from agents.evaluation.records import EpisodeSpec
from agents.experiments.stress import STRESS_METHODS, stress_specs
from filters.errors import InvalidParameterError

TINY = ["evaluate", "--suite", "stress", "--cases", "heavy_tail", "crossing5", "--methods",
        "none", "dr_cvar_auto", "--episodes", "1", "--workers", "1", "--no-progress"]


@pytest.mark.slow
def test_tiny_stress_suite_end_to_end(tmp_path, capsys):
    out = tmp_path / "stress"
    assert main([*TINY, "--output", str(out)]) == 0
    rows = list(csv.DictReader((out / "episodes.csv").open()))
    assert len(rows) == 2 * 2
    assert {(r["case"], r["risk"], r["epsilon"]) for r in rows} == {
        ("heavy_tail", "none", "0.05"), ("heavy_tail", "dr_cvar", "auto"),
        ("crossing5", "none", "0.05"), ("crossing5", "dr_cvar", "auto")}
    assert all(r["scenario"] == "Custom" and r["error"] == "" for r in rows)
    for r in rows:  # the audit columns agree with each other
        assert int(r["audit_steps"]) == decode_losses(r["audit_losses"]).size
        assert int(r["audit_all_steps"]) == decode_losses(r["audit_all_losses"]).size
        active = set(r["audit_losses"].split(";")) - {""}
        assert active <= set(r["audit_all_losses"].split(";"))
        filtered = r["risk"] != "none"
        assert (int(r["audit_all_steps"]) > 0) == filtered
        if r["case"] == "crossing5" and filtered:  # every step, five obstacles
            assert int(r["audit_all_steps"]) == 5 * int(r["steps"])
    summary = (out / "summary.md").read_text()
    assert "### heavy_tail" in summary and "### crossing5" in summary
    assert "| dr_cvar (eps=auto) | 1 |" in summary and "| none (unfiltered) | 1 |" in summary
    assert "## Guarantee audit" in summary and "CVaR_α ℓ ≤ δ" in summary
    assert (out / "figures" / "pareto.png").stat().st_size > 5000
    capsys.readouterr()
    # The same command resumes: nothing runs again, the CSV keeps its rows.
    assert main([*TINY, "--output", str(out), "--no-plots"]) == 0
    assert len(list(csv.DictReader((out / "episodes.csv").open()))) == 4


def test_stress_rejects_options_it_sets_itself(tmp_path, capsys):
    code = main([*TINY, "--risks", "mean", "--output", str(tmp_path / "x")])
    assert code == 2
    assert "--risks" in capsys.readouterr().err
    code = main([*TINY[:-6], "--methods", "nonsense", "--output", str(tmp_path / "x")])
    assert code == 2


def test_stress_specs_share_seeds_across_cells():
    specs = stress_specs(["biased", "turning"], list(STRESS_METHODS), episodes=3, seed=5)
    assert len(specs) == 2 * len(STRESS_METHODS) * 3
    cells = {}
    for spec in specs:
        cells.setdefault((spec.case, spec.risk, spec.epsilon), []).append(spec.seed)
    assert len(cells) == 2 * len(STRESS_METHODS)
    assert all(seeds == [5, 6, 7] for seeds in cells.values())
    assert {spec.epsilon for spec in specs if spec.risk == "dr_cvar"} == {0.05, "auto"}
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

"""``safe-nav bench --training``: the throughput ratio's bookkeeping (no timing asserts)."""

from __future__ import annotations

import dataclasses

import pytest

from agents.cli.main import main
from benchmarks.training import TrainingThroughput, benchmark_training


def test_training_benchmark_runs_both_kinds_and_reports_the_ratios():
    result = benchmark_training(timesteps=2 * 2048, chunk=2048, warmup_steps=256)
    assert result.timesteps == 4096 and len(result.plain_wall) == len(result.filtered_wall) == 2
    assert all(r > 0 for r in (*result.plain_wall, *result.filtered_wall,
                               *result.plain_cpu, *result.filtered_cpu))
    # the filter reports were read: every part of a filtered step took some time
    assert all(result.filter_us[key] > 0 for key in ("reference", "halfspaces", "qp"))
    assert result.filter_us["step"] > result.filter_us["halfspaces"] + result.filter_us["qp"]
    # the steps the hard QP could not answer: a share, and a part of the QP's time
    assert 0.0 <= result.not_optimal_share <= 1.0
    assert 0.0 <= result.filter_us["qp_not_optimal"] <= result.filter_us["qp"]
    text = result.format()
    assert "ratio filtered / plain" in text and "the rest" in text and "not optimal" in text


def test_throughput_ratios_follow_their_formulas():
    result = TrainingThroughput(
        chunk=100, plain_wall=(1000.0, 900.0, 1100.0), filtered_wall=(500.0, 450.0, 700.0),
        plain_cpu=(2000.0, 2000.0, 2000.0), filtered_cpu=(1000.0, 1200.0, 800.0),
        filter_us={"reference": 10.0, "halfspaces": 600.0, "qp": 300.0, "step": 2000.0})
    assert result.timesteps == 300
    assert "not optimal" not in result.format()  # the share was not measured: no line
    assert "8 environments" in result.format()
    assert "1 environment," in dataclasses.replace(result, n_envs=1).format()
    measured = dataclasses.replace(result, not_optimal_share=0.25,
                                   filter_us={**result.filter_us, "qp_not_optimal": 120.0})
    assert "120 on the 25 % of steps not optimal" in measured.format()
    assert result.ratio == pytest.approx(500.0 / 1000.0)
    assert result.cpu_ratio == pytest.approx(0.5)
    assert result.pair_ratio == pytest.approx(0.5)  # median of 0.5, 0.5, 0.636


def test_training_benchmark_options_are_checked(capsys):
    assert main(["bench", "--training", "--timesteps", "0"]) == 2
    assert main(["bench", "--training", "--chunk", "-1"]) == 2
    assert "--chunk" in capsys.readouterr().err
    assert main(["bench", "--training", "--envs", "0"]) == 2
    assert "--envs" in capsys.readouterr().err

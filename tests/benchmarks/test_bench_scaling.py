"""``safe-nav bench --scaling``: a smoke test on a tiny grid, and the pieces it is built of."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from agents.cli.main import main
from benchmarks.filter_qp import make_instances
from benchmarks.scaling import FULL_GRID, QUICK_GRID, ScalingGrid
from filters import InvalidParameterError


def test_bench_scaling_quick_runs_and_writes_table_csv_and_plot(tmp_path, capsys):
    code = main(["bench", "--scaling", "--quick", "--obstacles", "1", "3", "--horizons", "5",
                 "--samples", "20", "--steps", "6", "--output", str(tmp_path), "--no-policy"])
    assert code == 0
    out = capsys.readouterr().out
    assert "| obstacles | T | N_s | halfspaces | QP | step | CVXPY QP |" in out
    assert "| 1 | 5 | 20 |" in out and "| 3 | 5 | 20 |" in out
    assert "per QP clarabel (CPU, iterations, CPU µs per iteration) |" in out
    with (tmp_path / "scaling.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [(r["n_obstacles"], r["horizon"], r["n_samples"]) for r in rows] == [
        ("1", "5", "20"), ("3", "5", "20")]
    for row in rows:
        step, halfspaces, qp = float(row["step_ms"]), float(row["halfspaces_ms"]), float(
            row["qp_ms"])
        assert 0 < halfspaces < step and 0 < qp < step
        assert np.isclose(float(row["ratio"]), float(row["cvxpy_ms"]) / step)
        assert sum(int(s.split(":")[1]) for s in row["statuses"].split()) == 6
        assert float(row["agreement"]) >= 0.5  # ours and CVXPY mostly agree on the status
        assert float(row["max_input_difference"]) < 1e-3
        # the hard QP alone (clarabel)
        for name in ("clarabel",):
            per_qp, iterations = float(row[f"{name}_per_qp_ms"]), float(
                row[f"{name}_per_qp_iterations"])
            assert per_qp > 0 and iterations >= 1
            cpu = float(row[f"{name}_per_qp_cpu_ms"])
            assert 0 < cpu <= per_qp * 1.5  # medians of CPU <= wall per step
            assert 0 < float(row[f"{name}_per_iteration_us"]) <= 1e3 * cpu
            assert 0 <= float(row[f"{name}_per_qp_solved"]) <= 1
    assert (tmp_path / "scaling.png").stat().st_size > 10_000
    assert (tmp_path / "scaling.md").read_text().startswith("python ")


def test_instances_cross_the_obstacles_so_that_rows_are_active():
    rng = np.random.default_rng(0)
    instances = make_instances(40, 3, 10, rng, n_samples=50)
    assert len(instances) == 40 and instances[0].new_episode
    assert instances[0].samples.shape == (3, 50, 10, 2)
    assert instances[0].reference_states.shape == (11, 4)
    # the ego reference passes within 1 m of a predicted obstacle on some steps
    closest = min(
        np.min(np.linalg.norm(i.samples.mean(axis=1) - i.reference_states[None, 1:, :2], axis=-1))
        for i in instances)
    assert closest < 1.0
    again = make_instances(40, 3, 10, np.random.default_rng(0), n_samples=50)
    assert all(np.array_equal(a.samples, b.samples) and np.array_equal(a.x0, b.x0)
               for a, b in zip(instances, again, strict=True))


def test_grids_are_checked():
    assert set(QUICK_GRID.points) <= set(FULL_GRID.points)
    assert len(FULL_GRID.points) == 32
    with pytest.raises(InvalidParameterError, match="horizons"):
        ScalingGrid(horizons=(10, 0))
    with pytest.raises(InvalidParameterError, match="steps"):
        ScalingGrid(steps=1)


def test_the_goal_family_keeps_the_reference_inside_the_arena():
    straight = make_instances(30, 3, 80, np.random.default_rng(4), n_samples=20)
    goal = make_instances(30, 3, 80, np.random.default_rng(4), n_samples=20, family="goal")
    assert max(i.reference_states[:, 0].max() for i in straight) > 20.0  # runs far out
    assert max(i.reference_states[1:, 0].max() for i in goal) <= 4.5 + 1e-12
    # the same draws: the first step of each family starts from the same state
    assert np.array_equal(straight[0].x0, goal[0].x0)
    assert np.array_equal(straight[0].samples, goal[0].samples)
    with pytest.raises(InvalidParameterError, match="family"):
        make_instances(2, 1, 10, np.random.default_rng(0), n_samples=5, family="curvy")

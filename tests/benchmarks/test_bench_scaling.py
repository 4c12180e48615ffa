"""``safe-nav bench --scaling``: a smoke test on a tiny grid, and the pieces it is built of."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from agents.cli.main import main
from benchmarks.scaling import (
    FULL_GRID,
    QUICK_GRID,
    ScalingGrid,
    cvxpy_filter_class,
    make_scaling_instances,
)
from filters import InvalidParameterError


def test_bench_scaling_quick_runs_and_writes_table_csv_and_plot(tmp_path, capsys):
    code = main(["bench", "--scaling", "--quick", "--obstacles", "1", "3", "--horizons", "5",
                 "--samples", "20", "--steps", "6", "--output", str(tmp_path), "--no-policy"])
    assert code == 0
    out = capsys.readouterr().out
    assert "| obstacles | T | N_s | halfspaces | QP | step | CVXPY QP |" in out
    assert "| 1 | 5 | 20 |" in out and "| 3 | 5 | 20 |" in out
    assert ("per QP CPU clarabel / piqp | per QP iterations clarabel / piqp | "
            "CPU per iteration µs clarabel / piqp |") in out
    assert "recovery QP alone riccati (iterations, µs per iteration) |" in out
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
        # the hard QP alone (clarabel, piqp) and the recovery QP alone (riccati)
        for name in ("clarabel", "piqp", "riccati"):
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
    instances = make_scaling_instances(40, 3, 10, 50, rng)
    assert len(instances) == 40 and instances[0].new_episode
    assert instances[0].samples.shape == (3, 50, 10, 2)
    assert instances[0].reference_states.shape == (11, 4)
    # the ego reference passes within 1 m of a predicted obstacle on some steps
    closest = min(
        np.min(np.linalg.norm(i.samples.mean(axis=1) - i.reference_states[None, 1:, :2], axis=-1))
        for i in instances)
    assert closest < 1.0
    again = make_scaling_instances(40, 3, 10, 50, np.random.default_rng(0))
    assert all(np.array_equal(a.samples, b.samples) and np.array_equal(a.x0, b.x0)
               for a, b in zip(instances, again, strict=True))


def test_grids_and_the_reference_class():
    assert set(QUICK_GRID.points) <= set(FULL_GRID.points)
    assert len(FULL_GRID.points) == 32
    assert callable(getattr(cvxpy_filter_class(), "solve", None))
    with pytest.raises(InvalidParameterError, match="horizons"):
        ScalingGrid(horizons=(10, 0))
    with pytest.raises(InvalidParameterError, match="steps"):
        ScalingGrid(steps=1)


def test_the_goal_family_keeps_the_reference_inside_the_arena():
    straight = make_scaling_instances(30, 3, 80, 20, np.random.default_rng(4))
    goal = make_scaling_instances(30, 3, 80, 20, np.random.default_rng(4), family="goal")
    assert max(i.reference_states[:, 0].max() for i in straight) > 20.0  # runs far out
    assert max(i.reference_states[1:, 0].max() for i in goal) <= 4.5 + 1e-12
    # the same draws: the first step of each family starts from the same state
    assert np.array_equal(straight[0].x0, goal[0].x0)
    assert np.array_equal(straight[0].samples, goal[0].samples)
    with pytest.raises(InvalidParameterError, match="family"):
        make_scaling_instances(2, 1, 10, 5, np.random.default_rng(0), family="curvy")


def _point(n_obstacles: int, horizon: int, iterations: float, per_iteration_us: float,
           wall_factor=lambda horizon: 1.0):
    """A stand-in for a ScalingPoint with the fields ``_sparse_growth`` reads (wall time:
    the CPU time times ``wall_factor(T)``)."""
    from types import SimpleNamespace

    fields = {"n_obstacles": n_obstacles, "horizon": horizon, "n_samples": 100}
    for name in ("clarabel", "piqp", "riccati"):
        fields[f"{name}_per_qp_iterations"] = iterations
        fields[f"{name}_per_iteration_us"] = per_iteration_us
        fields[f"{name}_per_qp_cpu_ms"] = 1e-3 * iterations * per_iteration_us
        fields[f"{name}_per_qp_ms"] = wall_factor(horizon) * fields[f"{name}_per_qp_cpu_ms"]
    return SimpleNamespace(**fields)


def test_sparse_growth_splits_the_time_ratio_into_iterations_and_work_per_iteration():
    from benchmarks.suite import _sparse_growth

    # 3 obstacles: work per iteration linear in T, iterations constant (CPU time 4x,
    # slope 1); 10 obstacles: iterations 8 -> 16 on top (8x, slope 1.5). T = 10 is left
    # out. The wall time waits on a busy machine: 1.5x the CPU time at T = 80 only.
    def busy(horizon: int) -> float:
        return 1.5 if horizon == 80 else 1.0

    points = [_point(3, t, 8.0, t, busy) for t in (10, 20, 40, 80)]
    points += [_point(10, t, 8.0 * (t / 20) ** 0.5, t, busy) for t in (20, 40, 80)]
    line = _sparse_growth(points)
    assert "T = 80 over T = 20 (horizon ratio 4" in line
    assert "medians over 2 obstacle counts x N_s" in line
    # medians of {6, 12}, {4, 8}, {1, 2}, {4, 4}
    expected = ("wall time 9.00x (range 6.00x to 12.00x); CPU time 6.00x (range 4.00x to "
                "8.00x), its factors: iterations 1.50x (range 1.00x to 2.00x), CPU time per "
                "iteration 4.00x (range 4.00x to 4.00x); log-log slope over T in "
                "[20, 40, 80]: wall ")
    assert f"clarabel: {expected}" in line and f"piqp: {expected}" in line
    assert f"riccati: {expected}" in line
    # CPU slopes {1, 1.5}; the wall slopes are larger
    assert line.count("CPU 1.25 (range 1.00 to 1.50)") == 3
    wall_slope = float(line.split("wall ")[-1].split(" ")[0])
    assert wall_slope > 1.25
    assert "needs two horizons" in _sparse_growth([_point(3, 10, 8, 10), _point(3, 20, 8, 20)])


def test_interleaved_growth_measures_every_backend_on_its_own_qp():
    from benchmarks.growth import BACKENDS, benchmark_growth, format_growth

    ratios = benchmark_growth(3, 20, short=5, long=10, steps=4, repeats=1)
    assert [(r.backend, r.qp) for r in ratios] == list(BACKENDS.items())
    for r in ratios:
        assert r.short_ms > 0 and r.long_ms > 0 and r.short_iterations >= 1
        assert r.ratio == pytest.approx(r.long_ms / r.short_ms)
        assert r.per_iteration_ratio > 0
    text = format_growth(ratios)
    assert "T = 5 and T = 10 solved alternately" in text and "riccati (recovery QP)" in text
    assert "needs two horizons" in format_growth([])
    with pytest.raises(InvalidParameterError, match="short < long"):
        benchmark_growth(3, 20, short=10, long=10)
    with pytest.raises(InvalidParameterError, match="repeats"):
        benchmark_growth(3, 20, short=5, long=10, repeats=0)

"""``safe-nav bench --scaling``: the filter step on obstacles x horizon x samples, against CVXPY.

For every grid point ``(n_obstacles, T, N_s)`` (default: {1, 3, 10, 20} x {10, 20,
40, 80} x {100, 1000}) the same recorded instances (:func:`benchmarks.filter_qp.make_instances`
with ``N_s`` prediction samples) are solved by

* ours: :func:`filters.safe_halfspaces` (DR-CVaR, the paper's defaults) on the samples,
  then :meth:`filters.MPCSafetyFilter.solve` (``backend="auto"``: DAQP for the hard QP,
  DAQP or Clarabel for the recovery QP by size; the point says which); the *step* is
  their sum, what a control loop pays;
* the reference: the same QP in CVXPY, built once with Parameters (DPP) and compiled
  by its first solve, which is timed apart;
* each explicit back end (``"daqp"``, ``"clarabel"``), and how far their inputs are
  apart; then Clarabel's hard QP alone at every step ("per QP": one kind of QP at every
  size), with its median interior-point iterations, its median CPU time per iteration
  (``time.thread_time``) and the share of hard QPs it solved.

With the ``"straight"`` family (the default) the reference runs on at 1.5 m/s, 24 m at
T = 80, far outside the [-5, 5] m arena, and so do the constant-velocity predictions:
most long-horizon QPs are infeasible and their recovery QPs violate hundreds of rows.
The ``"goal"`` family stops the reference at x = 4.5 m: the QPs a real planner sends.
Every number is a median over the steps of one run; the ratios compare numbers of
the same run.
"""

from __future__ import annotations

import csv
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.filter_qp import (
    RADIUS,
    TS,
    agreement,
    double_integrator,
    filter_kwargs,
    make_instances,
    max_input_gap,
    solver_passes,
)
from benchmarks.timing import clock, clock_cpu, counts, machine, median, p90
from filters import Disc, MPCSafetyFilter, safe_halfspaces
from filters._validation import integer_at_least
from filters.errors import InvalidParameterError
from filters.mpc.result import StepData


@dataclass(frozen=True)
class ScalingGrid:
    """The grid of problem sizes, and how many filter steps are timed at each point."""

    obstacles: tuple[int, ...] = (1, 3, 10, 20)
    horizons: tuple[int, ...] = (10, 20, 40, 80)
    samples: tuple[int, ...] = (100, 1000)
    steps: int = 100

    def __post_init__(self) -> None:
        for name in ("obstacles", "horizons", "samples"):
            if not getattr(self, name):
                raise InvalidParameterError(f"ScalingGrid.{name} must not be empty")
            for value in getattr(self, name):
                integer_at_least(f"ScalingGrid.{name}", value)
        integer_at_least("ScalingGrid.steps", self.steps, low=2)

    @property
    def points(self) -> list[tuple[int, int, int]]:
        """``(n_obstacles, T, N_s)`` in the order they are run."""
        return [(n, t, s) for n in self.obstacles for t in self.horizons for s in self.samples]


FULL_GRID = ScalingGrid()
"""The issue's grid: {1, 3, 10, 20} obstacles x T in {10, 20, 40, 80} x N_s in {100, 1000}."""

QUICK_GRID = ScalingGrid(obstacles=(1, 3, 10), horizons=(10, 40), samples=(100,), steps=30)
"""A subset that runs in well under a minute."""


def benchmark_point(n_obstacles: int, horizon: int, n_samples: int, *, steps: int = 100,
                    seed: int = 0, family: str = "straight") -> dict:
    """One grid point: a row of the CSV (times in ms, medians over ``steps`` filter steps).

    ``ratio`` is CVXPY's QP over our whole step, ``qp_ratio`` over our QP alone;
    ``agreement`` the share of steps with the same status; the input differences are in
    m/s² over the steps both solved optimally.
    """
    rng = np.random.default_rng([seed, n_obstacles, horizon, n_samples])
    instances = make_instances(steps, n_obstacles, horizon, rng, n_samples=n_samples,
                               family=family)
    A, B, C = double_integrator(TS)
    kwargs = filter_kwargs(horizon, n_obstacles)
    shapes = {"ego_shape": Disc(RADIUS), "obstacle_shapes": [Disc(RADIUS)] * n_obstacles}
    halfspace_ms = np.array([clock(safe_halfspaces, i.reference_states[1:, :2], i.samples,
                                   risk="dr_cvar", ego_velocity=i.x0[2:], **shapes)[1]
                             for i in instances])
    solves, ours = solver_passes(A, B, C, kwargs, instances)
    clarabel = MPCSafetyFilter(A, B, C, backend="clarabel", **kwargs)._primary
    per_qp = []  # Clarabel's hard QP alone, the same QP at every step
    zero_inputs = np.zeros((horizon, B.shape[1]))
    for step in instances:
        data = StepData(step.x0, step.reference_states[1:], zero_inputs,
                        np.asarray(step.halfspaces.normals), np.asarray(step.halfspaces.offsets))
        solution, wall, cpu = clock_cpu(clarabel.solve, data, cpu=time.thread_time)
        per_qp.append((wall, cpu, solution.iterations, solution.found))
    wall, cpu, iterations, solved = np.array(per_qp, dtype=float).T
    step_ms = halfspace_ms + solves["ours"].ms
    qp, step, cvxpy = (median(v) for v in (solves["ours"].ms, step_ms, solves["cvxpy"].ms))
    recovery = ours.recovery_backend
    return {
        "n_obstacles": n_obstacles, "horizon": horizon, "n_samples": n_samples,
        "steps": len(instances), "halfspaces_ms": median(halfspace_ms), "qp_ms": qp,
        "step_ms": step, "step_p90_ms": p90(step_ms), "cvxpy_ms": cvxpy,
        "cvxpy_compile_ms": solves["cvxpy"].first_ms, "ratio": cvxpy / step,
        "qp_ratio": cvxpy / qp,
        "agreement": agreement(solves["ours"], solves["cvxpy"]),
        "max_input_difference": max_input_gap(solves["ours"].results, solves["cvxpy"].results),
        "statuses": counts((r.status.value for r in solves["ours"].results), "{}:{}", " "),
        "backend": ours.backend if recovery in (None, ours.backend)
        else f"{ours.backend}/{recovery}",
        "daqp_qp_ms": median(solves["daqp"].ms), "clarabel_qp_ms": median(solves["clarabel"].ms),
        "daqp_clarabel_difference": max_input_gap(solves["daqp"].results,
                                                  solves["clarabel"].results),
        "clarabel_per_qp_ms": median(wall), "family": family,
        "clarabel_per_qp_cpu_ms": median(cpu), "clarabel_per_qp_iterations": median(iterations),
        "clarabel_per_iteration_us": median(1e3 * cpu / np.maximum(iterations, 1.0)),
        "clarabel_per_qp_solved": float(np.mean(solved)),
    }


def format_scaling_table(points: Sequence[dict]) -> str:
    """The ratio table in markdown (medians in ms; ratios of the same run)."""
    lines = ["| obstacles | T | N_s | halfspaces | QP | step | CVXPY QP | CVXPY / step | "
             "CVXPY / QP | auto picks | QP daqp | QP clarabel | per QP clarabel (CPU, "
             "iterations, CPU µs per iteration) | hard QPs solved (clarabel) | max abs "
             "u_daqp - u_clarabel | statuses (ours) | same status |", "|" + "---|" * 16]
    for p in points:
        lines.append(
            "| {n_obstacles} | {horizon} | {n_samples} | {halfspaces_ms:.3f} | {qp_ms:.3f} | "
            "{step_ms:.3f} | {cvxpy_ms:.2f} | {ratio:.1f}x | {qp_ratio:.1f}x | {backend} | "
            "{daqp_qp_ms:.3f} | {clarabel_qp_ms:.3f} | {clarabel_per_qp_ms:.3f} "
            "({clarabel_per_qp_cpu_ms:.3f}, {clarabel_per_qp_iterations:.0f}, "
            "{clarabel_per_iteration_us:.1f}) | {solved:.0f}% | {daqp_clarabel_difference:.1e}"
            " | {shown} | {same:.0f}% |".format(
                **p, solved=100 * p["clarabel_per_qp_solved"], same=100 * p["agreement"],
                shown=", ".join(s.replace(":", " ") for s in p["statuses"].split())))
    return "\n".join(lines)


def plot_scaling(points: Sequence[dict], path: str | Path) -> Path:
    """Log-log plot of time against problem size, saved to ``path`` (PNG/SVG/PDF).

    Left: CVXPY's QP (dashed), our whole step (solid) and our QP (dotted) against the
    horizon ``T``, one colour per obstacle count (at the smallest ``N_s``). Right: the
    halfspaces against the number of samples processed, ``n_obstacles * T * N_s``, with
    a slope-1 guide (linear work) through the larger half of the points.
    """
    from agents.evaluation.plots import pyplot, save_figure

    plt = pyplot()
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    n_samples = min(p["n_samples"] for p in points)
    colour = {n: f"C{i}" for i, n in enumerate(sorted({p["n_obstacles"] for p in points}))}
    for n in colour:
        row = sorted((p for p in points if p["n_obstacles"] == n and p["n_samples"] == n_samples),
                     key=lambda p: p["horizon"])
        for key, line, marker in (("cvxpy_ms", "--", "s"), ("step_ms", "-", "o"),
                                  ("qp_ms", ":", ".")):
            left.plot([p["horizon"] for p in row], [p[key] for p in row], line, color=colour[n],
                      marker=marker, label=f"{n} obstacle{'s' if n != 1 else ''}"
                      if key == "step_ms" else None)
    horizons = sorted({p["horizon"] for p in points})
    left.set(xscale="log", yscale="log", xlabel="horizon T (steps)",
             ylabel="median time per filter step (ms)", title=f"CVXPY QP compiled once (--), "
             f"our step (—), our QP (··); N_s = {n_samples}")
    left.set_xticks(horizons, [str(h) for h in horizons])
    left.minorticks_off()
    work = np.array([p["n_obstacles"] * p["horizon"] * p["n_samples"] for p in points], float)
    times = np.array([p["halfspaces_ms"] for p in points])
    right.scatter(work, times, c=[colour[p["n_obstacles"]] for p in points], s=18)
    large = work >= np.median(work)  # fixed costs dominate the small sizes
    guide = np.array([work.min(), work.max()])
    right.plot(guide, float(np.median(times[large] / work[large])) * guide, "k--", lw=1,
               label="slope 1 (linear work)")
    right.set(xscale="log", yscale="log", xlabel="samples processed, n_obstacles × T × N_s",
              ylabel="median time of all halfspaces of a step (ms)",
              title="DR-CVaR halfspaces: time against work")
    for axes, corner in ((left, "lower right"), (right, "upper left")):
        axes.legend(fontsize=7, loc=corner)
        axes.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)


def run_scaling(grid: ScalingGrid = FULL_GRID, *, seed: int = 0,
                output: str | Path | None = None, plot: bool = True, policy: bool = True,
                family: str = "straight") -> str:
    """``safe-nav bench --scaling``: the scaling table (markdown), CSV and log-log plot.

    ``output``: folder for ``scaling.csv``, ``scaling.md`` and (``plot``) ``scaling.png``;
    ``None`` writes nothing. ``policy`` also times the policy forward pass and the
    roll-out reference (SB3 against :class:`agents.NumpyPolicy`). ``family``: one of
    :data:`benchmarks.filter_qp.FAMILIES`. Returns the printed report.
    """
    points = []
    for n_obstacles, horizon, n_samples in grid.points:
        point = benchmark_point(n_obstacles, horizon, n_samples, steps=grid.steps, seed=seed,
                                family=family)
        print(f"  obstacles {n_obstacles:>2}, T {horizon:>2}, N_s {n_samples:>4}: step "
              f"{point['step_ms']:.3f} ms, CVXPY {point['cvxpy_ms']:.3f} ms "
              f"({point['ratio']:.1f}x)", flush=True)
        points.append(point)
    ratios, qp_ratios = (np.array([p[key] for p in points]) for key in ("ratio", "qp_ratio"))
    work = np.array([p["n_obstacles"] * p["horizon"] * p["n_samples"] for p in points], float)
    per_sample_ns = 1e6 * np.array([p["halfspaces_ms"] for p in points]) / work
    parts = [
        f"{machine()}; grid obstacles {list(grid.obstacles)} x T {list(grid.horizons)} x N_s "
        f"{list(grid.samples)}, {grid.steps} steps per point; instances {family!r}; medians "
        "in ms; DR-CVaR; CVXPY = the same QP built once with Parameters (Clarabel), first "
        "compile excluded",
        format_scaling_table(points),
        f"CVXPY QP / our QP (MPCSafetyFilter.solve against the same QP, the issue's "
        f"comparison): lowest {qp_ratios.min():.1f}x, median {np.median(qp_ratios):.1f}x; "
        f"{int((qp_ratios >= 10).sum())} of {len(points)} points >= 10x (the issue's target)",
        f"CVXPY QP / our whole step (halfspaces + QP, which CVXPY's side does not compute): "
        f"lowest {ratios.min():.1f}x, median {np.median(ratios):.1f}x; "
        f"{int((ratios >= 10).sum())} of {len(points)} points >= 10x",
        f"halfspaces per sample processed (n x T x N_s): "
        f"{per_sample_ns[int(np.argmax(work))]:.1f} ns at the largest point, "
        f"{per_sample_ns.min():.1f} to {per_sample_ns.max():.1f} ns over the grid (fixed "
        "costs dominate the small points)",
    ]
    if policy:
        from benchmarks.policy import (
            benchmark_numpy_policy,
            benchmark_rollout_reference,
            format_rollout_reference,
        )

        parts += [benchmark_numpy_policy(seed=seed).format(),
                  format_rollout_reference(benchmark_rollout_reference(seed=seed))]
    report = "\n\n".join(parts)
    if output is not None:
        folder = Path(output)
        folder.mkdir(parents=True, exist_ok=True)
        with (folder / "scaling.csv").open("w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(points[0]))
            writer.writeheader()
            writer.writerows(points)
        (folder / "scaling.md").write_text(report + "\n")
        written = [folder / "scaling.csv", folder / "scaling.md"]
        if plot:
            written.append(plot_scaling(points, folder / "scaling.png"))
        report += "\n\nwrote " + ", ".join(map(str, written))
    return report

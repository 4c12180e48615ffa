"""How the filter step scales: obstacles x horizon x samples, ours against CVXPY compiled once.

For every grid point ``(n_obstacles, T, N_s)`` (default: {1, 3, 10, 20} x {10, 20,
40, 80} x {100, 1000}) the same recorded instances are solved by

* ours: :func:`filters.safe_halfspaces` (DR-CVaR, the paper's defaults) on the ``N_s``
  prediction samples, then :meth:`filters.MPCSafetyFilter.solve` (built once per grid
  point), timed separately; the *step* is their sum, what a control loop pays;
* the reference: the same QP (the same halfspaces) in CVXPY, built once with
  Parameters (DPP) and compiled by its first solve, which is timed apart.

Instances are made as in :mod:`benchmarks.filter_qp`: the paper's double
integrator (Ts = 0.2 s) crosses the arena from the left at 1.5 m/s with a
straight-line reference while obstacles start ahead of it with random headings
and speeds up to 1 m/s, so that they cross its path and some halfspace rows are
active. Beyond 3 obstacles their starting area widens with their number (see
:func:`obstacle_area`) so that each keeps about as much room. Predictions are the
nominal constant-velocity positions plus N(0, 0.01 I) samples at each step (the
paper's model). The fast filter drives the ego, so the episodes have active rows,
the occasional infeasible step and the fallbacks that follow; an episode ends at
the far side, after 40 steps, on a collision, or when the filter had to brake (as
an environment episode would end). The statuses are reported with the times.

Two instance families (``family=``):

* ``"straight"`` (the default, the grid issue 12 measured): the reference runs on at
  1.5 m/s for the whole horizon, 24 m at T = 80, far outside the [-5, 5] m arena, and
  the constant-velocity obstacle predictions leave it too; most long-horizon QPs are
  then infeasible (the recovery QP is solved too), and their recovery QPs violate
  hundreds of rows;
* ``"goal"``: the same episodes, but the reference stops at a goal inside the arena
  (x = 4.5 m on the ego's lane): the long-horizon QPs a real planner would send.

Ours is the default ``backend="auto"`` (DAQP for the hard QP; DAQP or Clarabel for the
recovery QP, by size; the point reports which); each explicit back end (``"daqp"``,
``"clarabel"``) then solves
the same recorded halfspaces in a pass of its own, so that the table shows them both
and how far their inputs are apart; Clarabel then also times its hard QP alone at every
step, in one more pass ("per QP": one kind of QP at every size), with its median
interior-point iterations, its median time per iteration (CPU time of the thread,
``time.thread_time``) and the share of hard QPs it solved. The filters are timed in
separate passes over the same instances (interleaved, each evicts the other's data from
the caches). Every number is a median over the steps of one run; the ratios compare
numbers of the same run.
"""

from __future__ import annotations

import csv
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.filter_qp import (
    RADIUS,
    TS,
    crossing_start,
    double_integrator,
    filter_kwargs,
    max_input_gap,
    straight_reference,
    timed_solves,
)
from filters import Disc, FilterStatus, MPCSafetyFilter, safe_halfspaces
from filters._validation import integer_at_least
from filters.errors import InvalidParameterError
from filters.mpc.result import StepData

__all__ = [
    "FAMILIES",
    "FULL_GRID",
    "QUICK_GRID",
    "ScalingGrid",
    "ScalingPoint",
    "benchmark_point",
    "benchmark_scaling",
    "format_scaling_table",
    "make_scaling_instances",
    "obstacle_area",
    "plot_scaling",
    "write_scaling_csv",
]

PREDICTION_STD = 0.1  # m per axis, the paper's N(0, 0.01 I) prediction noise
GOAL_X = 4.5  # m, where the "goal" reference stops
#: Instance families of :func:`make_scaling_instances` (module docstring).
FAMILIES = ("straight", "goal")
EPISODE_STEPS = 40  # steps per crossing episode (8 s)


@dataclass(frozen=True)
class ScalingGrid:
    """The grid of problem sizes, and how many filter steps are timed at each point."""

    obstacles: tuple[int, ...] = (1, 3, 10, 20)
    horizons: tuple[int, ...] = (10, 20, 40, 80)
    samples: tuple[int, ...] = (100, 1000)
    steps: int = 100

    def __post_init__(self) -> None:
        for name in ("obstacles", "horizons", "samples"):
            values = getattr(self, name)
            if not values:
                raise InvalidParameterError(f"ScalingGrid.{name} must not be empty")
            for value in values:
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


@dataclass(frozen=True)
class Instance:
    """One control step: state, reference (T+1, 4) and prediction samples (n, N_s, T, 2)."""

    x0: np.ndarray
    reference_states: np.ndarray
    samples: np.ndarray
    new_episode: bool


def obstacle_area(n_obstacles: int) -> tuple[float, float, float]:
    """``(x_low, x_high, y_half)`` in m: obstacles start in ``[x_low, x_high] x [-y_half, y_half]``.

    :mod:`benchmarks.filter_qp`'s ``[-2, 3] x [-1.5, 1.5]`` up to 3 obstacles,
    widened beyond so that each obstacle keeps about as much room.
    """
    scale = max(1.0, n_obstacles / 3.0)
    return -2.0, min(4.5, -2.0 + 5.0 * np.sqrt(scale)), min(4.5, 1.5 * np.sqrt(scale))


def make_scaling_instances(
    n_steps: int, n_obstacles: int, horizon: int, n_samples: int, rng: np.random.Generator,
    *, family: str = "straight",
) -> list[Instance]:
    """Crossing episodes with the fast DR-CVaR filter in the loop; record each step's data.

    The episode set-up is :func:`benchmarks.filter_qp.make_instances`'s, with
    real prediction samples instead of its fixed risk margins, and an obstacle area
    that widens with the number of obstacles (see the module docstring). ``family`` is
    one of :data:`FAMILIES`; both draw the same random numbers.

    Raises
    ------
    InvalidParameterError
        If ``family`` is not one of :data:`FAMILIES`.
    """
    if family not in FAMILIES:
        raise InvalidParameterError(f"family must be one of {FAMILIES}, got {family!r}")
    A, B, C = double_integrator(TS)
    mpc = MPCSafetyFilter(A, B, C, **filter_kwargs(horizon, n_obstacles))
    ego_shape, shapes = Disc(RADIUS), [Disc(RADIUS)] * n_obstacles
    steps = np.arange(1, horizon + 1)[:, None] * TS  # (T, 1), s
    instances: list[Instance] = []
    new_episode = True
    while len(instances) < n_steps:
        if new_episode:
            mpc.reset()
            x, obstacles, velocities = crossing_start(rng, n_obstacles, obstacle_area(n_obstacles))
            lane = x[1]
            step_in_episode = 0
        reference_states = straight_reference(x, lane, horizon,
                                              stop_x=GOAL_X if family == "goal" else None)
        nominal = obstacles[:, None, :] + velocities[:, None, :] * steps[None]  # (n, T, 2)
        samples = nominal[:, None] + PREDICTION_STD * rng.standard_normal(
            (n_obstacles, n_samples, horizon, 2))
        instances.append(Instance(x.copy(), reference_states, samples, new_episode))
        hs = safe_halfspaces(reference_states[1:, :2], samples, ego_shape=ego_shape,
                             obstacle_shapes=shapes, risk="dr_cvar", ego_velocity=x[2:])
        result = mpc.solve(x, reference_states, hs)
        x = A @ x + B @ result.inputs[0]
        obstacles = obstacles + TS * velocities
        step_in_episode += 1
        clearance = np.min(np.linalg.norm(obstacles - x[:2], axis=-1), initial=np.inf)
        # An episode ends as the environment's do: at the goal side, on a collision, or
        # (here) when the filter had to brake; so the steps are those of a working loop.
        new_episode = (step_in_episode >= EPISODE_STEPS or x[0] > 4.5
                       or clearance < 2 * RADIUS or result.status == FilterStatus.BRAKE)
    return instances


@dataclass(frozen=True)
class ScalingPoint:
    """Medians (ms) at one grid point, ours and CVXPY on the same instances."""

    n_obstacles: int
    horizon: int
    n_samples: int
    steps: int
    halfspaces_ms: float
    qp_ms: float
    step_ms: float  # halfspaces + QP, per step
    step_p90_ms: float
    cvxpy_ms: float  # the same QP in CVXPY compiled once (Clarabel), per step
    cvxpy_compile_ms: float  # its first solve (canonicalisation), not in cvxpy_ms
    ratio: float  # cvxpy_ms / step_ms: CVXPY's QP alone against our whole step
    qp_ratio: float  # cvxpy_ms / qp_ms
    agreement: float  # share of steps with the same status
    max_input_difference: float  # m/s^2, over the steps where both were optimal
    statuses: dict[str, int] = field(default_factory=dict)  # ours
    backend: str = ""  # what backend="auto" picked (hard QP, and recovery QP if other)
    daqp_qp_ms: float = float("nan")  # backend="daqp", QP (solve call) median
    clarabel_qp_ms: float = float("nan")  # backend="clarabel", QP median
    daqp_clarabel_difference: float = float("nan")  # max |u_daqp - u_clarabel|, both optimal
    clarabel_per_qp_ms: float = float("nan")  # backend="clarabel": its hard QP alone
    family: str = "straight"  # instance family (FAMILIES)
    clarabel_per_qp_cpu_ms: float = float("nan")  # its hard QP alone: CPU time of the thread
    clarabel_per_qp_iterations: float = float("nan")  # its hard QP alone: median iterations
    clarabel_per_iteration_us: float = float("nan")  # median of (CPU time / iterations), µs
    clarabel_per_qp_solved: float = float("nan")  # share of the hard QPs it solved

    def as_row(self) -> dict:
        """Flat ``dict`` for CSV (statuses as ``name:count`` pairs)."""
        row = asdict(self)
        row["statuses"] = " ".join(f"{k}:{v}" for k, v in sorted(self.statuses.items()))
        return row


def benchmark_point(
    n_obstacles: int, horizon: int, n_samples: int, *, steps: int = 100, seed: int = 0,
    family: str = "straight",
) -> ScalingPoint:
    """Time halfspaces, QP, step and the CVXPY reference at one grid point.

    Parameters
    ----------
    n_obstacles, horizon, n_samples
        Obstacles, MPC horizon ``T`` and prediction samples ``N_s`` per obstacle and step.
    steps
        Filter steps (recorded instances) timed.
    seed
        Seed of the ``numpy.random.Generator`` that draws the episodes and samples.
    family
        Instance family, one of :data:`FAMILIES`.
    """
    rng = np.random.default_rng([seed, n_obstacles, horizon, n_samples])
    instances = make_scaling_instances(steps, n_obstacles, horizon, n_samples, rng,
                                       family=family)
    A, B, C = double_integrator(TS)
    kwargs = filter_kwargs(horizon, n_obstacles)
    ego_shape, shapes = Disc(RADIUS), [Disc(RADIUS)] * n_obstacles

    def halfspaces(instance: Instance) -> Any:
        return safe_halfspaces(instance.reference_states[1:, :2], instance.samples,
                               ego_shape=ego_shape, obstacle_shapes=shapes, risk="dr_cvar",
                               ego_velocity=instance.x0[2:])

    ours = MPCSafetyFilter(A, B, C, **kwargs)  # backend="auto"
    for instance in instances[: min(20, len(instances))]:  # build the lazily made QPs
        if instance.new_episode:
            ours.reset()
        ours.solve(instance.x0, instance.reference_states, halfspaces(instance))
    halfspace_ms, qp_ms, step_ms, recorded, results = [], [], [], [], []
    for instance in instances:
        if instance.new_episode:
            ours.reset()
        begin = time.perf_counter()
        hs = halfspaces(instance)
        middle = time.perf_counter()
        result = ours.solve(instance.x0, instance.reference_states, hs)
        end = time.perf_counter()
        halfspace_ms.append(1e3 * (middle - begin))
        qp_ms.append(1e3 * (end - middle))
        step_ms.append(1e3 * (end - begin))
        recorded.append(hs)
        results.append(result)
    problems = [(instance.new_episode, instance.x0, instance.reference_states, hs, None)
                for instance, hs in zip(instances, recorded, strict=True)]

    from filters import CVXPYSafetyFilter  # imports cvxpy: only when benchmarking

    reference = CVXPYSafetyFilter(A, B, C, **kwargs)
    begin = time.perf_counter()
    reference.solve(*problems[0][1:4])
    compile_ms = 1e3 * (time.perf_counter() - begin)
    cvxpy_ms, slow = timed_solves(reference, problems)
    statuses = Counter(result.status.value for result in results)
    same = sum(a.status == b.status for a, b in zip(results, slow, strict=True))

    backend_ms, backend_results = {}, {}
    for name in ("daqp", "clarabel"):
        explicit = MPCSafetyFilter(A, B, C, backend=name, **kwargs)
        backend_ms[name], backend_results[name] = timed_solves(explicit, problems)
    # Clarabel's hard QP alone, the same QP at every step, in a pass of its own.
    zero_inputs = np.zeros((horizon, B.shape[1]))
    per_qp = []
    for instance, hs in zip(instances, recorded, strict=True):
        step = StepData(instance.x0, instance.reference_states[1:], zero_inputs,
                        np.asarray(hs.normals), np.asarray(hs.offsets))
        begin, begin_cpu = time.perf_counter(), time.thread_time()
        solution = explicit._primary.solve(step)
        end_cpu, end = time.thread_time(), time.perf_counter()
        per_qp.append((1e3 * (end - begin), 1e3 * (end_cpu - begin_cpu),
                       solution.iterations, solution.found))

    step, qp, cvxpy_median = (float(np.median(v)) for v in (step_ms, qp_ms, cvxpy_ms))
    return ScalingPoint(
        n_obstacles=n_obstacles, horizon=horizon, n_samples=n_samples, steps=len(instances),
        halfspaces_ms=float(np.median(halfspace_ms)), qp_ms=qp, step_ms=step,
        step_p90_ms=float(np.percentile(step_ms, 90)), cvxpy_ms=cvxpy_median,
        cvxpy_compile_ms=compile_ms, ratio=cvxpy_median / step, qp_ratio=cvxpy_median / qp,
        agreement=same / len(instances), max_input_difference=max_input_gap(results, slow),
        statuses=dict(statuses), backend=_backend_label(ours),
        daqp_qp_ms=float(np.median(backend_ms["daqp"])),
        clarabel_qp_ms=float(np.median(backend_ms["clarabel"])),
        daqp_clarabel_difference=max_input_gap(backend_results["daqp"],
                                               backend_results["clarabel"]),
        **_per_qp_fields("clarabel", per_qp),
        family=family,
    )


def _per_qp_fields(name: str, timings: list[tuple[float, float, int, bool]]
                   ) -> dict[str, float]:
    """The :class:`ScalingPoint` fields of one back end's pass of single QPs.

    ``timings`` holds ``(wall time in ms, CPU time of the thread in ms, interior-point
    iterations, solved)`` per step; the time per iteration is each step's CPU time over
    its iterations (at least one).
    """
    keys = ("per_qp_ms", "per_qp_cpu_ms", "per_qp_iterations", "per_iteration_us",
            "per_qp_solved")
    if not timings:
        return {f"{name}_{key}": float("nan") for key in keys}
    table = np.array(timings, dtype=float)  # (steps, 4)
    wall, cpu, iterations, solved = table.T
    values = (np.median(wall), np.median(cpu), np.median(iterations),
              np.median(1e3 * cpu / np.maximum(iterations, 1.0)), np.mean(solved))
    return {f"{name}_{key}": float(value) for key, value in zip(keys, values, strict=True)}


def _backend_label(mpc: MPCSafetyFilter) -> str:
    """``"daqp"``, or ``"daqp/clarabel"`` when the recovery QP has another back end."""
    recovery = mpc.recovery_backend
    return mpc.backend if recovery in (None, mpc.backend) else f"{mpc.backend}/{recovery}"


def benchmark_scaling(
    grid: ScalingGrid = FULL_GRID, *, seed: int = 0, progress: bool = False,
    family: str = "straight",
) -> list[ScalingPoint]:
    """Run :func:`benchmark_point` at every point of ``grid`` (see the module docstring)."""
    points = []
    for n_obstacles, horizon, n_samples in grid.points:
        point = benchmark_point(n_obstacles, horizon, n_samples, steps=grid.steps, seed=seed,
                                family=family)
        if progress:
            print(f"  obstacles {n_obstacles:>2}, T {horizon:>2}, N_s {n_samples:>4}: step "
                  f"{point.step_ms:.3f} ms, CVXPY {point.cvxpy_ms:.3f} ms ({point.ratio:.1f}x)",
                  flush=True)
        points.append(point)
    return points


def format_scaling_table(points: Sequence[ScalingPoint]) -> str:
    """The ratio table in markdown (medians in ms; ratios of the same run)."""
    lines = [
        "| obstacles | T | N_s | halfspaces | QP | step | CVXPY QP | "
        "CVXPY / step | CVXPY / QP | auto picks | QP daqp | QP clarabel | "
        "per QP clarabel (CPU, iterations, CPU µs per iteration) | "
        "hard QPs solved (clarabel) | max abs u_daqp - u_clarabel | "
        "statuses (ours) | same status |",
        "|" + "---|" * 16,
    ]
    for p in points:
        statuses = ", ".join(f"{k} {v}" for k, v in sorted(p.statuses.items()))
        lines.append(
            f"| {p.n_obstacles} | {p.horizon} | {p.n_samples} | {p.halfspaces_ms:.3f} | "
            f"{p.qp_ms:.3f} | {p.step_ms:.3f} | {p.cvxpy_ms:.2f} | "
            f"{p.ratio:.1f}x | "
            f"{p.qp_ratio:.1f}x | {p.backend} | {p.daqp_qp_ms:.3f} | {p.clarabel_qp_ms:.3f} | "
            f"{p.clarabel_per_qp_ms:.3f} ({p.clarabel_per_qp_cpu_ms:.3f}, "
            f"{p.clarabel_per_qp_iterations:.0f}, {p.clarabel_per_iteration_us:.1f}) | "
            f"{100 * p.clarabel_per_qp_solved:.0f}% | "
            f"{p.daqp_clarabel_difference:.1e} | {statuses} | "
            f"{100 * p.agreement:.0f}% |"
        )
    return "\n".join(lines)


def write_scaling_csv(points: Sequence[ScalingPoint], path: str | Path) -> Path:
    """One row per grid point (the fields of :class:`ScalingPoint`)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=[f.name for f in fields(ScalingPoint)])
        writer.writeheader()
        for point in points:
            writer.writerow(point.as_row())
    return path


def plot_scaling(points: Sequence[ScalingPoint], path: str | Path) -> Path:
    """Log-log plot of time against problem size, saved to ``path`` (PNG/SVG/PDF).

    Left: our QP, our whole step and CVXPY's QP against the horizon ``T``, one colour
    per obstacle count (at the smallest ``N_s``). Right: the halfspaces against the
    number of samples processed, ``n_obstacles * T * N_s``, with a slope-1 guide
    (linear work) through the larger half of the points.
    """
    from agents.evaluation.plots import pyplot, save_figure

    plt = pyplot()
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    n_samples = min(p.n_samples for p in points)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for index, n_obstacles in enumerate(sorted({p.n_obstacles for p in points})):
        row = sorted((p for p in points if p.n_obstacles == n_obstacles
                      and p.n_samples == n_samples), key=lambda p: p.horizon)
        horizons = [p.horizon for p in row]
        colour = colours[index % len(colours)]
        left.plot(horizons, [p.cvxpy_ms for p in row], "--", color=colour, marker="s")
        left.plot(horizons, [p.step_ms for p in row], "-", color=colour, marker="o")
        left.plot(horizons, [p.qp_ms for p in row], ":", color=colour, marker=".")
    left.set(xscale="log", yscale="log", xlabel="horizon T (steps)",
             ylabel="median time per filter step (ms)",
             title=f"Filter step against the same QP in CVXPY (N_s = {n_samples} samples)")
    all_horizons = sorted({p.horizon for p in points})
    left.set_xticks(all_horizons, [str(h) for h in all_horizons])
    left.minorticks_off()
    obstacle_counts = sorted({p.n_obstacles for p in points})
    colour_key = [plt.Line2D([], [], color=colours[i % len(colours)], lw=6)
                  for i in range(len(obstacle_counts))]
    style_key = [plt.Line2D([], [], color="0.3", ls="--", marker="s"),
                 plt.Line2D([], [], color="0.3", ls="-", marker="o"),
                 plt.Line2D([], [], color="0.3", ls=":", marker=".")]
    styles = left.legend(style_key, ["CVXPY QP, compiled once", "our whole step (halfspaces + QP)",
                                     "our QP alone"], fontsize=7, loc="upper left")
    left.add_artist(styles)
    counts = [f"{n} obstacle{'s' if n != 1 else ''}" for n in obstacle_counts]
    left.legend(colour_key, counts, fontsize=7,
                loc="lower right")
    left.grid(True, which="both", alpha=0.3)
    work = np.array([p.n_obstacles * p.horizon * p.n_samples for p in points], dtype=float)
    times = np.array([p.halfspaces_ms for p in points])
    right.scatter(work, times, c=[colours[sorted({q.n_obstacles for q in points}).index(
        p.n_obstacles) % len(colours)] for p in points], s=18)
    guide = np.array([work.min(), work.max()])
    large = work >= np.median(work)  # fixed costs dominate the small sizes
    anchor = float(np.median(times[large] / work[large]))
    right.plot(guide, anchor * guide, "k--", lw=1, label="slope 1 (linear work)")
    right.set(xscale="log", yscale="log", xlabel="samples processed, n_obstacles × T × N_s",
              ylabel="median time of all halfspaces of a step (ms)",
              title="DR-CVaR halfspaces: time against work")
    right.legend([*colour_key, right.lines[-1]],
                 [*counts, "slope 1 (linear work)"],
                 fontsize=7, loc="upper left")
    right.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)

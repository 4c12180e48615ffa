"""Recorded filter steps, timed passes of each solver over them, and the QP benchmark.

:func:`make_instances` drives the paper's ego double integrator (Ts = 0.2 s) through
random crossing episodes: the ego starts at x = -4.5 m at 1.5 m/s on a lane
y ~ U(-1, 1) m with an obstacle-agnostic straight-line reference toward +x; the
obstacles start ahead of it (``[-2, 3] x [-1.5, 1.5]`` m up to 3 obstacles, widened
beyond, see :func:`_crossing_start`) with speeds U(0, 1) m/s in uniform directions, so
that they cross its path. Its halfspaces are either

* synthetic (``n_samples=None``): the normal from the ego reference to the nominal
  obstacle position, the offset of two 0.3 m discs plus a random margin U(0, 0.15) m per
  obstacle (a stand-in for the risk tightening: the realistic QP without the halfspace
  computation); or
* the DR-CVaR halfspaces (:func:`filters.safe_halfspaces`, the paper's defaults) of
  ``N_s`` prediction samples: the nominal constant-velocity positions plus
  N(0, 0.01 I) noise at each step.

The fast filter's first input drives the ego, so the episodes have active rows, the
occasional infeasible step and the fallbacks that follow; an episode ends after 40
steps (8 s), at the far side (x > 4.5 m), on a collision or when the filter braked.

:func:`timed_solves` then times one filter's ``solve`` over the recorded steps, in a
pass of its own (interleaved, each solver would evict the other's data from the
caches). :func:`benchmark_filter_qp` compares :class:`filters.mpc.MPCSafetyFilter`
(``backend="auto"``) with :class:`filters.CVXPYSafetyFilter` (the same QP built once
with Parameters, its first compile timed apart) on synthetic instances:

* the headline medians are over the steps where ours solved at least one QP (no
  reference inputs are given, so ``skip_feasible_reference`` never applies there);
* the recovery QP (``fallback="soft"``) was solved too on the steps that solved two
  QPs; the *constrained* steps are those whose QP took at least one iteration;
* a third pass of ours gives ``reference_inputs = 0`` (the same QP: zeros are the
  default), so ``skip_feasible_reference`` answers from the unconstrained minimiser
  when it is feasible.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from benchmarks.timing import clock, counts, median, p90
from filters import Disc, safe_halfspaces
from filters.errors import InvalidParameterError
from filters.mpc import FilterResult, FilterStatus, MPCSafetyFilter
from safe_nav_env.constants import ARENA_HALF_WIDTH, DT, EGO_RADIUS, EGO_START_SPEED
from safe_nav_env.dynamics import double_integrator

TS = DT  # s, sampling time of the paper
SPEED = EGO_START_SPEED  # m/s, ego reference speed
RADIUS = EGO_RADIUS  # m, ego and obstacle disc radii
INPUT_LIMIT = 5.0  # m/s^2 per axis
PREDICTION_STD = 0.1  # m per axis, the paper's N(0, 0.01 I) prediction noise
GOAL_X = 4.5  # m, where the "goal" reference stops
EPISODE_STEPS = 40  # steps per crossing episode (8 s)
#: Instance families: the reference runs straight on at 1.5 m/s for the whole horizon
#: (far outside the arena at long horizons), or stops at a goal x = 4.5 m on its lane.
FAMILIES = ("straight", "goal")


def filter_kwargs(horizon: int, n_obstacles: int) -> dict:
    """Constructor keywords shared by both filters (the authors' effective weights)."""
    return {"horizon": horizon, "Q": 4.0 * np.eye(4), "Q_terminal": 25.0 * np.eye(4),
            "R": np.eye(2), "input_bounds": (-INPUT_LIMIT, INPUT_LIMIT),
            "position_bounds": (-ARENA_HALF_WIDTH, ARENA_HALF_WIDTH),
            "n_obstacles": n_obstacles}


def straight_reference(x: np.ndarray, lane: float, horizon: int, *,
                       stop_x: float | None = None) -> np.ndarray:
    """Reference (T+1, 4) at 1.5 m/s along +x on the ego's lane; row 0 is ``x``.

    With ``stop_x`` (m) the reference stops there (zero velocity from then on).
    """
    reference = np.empty((horizon + 1, 4))
    reference[:, 0] = x[0] + SPEED * TS * np.arange(horizon + 1)
    reference[:, 1] = lane
    reference[:, 2:] = (SPEED, 0.0)
    if stop_x is not None:
        stopped = reference[:, 0] >= stop_x
        reference[stopped, 0] = max(stop_x, x[0])
        reference[stopped, 2] = 0.0
    reference[0] = x
    return reference


def _margin_halfspaces(reference_positions: np.ndarray, predicted: np.ndarray,
                       margins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normals from the ego reference to each prediction; offsets keep two discs apart."""
    direction = predicted - reference_positions[None]
    norm = np.linalg.norm(direction, axis=-1, keepdims=True)
    normals = direction / np.maximum(norm, 1e-9)
    normals[norm[..., 0] < 1e-9] = (1.0, 0.0)
    offsets = np.einsum("ktd,ktd->kt", normals, predicted) - 2 * RADIUS - margins[:, None]
    return normals, offsets


@dataclass(frozen=True)
class Instance:
    """One recorded filter step."""

    x0: np.ndarray  # (4,) state
    reference_states: np.ndarray  # (T+1, 4)
    halfspaces: Any  # (normals (k, T, 2), offsets (k, T)) or filters.Halfspaces
    new_episode: bool
    samples: np.ndarray | None = None  # (n, N_s, T, 2) prediction samples, if any
    reference_inputs: np.ndarray | None = None  # (T, 2), the planner's


def make_instances(n_steps: int, n_obstacles: int, horizon: int, rng: np.random.Generator, *,
                   n_samples: int | None = None, family: str = "straight") -> list[Instance]:
    """Crossing episodes with the fast filter in the loop; record each step (module docstring).

    ``n_samples=None``: synthetic halfspaces; else the DR-CVaR halfspaces of that many
    prediction samples. Both ``family`` values (:data:`FAMILIES`) draw the same numbers.

    Raises
    ------
    InvalidParameterError
        If ``family`` is not one of :data:`FAMILIES`.
    """
    if family not in FAMILIES:
        raise InvalidParameterError(f"family must be one of {FAMILIES}, got {family!r}")
    A, B, C = double_integrator(TS)
    mpc = MPCSafetyFilter(A, B, C, **filter_kwargs(horizon, n_obstacles))
    shapes = {"ego_shape": Disc(RADIUS), "obstacle_shapes": [Disc(RADIUS)] * n_obstacles}
    ahead = np.arange(1, horizon + 1)[:, None] * TS  # (T, 1), s
    instances: list[Instance] = []
    new_episode = True
    while len(instances) < n_steps:
        if new_episode:
            mpc.reset()
            x, obstacles, velocities = _crossing_start(rng, n_obstacles)
            lane, step = x[1], 0
            margins = rng.uniform(0.0, 0.15, n_obstacles) if n_samples is None else None
        reference = straight_reference(x, lane, horizon,
                                       stop_x=GOAL_X if family == "goal" else None)
        nominal = obstacles[:, None, :] + velocities[:, None, :] * ahead[None]  # (n, T, 2)
        samples = None
        if n_samples is None:
            halfspaces = _margin_halfspaces(reference[1:, :2], nominal, margins)
        else:
            samples = nominal[:, None] + PREDICTION_STD * rng.standard_normal(
                (n_obstacles, n_samples, horizon, 2))
            halfspaces = safe_halfspaces(reference[1:, :2], samples, risk="dr_cvar",
                                         ego_velocity=x[2:], **shapes)
        instances.append(Instance(x.copy(), reference, halfspaces, new_episode, samples))
        result = mpc.solve(x, reference, halfspaces)
        x = A @ x + B @ result.first_input
        obstacles = obstacles + TS * velocities
        step += 1
        clearance = np.min(np.linalg.norm(obstacles - x[:2], axis=-1), initial=np.inf)
        new_episode = (step >= EPISODE_STEPS or x[0] > 4.5 or clearance < 2 * RADIUS
                       or result.status == FilterStatus.BRAKE)
    return instances


def _crossing_start(rng: np.random.Generator, n_obstacles: int
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ego state (4,), obstacle positions and velocities (n, 2) of a new episode.

    The obstacles start in ``[-2, 3] x [-1.5, 1.5]`` m up to 3 obstacles, each side
    scaled by ``sqrt(n / 3)`` beyond (capped at 4.5 m), so that each obstacle keeps
    about as much room.
    """
    scale = np.sqrt(max(1.0, n_obstacles / 3.0))
    y_half = min(4.5, 1.5 * scale)
    x = np.array([-4.5, rng.uniform(-1.0, 1.0), SPEED, 0.0])
    obstacles = np.column_stack([rng.uniform(-2.0, min(4.5, -2.0 + 5.0 * scale), n_obstacles),
                                 rng.uniform(-y_half, y_half, n_obstacles)])
    speed = rng.uniform(0.0, 1.0, n_obstacles)
    heading = rng.uniform(0.0, 2.0 * np.pi, n_obstacles)
    return x, obstacles, speed[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])


@dataclass(frozen=True)
class Solves:
    """One filter's timed pass over the instances."""

    ms: np.ndarray  # wall time of each solve call, ms
    results: list[FilterResult]
    qp_solves: np.ndarray  # QPs solved at each step (0: answered without one)
    first_ms: float  # the very first solve, before the timed pass (CVXPY compiles there)


def timed_solves(mpc: MPCSafetyFilter, instances: Sequence[Instance], *,
                 zero_inputs: bool = False) -> Solves:
    """Solve every instance in turn with ``mpc`` (reset at each new episode), timed.

    A first pass over up to 20 instances builds what is made lazily and warms the
    caches. ``zero_inputs`` gives ``reference_inputs = 0`` instead of the instances' own.
    """
    def run(batch: Sequence[Instance]) -> list[tuple[float, FilterResult, int]]:
        rows = []
        for step in batch:
            if step.new_episode:
                mpc.reset()
            inputs = (np.zeros((len(step.reference_states) - 1, 2)) if zero_inputs
                      else step.reference_inputs)
            result, ms = clock(mpc.solve, step.x0, step.reference_states, step.halfspaces,
                               reference_inputs=inputs)
            rows.append((ms, result, mpc.last_qp_solves))
        return rows

    first_ms = run(instances[:20])[0][0]
    ms, results, solves = zip(*run(instances), strict=True)
    return Solves(np.array(ms), list(results), np.array(solves), first_ms)


def max_input_gap(first: Sequence[FilterResult], second: Sequence[FilterResult]) -> float:
    """Largest ``|u_first - u_second|`` (m/s²) over the steps both solved optimally (NaN: none)."""
    gaps = [float(np.max(np.abs(a.inputs - b.inputs)))
            for a, b in zip(first, second, strict=True)
            if a.status == b.status == FilterStatus.OPTIMAL]
    return max(gaps, default=float("nan"))


def solver_passes(A: np.ndarray, B: np.ndarray, C: np.ndarray, kwargs: dict,
                  instances: Sequence[Instance], *, zero_inputs: bool = False
                  ) -> tuple[dict[str, Solves], MPCSafetyFilter]:
    """Each filter's timed pass over ``instances``, and our filter (``backend="auto"``).

    Passes: ``"ours"`` (``backend="auto"``), ``"cvxpy"`` (:class:`filters.CVXPYSafetyFilter`:
    it never skips the QP), ``"daqp"`` and ``"clarabel"`` (explicit back ends) and, with
    ``zero_inputs``, ``"zero_inputs"``: ours again with ``reference_inputs = 0``.
    """
    from filters import CVXPYSafetyFilter  # imports cvxpy: only when benchmarking

    ours = MPCSafetyFilter(A, B, C, **kwargs)
    passes = {"ours": timed_solves(ours, instances),
              "cvxpy": timed_solves(CVXPYSafetyFilter(A, B, C, **kwargs), instances)}
    for name in ("daqp", "clarabel"):
        passes[name] = timed_solves(MPCSafetyFilter(A, B, C, backend=name, **kwargs), instances)
    if zero_inputs:
        passes["zero_inputs"] = timed_solves(MPCSafetyFilter(A, B, C, **kwargs), instances,
                                             zero_inputs=True)
    return passes, ours


def agreement(first: Solves, second: Solves) -> float:
    """Share of the steps where both passes gave the same status."""
    return float(np.mean([a.status == b.status
                          for a, b in zip(first.results, second.results, strict=True)]))


def format_passes(title: str, passes: dict[str, Solves], backend: str,
                  halfspace_ms: np.ndarray | None = None) -> str:
    """The report of :func:`solver_passes` (medians in ms); ``halfspace_ms`` per step, if
    the halfspaces were timed (our *step* is then halfspaces + QP)."""
    ours, cvxpy = passes["ours"], passes["cvxpy"]
    halfspaces = np.zeros(len(ours.ms)) if halfspace_ms is None else np.asarray(halfspace_ms)
    step = halfspaces + ours.ms
    qp = ours.qp_solves > 0
    constrained = qp & (np.array([r.iterations for r in ours.results]) > 0)
    step_qp, cvxpy_qp = median(step, qp), median(cvxpy.ms, qp)
    ours_c, cvxpy_c = median(step, constrained), median(cvxpy.ms, constrained)
    lines = [
        f"{title}, {len(step)} steps, medians:",
        "    ours: " + (f"halfspaces {median(halfspaces):.3f} ms + " if halfspace_ms is not None
                         else "") + f"QP {median(ours.ms):.3f} ms (solver calls "
        f"{median([1e3 * r.solve_time for r in ours.results], qp):.3f} ms where used) = step "
        f"{median(step):.3f} ms (p90 {p90(step):.3f} ms)",
        f"    CVXPY QP built once with Parameters (Clarabel): {median(cvxpy.ms):.3f} ms (p90 "
        f"{p90(cvxpy.ms):.3f} ms; first compile {cvxpy.first_ms:.0f} ms)",
        f"    ratio CVXPY QP / our whole step: {median(cvxpy.ms) / median(step):.1f}x   "
        "(target >= 10x, step < 1 ms)",
        f"    steps that needed a QP ({int(qp.sum())}; the others were answered by the "
        f"feasible-reference shortcut): ours {step_qp:.3f} ms, CVXPY {cvxpy_qp:.3f} ms, ratio "
        f"{cvxpy_qp / step_qp:.1f}x",
        f"    recovery QP solved on {int((ours.qp_solves > 1).sum())} steps; over the "
        f"{int(constrained.sum())} steps whose QP had active rows (>= 1 iteration): ours "
        f"{ours_c:.3f} ms, CVXPY {cvxpy_c:.3f} ms ({cvxpy_c / ours_c:.1f}x)",
        f"    statuses: {counts(r.status.value for r in ours.results)}; the same as CVXPY's "
        f"on {100 * agreement(ours, cvxpy):.1f}% of steps; max |u_ours - u_cvxpy| = "
        f"{max_input_gap(ours.results, cvxpy.results):.2e} m/s^2 where both optimal",
    ]
    if "zero_inputs" in passes:
        zero = passes["zero_inputs"]
        lines.append(f"    same QPs with reference_inputs = 0: {int((zero.qp_solves == 0).sum())}"
                     " steps skipped the QP (unconstrained optimum feasible); median over all "
                     f"steps {median(zero.ms):.3f} ms")
    lines.append(f"    backend=\"auto\" picked {backend!r}; each back end on the same steps "
                 "(QP = the solve call; step = halfspaces + QP):")
    for name in ("daqp", "clarabel"):
        step_ms = median(halfspaces + passes[name].ms)
        gap = max_input_gap(passes[name].results, passes["clarabel"].results)
        lines.append(f"      {name:<9} QP {median(passes[name].ms):.3f} ms, step {step_ms:.3f} "
                     f"ms, CVXPY QP / step {median(cvxpy.ms) / step_ms:.1f}x, max |u - "
                     f"u_clarabel| {gap:.1e} m/s^2")
    return "\n".join(lines)


def benchmark_filter_qp(n_steps: int = 500, n_obstacles: int = 3, horizon: int = 10,
                        seed: int = 0) -> str:
    """The report of :func:`solver_passes` on synthetic instances (module docstring), with
    the ``reference_inputs = 0`` pass; ``seed`` seeds the episodes' generator."""
    instances = make_instances(n_steps, n_obstacles, horizon, np.random.default_rng(seed))
    passes, ours = solver_passes(*double_integrator(TS), filter_kwargs(horizon, n_obstacles),
                                 instances, zero_inputs=True)
    return format_passes(f"QP alone on synthetic instances, T = {horizon}, {n_obstacles} "
                         "obstacles", passes, ours.backend)

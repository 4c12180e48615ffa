"""Time the safety-filter QP: the fast filter (any back end) vs the CVXPY reference.

:func:`benchmark_filter_qp` drives the paper's ego double integrator (Ts = 0.2 s)
through a sequence of random crossing episodes: the ego starts on the left at
1.5 m/s with an obstacle-agnostic straight-line reference toward the right; the
obstacles start ahead of it with random constant velocities; their safe
halfspaces at every predicted step use the normal from the ego reference to the
predicted obstacle position and the offset of two 0.3 m discs plus a random
risk margin (a stand-in for the DR-CVaR tightening, so that the QP is the
realistic one without timing the halfspace computation). The fast filter's
first input drives the ego, so the sequence has active constraints, the
occasional infeasible step and the fallbacks that follow.

Both :class:`filters.mpc.MPCSafetyFilter` (``backend="auto"`` unless told) and
:class:`filters.CVXPYSafetyFilter` (the same filter with the CVXPY back end, built once
with parameters, its first compile excluded) then solve the same recorded instances,
interleaved so machine noise hits both alike. The times are wall times of the whole
``solve`` call (validation, data update, solver, acceptance check, roll-out); the
solver call alone is reported too.

What the fast filter's own shortcuts did is reported next to the times:

* The headline median (and the speed-up) is over the steps where our filter solved at
  least one QP. The recorded instances carry no reference inputs, so
  ``skip_feasible_reference`` never applies there: that is every step.
* ``resolved_steps`` counts the steps whose hard QP failed, so that the recovery QP
  (``fallback="soft"``) was solved too; ``constrained_steps`` those whose QP took at
  least one interior-point iteration.
* A second pass of our filter solves the same instances with ``reference_inputs`` set to
  zeros, the same QP (zeros are the default), which lets ``skip_feasible_reference``
  answer from the unconstrained minimiser when it is feasible: the report gives how
  many steps skipped the QP and the median over all steps of that pass.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from filters.mpc import FilterResult, FilterStatus, MPCSafetyFilter
from safe_nav_env.constants import ARENA_HALF_WIDTH, DT, EGO_RADIUS, EGO_START_SPEED
from safe_nav_env.dynamics import double_integrator

__all__ = ["FilterQPBenchmark", "benchmark_filter_qp", "format_filter_qp", "make_instances"]

TS = DT  # s, sampling time of the paper
SPEED = EGO_START_SPEED  # m/s, ego reference speed
RADIUS = EGO_RADIUS  # m, ego and obstacle disc radii
ARENA = ARENA_HALF_WIDTH  # m, arena [-5, 5]^2
INPUT_LIMIT = 5.0  # m/s^2 per axis


def filter_kwargs(horizon: int, n_obstacles: int) -> dict:
    """Constructor keywords shared by both filters (the authors' effective weights)."""
    return {
        "horizon": horizon,
        "Q": 4.0 * np.eye(4),
        "Q_terminal": 25.0 * np.eye(4),
        "R": np.eye(2),
        "input_bounds": (-INPUT_LIMIT, INPUT_LIMIT),
        "position_bounds": (-ARENA, ARENA),
        "n_obstacles": n_obstacles,
    }


def straight_reference(
    x: np.ndarray, lane: float, horizon: int, *, stop_x: float | None = None
) -> np.ndarray:
    """Reference (T+1, 4) at :data:`SPEED` along +x on the ego's lane; row 0 is ``x``.

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


def crossing_start(
    rng: np.random.Generator, n_obstacles: int, area: tuple[float, float, float] = (-2.0, 3.0, 1.5)
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A crossing episode's start: ego state (4,), obstacle positions and velocities (n, 2).

    The ego starts at x = -4.5 m at :data:`SPEED` along +x on a lane y ~ U(-1, 1) m; the
    obstacles in ``[x_low, x_high] x [-y_half, y_half]`` (``area``, m) with speeds
    U(0, 1) m/s in uniform directions.
    """
    x_low, x_high, y_half = area
    x = np.array([-4.5, rng.uniform(-1.0, 1.0), SPEED, 0.0])
    obstacles = np.column_stack(
        [rng.uniform(x_low, x_high, n_obstacles), rng.uniform(-y_half, y_half, n_obstacles)]
    )
    speed = rng.uniform(0.0, 1.0, n_obstacles)
    heading = rng.uniform(0.0, 2.0 * np.pi, n_obstacles)
    velocities = speed[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
    return x, obstacles, velocities


def timed_solves(
    mpc: Any, problems: Sequence[tuple[bool, np.ndarray, np.ndarray, Any, np.ndarray | None]]
) -> tuple[list[float], list[FilterResult]]:
    """Solve each ``(new_episode, x0, reference_states, halfspaces, reference_inputs)`` in turn.

    ``mpc`` (an :class:`MPCSafetyFilter` or :class:`filters.CVXPYSafetyFilter`) is reset
    at each new episode. Returns the wall time of each ``solve`` call in ms and the results.
    """
    times, results = [], []
    for new_episode, x0, reference_states, halfspaces, reference_inputs in problems:
        if new_episode:
            mpc.reset()
        begin = time.perf_counter()
        results.append(mpc.solve(x0, reference_states, halfspaces,
                                 reference_inputs=reference_inputs))
        times.append(1e3 * (time.perf_counter() - begin))
    return times, results


def max_input_gap(first: Sequence[FilterResult], second: Sequence[FilterResult]) -> float:
    """Largest ``|u_first - u_second|`` (m/s²) over the steps both solved optimally (NaN: none)."""
    gaps = [float(np.max(np.abs(a.inputs - b.inputs)))
            for a, b in zip(first, second, strict=True)
            if a.status == b.status == FilterStatus.OPTIMAL]
    return max(gaps, default=float("nan"))


@dataclass(frozen=True)
class Instance:
    """One filter problem: state, reference and halfspaces (normals ``(k, T, 2)``)."""

    x0: np.ndarray
    reference_states: np.ndarray
    normals: np.ndarray
    offsets: np.ndarray
    new_episode: bool


def _halfspaces(
    reference_positions: np.ndarray, predicted: np.ndarray, margins: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Normals from the ego reference to each prediction; offsets keep two discs apart."""
    direction = predicted - reference_positions[None]
    norm = np.linalg.norm(direction, axis=-1, keepdims=True)
    normals = direction / np.maximum(norm, 1e-9)
    normals[norm[..., 0] < 1e-9] = (1.0, 0.0)
    offsets = np.einsum("ktd,ktd->kt", normals, predicted) - 2 * RADIUS - margins[:, None]
    return normals, offsets


def make_instances(
    n_steps: int, n_obstacles: int, horizon: int, rng: np.random.Generator
) -> list[Instance]:
    """Simulate crossing episodes with the fast filter in the loop; record each step's QP."""
    A, B, C = double_integrator(TS)
    mpc = MPCSafetyFilter(A, B, C, **filter_kwargs(horizon, n_obstacles))
    steps = np.arange(1, horizon + 1)[:, None] * TS  # (T, 1)
    instances: list[Instance] = []
    new_episode = True
    while len(instances) < n_steps:
        if new_episode:
            mpc.reset()
            x, obstacles, velocities = crossing_start(rng, n_obstacles)
            lane = x[1]
            margins = rng.uniform(0.0, 0.15, n_obstacles)
            step_in_episode = 0
        reference = straight_reference(x, lane, horizon)
        predicted = obstacles[:, None, :] + velocities[:, None, :] * steps[None]
        normals, offsets = _halfspaces(reference[1:, :2], predicted, margins)
        instances.append(Instance(x.copy(), reference, normals, offsets, new_episode))
        result = mpc.solve(x, reference, (normals, offsets))
        x = A @ x + B @ result.first_input
        obstacles = obstacles + TS * velocities
        step_in_episode += 1
        new_episode = step_in_episode >= 40 or x[0] > 4.5
    return instances


@dataclass(frozen=True)
class FilterQPBenchmark:
    """Timings (ms) of one filter step on the same instances, and their agreement."""

    n_steps: int
    n_obstacles: int
    horizon: int
    ours_median_ms: float
    ours_p90_ms: float
    ours_solver_median_ms: float
    cvxpy_median_ms: float
    cvxpy_p90_ms: float
    cvxpy_compile_ms: float
    ratio: float  # cvxpy median / ours median, over the steps where ours solved a QP
    max_input_difference: float  # over steps both solved optimally, in m/s^2 (NaN: none)
    statuses: dict[str, int] = field(default_factory=dict)  # ours
    agreement: float = 1.0  # share of steps where both gave the same status
    qp_steps: int = 0  # steps where ours solved at least one QP (the headline's steps)
    shortcut_steps: int = 0  # steps ours answered without a QP (no reference inputs: 0)
    resolved_steps: int = 0  # steps where ours also solved the recovery QP
    constrained_steps: int = 0  # steps whose final QP took >= 1 interior-point iteration
    constrained_ours_median_ms: float = float("nan")
    constrained_cvxpy_median_ms: float = float("nan")
    reference_inputs_shortcut_steps: int = 0  # pass with reference_inputs = 0
    reference_inputs_median_ms: float = float("nan")  # that pass, all steps
    backend: str = "clarabel"  # the back end of ours (``"auto"`` resolved)


def benchmark_filter_qp(
    n_steps: int = 500, n_obstacles: int = 3, horizon: int = 10, seed: int = 0,
    *, backend: str = "auto",
) -> FilterQPBenchmark:
    """Time :class:`MPCSafetyFilter` against :class:`CVXPYSafetyFilter` on the same QPs.

    Parameters
    ----------
    n_steps
        Number of filter steps (QP instances) timed.
    n_obstacles
        Obstacles per episode (halfspace rows per step).
    horizon
        MPC horizon ``T``.
    seed
        Seed of the ``numpy.random.Generator`` that draws the episodes.
    backend
        Back end of our filter (``"auto"``, ``"daqp"``, ``"clarabel"``).

    Returns
    -------
    FilterQPBenchmark
        Medians and 90th percentiles of the per-step wall times in ms, the ratio of
        the medians (CVXPY / ours), and how closely the two agree.
    """
    from filters import CVXPYSafetyFilter  # imports cvxpy: only when benchmarking

    rng = np.random.default_rng(seed)
    instances = make_instances(n_steps, n_obstacles, horizon, rng)
    A, B, C = double_integrator(TS)
    ours = MPCSafetyFilter(A, B, C, backend=backend, **filter_kwargs(horizon, n_obstacles))
    with_inputs = MPCSafetyFilter(A, B, C, backend=backend,
                                  **filter_kwargs(horizon, n_obstacles))
    reference = CVXPYSafetyFilter(A, B, C, **filter_kwargs(horizon, n_obstacles))
    zero_inputs = np.zeros((horizon, B.shape[1]))
    first = instances[0]
    begin = time.perf_counter()
    reference.solve(first.x0, first.reference_states, (first.normals, first.offsets))
    compile_ms = 1e3 * (time.perf_counter() - begin)
    for instance in instances[:20]:  # warm the caches
        halfspaces = (instance.normals, instance.offsets)
        ours.solve(instance.x0, instance.reference_states, halfspaces)
        with_inputs.solve(instance.x0, instance.reference_states, halfspaces)

    ours_ms, ours_solver_ms, cvxpy_ms, inputs_ms = [], [], [], []
    qp_calls, shortcut_calls, fast_results, slow_results = [], [], [], []
    for instance in instances:
        if instance.new_episode:
            ours.reset()
            with_inputs.reset()
            reference.reset()
        halfspaces = (instance.normals, instance.offsets)
        begin = time.perf_counter()
        fast = ours.solve(instance.x0, instance.reference_states, halfspaces)
        ours_ms.append(1e3 * (time.perf_counter() - begin))
        ours_solver_ms.append(1e3 * fast.solve_time)
        qp_calls.append(ours.last_qp_solves)
        begin = time.perf_counter()
        slow = reference.solve(instance.x0, instance.reference_states, halfspaces)
        cvxpy_ms.append(1e3 * (time.perf_counter() - begin))
        begin = time.perf_counter()
        with_inputs.solve(
            instance.x0, instance.reference_states, halfspaces, reference_inputs=zero_inputs
        )
        inputs_ms.append(1e3 * (time.perf_counter() - begin))
        shortcut_calls.append(with_inputs.last_qp_solves)
        fast_results.append(fast)
        slow_results.append(slow)

    ours_all, cvxpy_all = np.array(ours_ms), np.array(cvxpy_ms)
    calls = np.array(qp_calls)
    qp = calls > 0  # ours solved a QP: the headline's steps
    constrained = qp & (np.array([r.iterations for r in fast_results]) > 0)
    same = sum(a.status == b.status for a, b in zip(fast_results, slow_results, strict=True))
    ours_median = float(np.median(ours_all[qp])) if qp.any() else float("nan")
    cvxpy_median = float(np.median(cvxpy_all[qp])) if qp.any() else float("nan")
    return FilterQPBenchmark(
        n_steps=len(instances),
        n_obstacles=n_obstacles,
        horizon=horizon,
        ours_median_ms=ours_median,
        ours_p90_ms=float(np.percentile(ours_ms, 90)),
        ours_solver_median_ms=float(np.median(ours_solver_ms)),
        cvxpy_median_ms=cvxpy_median,
        cvxpy_p90_ms=float(np.percentile(cvxpy_ms, 90)),
        cvxpy_compile_ms=compile_ms,
        ratio=cvxpy_median / ours_median,
        max_input_difference=max_input_gap(fast_results, slow_results),
        statuses=dict(Counter(r.status.value for r in fast_results)),
        agreement=same / len(instances),
        qp_steps=int(qp.sum()),
        shortcut_steps=int((calls == 0).sum()),
        resolved_steps=int((calls > 1).sum()),
        constrained_steps=int(constrained.sum()),
        constrained_ours_median_ms=(
            float(np.median(ours_all[constrained])) if constrained.any() else float("nan")
        ),
        constrained_cvxpy_median_ms=(
            float(np.median(cvxpy_all[constrained])) if constrained.any() else float("nan")
        ),
        reference_inputs_shortcut_steps=int((np.array(shortcut_calls) == 0).sum()),
        reference_inputs_median_ms=float(np.median(inputs_ms)),
        backend=ours.backend,
    )


def format_filter_qp(result: FilterQPBenchmark) -> str:
    """A short table of a :func:`benchmark_filter_qp` result."""
    statuses = ", ".join(f"{name} {count}" for name, count in sorted(result.statuses.items()))
    constrained_ratio = result.constrained_cvxpy_median_ms / result.constrained_ours_median_ms
    return "\n".join(
        [
            f"Filter QP, T = {result.horizon}, {result.n_obstacles} obstacles, "
            f"{result.n_steps} steps ({statuses})",
            f"{'':28}{'median ms':>10}{'p90 ms':>10}",
            f"{f'MPCSafetyFilter ({result.backend})':28}{result.ours_median_ms:>10.3f}"
            f"{result.ours_p90_ms:>10.3f}",
            f"{'  of which solver call':28}{result.ours_solver_median_ms:>10.3f}",
            f"{'CVXPYSafetyFilter':28}{result.cvxpy_median_ms:>10.3f}{result.cvxpy_p90_ms:>10.3f}",
            f"speed-up (median ratio): {result.ratio:.1f}x over the {result.qp_steps} steps "
            f"where ours solved a QP ({result.shortcut_steps} answered without one); "
            f"CVXPY first compile {result.cvxpy_compile_ms:.0f} ms",
            f"recovery QP solved on {result.resolved_steps} steps; over the "
            f"{result.constrained_steps} steps whose QP had active rows (>= 1 iteration): "
            f"ours {result.constrained_ours_median_ms:.3f} ms, CVXPY "
            f"{result.constrained_cvxpy_median_ms:.3f} ms ({constrained_ratio:.1f}x)",
            f"same QPs with reference_inputs = 0: {result.reference_inputs_shortcut_steps} "
            f"steps skipped the QP (unconstrained optimum feasible); median over all "
            f"steps {result.reference_inputs_median_ms:.3f} ms",
            f"same status on {100 * result.agreement:.1f}% of steps; max |u_ours - u_cvxpy| "
            f"= {result.max_input_difference:.2e} m/s^2 where both optimal",
        ]
    )


if __name__ == "__main__":  # pragma: no cover
    print(format_filter_qp(benchmark_filter_qp()))

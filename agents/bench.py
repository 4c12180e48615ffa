"""``safe-nav bench``: every speed target, measured as ratios in one run.

These machines are shared and noisy, so every number is a median and every target
is a ratio against a reference measured in the same run:

(a) the paper's Table I: one CVaR / DR-CVaR halfspace with CVXPY (setup, solve,
    call) at N_s = 50, 500, 1500, against our closed form for all 3 x 10 halfspaces;
(b) one full filter step (halfspaces + QP) on the multi-obstacle scenario
    (3 obstacles, T = 10, N_s = 100) against the same QP in CVXPY built once with
    Parameters, and the QP alone on synthetic instances;
(c) the unfiltered environment's steps per second.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


def halfspace_timing_table(
    sample_counts: Sequence[int] = (50, 500, 1500), repeats: int = 100, seed: int = 0
) -> dict:
    """Table I as nested dicts (ms): ``cvxpy[risk][N_s] = {setup, solve, call}`` (means)
    and ``ours[N_s]`` = our DR-CVaR time for one halfspace; ``result`` is the raw
    :class:`filters.benchmarks.halfspaces.TableOneResult`."""
    from filters.benchmarks.halfspaces import benchmark_table_one

    result = benchmark_table_one(sample_counts, repeats, seed)
    cvxpy: dict[str, dict[int, dict[str, float]]] = {}
    for row in result.cvxpy:
        cvxpy.setdefault(row.risk, {})[row.n_samples] = {
            "setup": row.setup_mean, "solve": row.solve_mean, "call": row.call_mean}
    ours = {row.n_samples: row.one_halfspace_us / 1e3 for row in result.ours
            if row.risk == "dr_cvar"}
    return {"cvxpy": cvxpy, "ours": ours, "result": result}


@dataclass(frozen=True)
class FilterStepBenchmark:
    """Per-step times (ms, medians) of the full filter on a real scenario."""

    steps: int
    halfspaces_ms: float
    qp_ms: float
    step_ms: float
    step_p90_ms: float
    cvxpy_qp_ms: float
    ratio: float  # CVXPY QP alone / our full step (halfspaces + QP)
    qp_steps: int  # steps where ours needed a QP (the rest: feasible-reference shortcut)
    step_qp_ms: float  # our full step, median over the qp_steps
    cvxpy_qp_steps_ms: float  # CVXPY, median over the same qp_steps
    statuses: dict[str, int]

    def format(self) -> str:
        statuses = ", ".join(f"{k} {v}" for k, v in sorted(self.statuses.items()))
        return "\n".join([
            f"(b) one filter step, MultiObstacle (3 obstacles, T = 10, N_s = 100), "
            f"{self.steps} steps, medians:",
            f"    ours: halfspaces {self.halfspaces_ms:.3f} ms + QP {self.qp_ms:.3f} ms = "
            f"step {self.step_ms:.3f} ms (p90 {self.step_p90_ms:.3f} ms)",
            f"    CVXPY QP built once with Parameters (Clarabel): {self.cvxpy_qp_ms:.3f} ms",
            f"    ratio CVXPY QP / our whole step: {self.ratio:.1f}x   (target >= 10x, "
            f"step < 1 ms)",
            f"    steps that needed a QP ({self.qp_steps}; the others were answered by the "
            f"feasible-reference shortcut): ours {self.step_qp_ms:.3f} ms, CVXPY "
            f"{self.cvxpy_qp_steps_ms:.3f} ms, ratio "
            f"{self.cvxpy_qp_steps_ms / self.step_qp_ms:.1f}x",
            f"    statuses: {statuses}",
        ])


def benchmark_filter_step(n_steps: int = 500, seed: int = 0) -> FilterStepBenchmark:
    """Time the full DR-CVaR filter step along real MultiObstacle episodes.

    The reference is the paper's obstacle-agnostic MPC plan; the applied action is
    ours, so the episode follows the filtered trajectory, as in a real control loop.
    The CVXPY QP is then solved on the very same data, in a second pass (run
    interleaved, each solver evicts the other's data from the caches and both
    look slower than in a loop of their own).
    """
    import gymnasium as gym

    import safe_nav_env  # noqa: F401
    from agents.planners import MPCReferencePlanner
    from filters import CVXPYSafetyFilter, Disc, MPCSafetyFilter, safe_halfspaces

    env = gym.make("SafeNav/MultiObstacle-v0", n_samples=100, horizon=10)
    base = env.unwrapped
    A, B, C = base.dynamics
    planner = MPCReferencePlanner.from_env(env)
    weights = dict(horizon=10, Q=4.0 * np.eye(4), Q_terminal=25.0 * np.eye(4), R=np.eye(2),
                   input_bounds=base.input_bounds, position_bounds=base.position_bounds,
                   n_obstacles=3)
    ours = MPCSafetyFilter(A, B, C, **weights)
    halfspace_ms, qp_ms, step_ms, needed_qp = [], [], [], []
    instances = []
    statuses: dict[str, int] = {}
    episode = 0
    while len(step_ms) < n_steps:
        env.reset(seed=seed + episode)
        ours.reset()
        episode += 1
        done = False
        instances.append(None)  # episode boundary: reset the reference filter too
        ego_shape = Disc(base.ego_radius)  # built once per episode, as the wrapper does
        obstacle_shapes = [Disc(r) for r in base.obstacle_radii]
        while not done and len(step_ms) < n_steps:
            x0 = np.asarray(base.ego_state, dtype=float)
            ref_states, ref_inputs = planner.plan(x0, base.goal)
            begin = time.perf_counter()
            hs = safe_halfspaces(
                ref_states[1:] @ C.T, base.predictions, ego_shape=ego_shape,
                obstacle_shapes=obstacle_shapes, risk="dr_cvar", ego_velocity=x0[2:])
            middle = time.perf_counter()
            result = ours.solve(x0, ref_states, hs, reference_inputs=ref_inputs)
            end = time.perf_counter()
            halfspace_ms.append(1e3 * (middle - begin))
            qp_ms.append(1e3 * (end - middle))
            step_ms.append(1e3 * (end - begin))
            needed_qp.append(ours.last_qp_solves > 0)
            instances.append((x0, ref_states, hs, ref_inputs))
            statuses[result.status.value] = statuses.get(result.status.value, 0) + 1
            _, _, terminated, truncated, _ = env.step(result.inputs[0].astype(np.float32))
            done = terminated or truncated
    reference = CVXPYSafetyFilter(A, B, C, **weights)
    cvxpy_ms = []
    for instance in instances:
        if instance is None:
            reference.reset()
            continue
        x0, ref_states, hs, ref_inputs = instance
        begin = time.perf_counter()
        reference.solve(x0, ref_states, hs, reference_inputs=ref_inputs)
        cvxpy_ms.append(1e3 * (time.perf_counter() - begin))
    env.close()
    step = float(np.median(step_ms))
    mask = np.asarray(needed_qp)
    steps_qp = np.asarray(step_ms)[mask] if mask.any() else np.asarray([np.nan])
    cvxpy_qp = np.asarray(cvxpy_ms)[mask] if mask.any() else np.asarray([np.nan])
    return FilterStepBenchmark(
        steps=len(step_ms), halfspaces_ms=float(np.median(halfspace_ms)),
        qp_ms=float(np.median(qp_ms)), step_ms=step,
        step_p90_ms=float(np.percentile(step_ms, 90)), cvxpy_qp_ms=float(np.median(cvxpy_ms)),
        ratio=float(np.median(cvxpy_ms)) / step, qp_steps=int(mask.sum()),
        step_qp_ms=float(np.median(steps_qp)), cvxpy_qp_steps_ms=float(np.median(cvxpy_qp)),
        statuses=statuses)


def run_benchmarks(filter_steps: int = 500, table_repeats: int = 100, seed: int = 0,
                   env_steps: int = 3000) -> str:
    """Run (a), (b) and (c) and return the printed report."""
    import platform

    from filters.benchmarks.filter_qp import benchmark_filter_qp, format_filter_qp
    from filters.benchmarks.halfspaces import format_table_one
    from safe_nav_env.benchmark import benchmark as env_benchmark

    parts = [f"python {platform.python_version()}, numpy {np.__version__}, "
             f"{platform.machine()}; medians; ratios measured in this run"]
    table = halfspace_timing_table((50, 500, 1500), table_repeats, seed)
    parts.append("(a) " + format_table_one(table["result"]))
    parts.append(benchmark_filter_step(filter_steps, seed).format())
    parts.append("    QP alone on synthetic instances:\n" + format_filter_qp(
        benchmark_filter_qp(n_steps=filter_steps, seed=seed)))
    rates = env_benchmark(n_steps=env_steps, repeats=3, seed=seed)
    parts.append("(c) unfiltered environment, gym.make, N_s = 100, T = 10:\n" + "\n".join(
        f"    {env_id:<28} {rate:8.0f} steps/s" for env_id, rate in rates.items()))
    return "\n\n".join(parts)

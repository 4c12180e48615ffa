"""``safe-nav bench``: every speed target, measured as ratios in one run.

(a) the paper's Table I: one CVaR / DR-CVaR halfspace with CVXPY (setup, solve,
    call) at N_s = 50, 500, 1500, against our closed form for all 3 x 10 halfspaces;
(b) one full filter step (halfspaces + QP) along MultiObstacle episodes (3 obstacles,
    T = 10, N_s = 100), the paper's filter and the wrapper's continuous-time one,
    against the same QP in CVXPY built once with Parameters; ours is the default
    ``backend="auto"``, and each explicit back end (DAQP, Clarabel) solves the same
    steps too. Then the policy roll-out reference (SB3 against :class:`agents.NumpyPolicy`,
    :mod:`benchmarks.policy`) against that QP, both step by step in the evaluation's
    control loop, and the QP alone on synthetic instances (:mod:`benchmarks.filter_qp`);
(c) the unfiltered environment's steps per second, and the renderer's time per frame
    (:mod:`benchmarks.env`).

``--training`` (:mod:`benchmarks.training`), ``--evaluation`` (:mod:`benchmarks.evaluation`)
and ``--scaling`` (:mod:`benchmarks.scaling`) are run on their own.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

import safe_nav_env  # noqa: F401  (registers the ids)
from benchmarks.filter_qp import Instance, filter_kwargs, format_passes, solver_passes
from benchmarks.timing import clock, drive, machine, median, p90
from filters import Disc, MPCSafetyFilter, SafetyFilterWrapper, safe_halfspaces
from filters.intersample import intersample_rows
from filters.mpc import stopping_terminal_set


def filter_step(n_steps: int = 500, seed: int = 0, *, continuous: bool = False
                ) -> tuple[str, float]:
    """Time the DR-CVaR filter step along MultiObstacle episodes; the report and our QP median.

    ``continuous=False`` is the paper's filter (halfspaces at the samples, hard QP);
    ``continuous=True`` the wrapper's default one: the inter-sample rows of
    :func:`filters.intersample_rows` (twice the rows), the terminal set and the soft
    recovery. The reference is the paper's obstacle-agnostic MPC plan and our filter
    drives the episode, as in a control loop. The halfspaces are timed as the steps are
    recorded; then each filter solves the recorded steps in a pass of its own.
    """
    from agents.planners import MPCReferencePlanner

    env = gym.make("SafeNav/MultiObstacle-v0", n_samples=100, horizon=10)
    base = env.unwrapped
    A, B, C = base.dynamics
    planner = MPCReferencePlanner.from_env(env)
    kwargs = {**filter_kwargs(10, 6 if continuous else 3), "input_bounds": base.input_bounds,
              "position_bounds": base.position_bounds}
    if continuous:
        kwargs.update(fallback="soft", terminal_set=stopping_terminal_set(
            base.dt, base.input_bounds, base.position_bounds))
    shapes = {"ego_shape": Disc(base.ego_radius),
              "obstacle_shapes": [Disc(r) for r in base.obstacle_radii]}

    def halfspaces(x0: np.ndarray, positions: np.ndarray, predictions: np.ndarray) -> tuple:
        rows = safe_halfspaces(positions, predictions, risk="dr_cvar", ego_velocity=x0[2:],
                               **shapes)
        if continuous:
            rows = intersample_rows(rows, predictions, input_bounds=base.input_bounds,
                                    dt=float(base.dt), **shapes)
        return rows.normals, rows.offsets

    live, instances, halfspace_ms = MPCSafetyFilter(A, B, C, **kwargs), [], []

    def act(_: np.ndarray, new_episode: bool) -> np.ndarray:
        if new_episode:
            live.reset()
        x0 = np.asarray(base.ego_state, dtype=float)
        states, inputs = planner.plan(x0, base.goal)
        rows, ms = clock(halfspaces, x0, states[1:] @ C.T, base.predictions[:, :, :10])
        instances.append(Instance(x0, states, rows, new_episode, reference_inputs=inputs))
        halfspace_ms.append(ms)
        return live.solve(x0, states, rows, reference_inputs=inputs).inputs[0].astype(np.float32)

    list(drive(env, n_steps, seed, act))
    env.close()
    passes, ours = solver_passes(A, B, C, kwargs, instances)
    variant = ("the continuous-time filter (inter-sample rows, terminal set, recovery)"
               if continuous else "the paper's filter")
    return format_passes(f"(b) one filter step, {variant}, MultiObstacle (3 obstacles, T = 10, "
                         "N_s = 100)", passes, ours.backend, halfspace_ms), median(
        passes["ours"].ms)


def control_loop(steps: int = 500, seed: int = 0) -> str:
    """The roll-out reference against the QP, step by step, in the evaluation's loop.

    ``SafetyFilterWrapper(env, policy=NumpyPolicy)`` as ``safe-nav evaluate`` builds it,
    driven by the same actor; the times are the filter reports' (reference, halfspaces,
    QP = ``filter_time - halfspace_time``), so all are measured on the same steps.
    """
    from benchmarks.policy import shipped_policy

    _, actor = shipped_policy()
    env = SafetyFilterWrapper(gym.make("SafeNav/MultiObstacle-v0"), policy=actor)
    rows = [(info["filter"].reference_time, info["filter"].halfspace_time,
             info["filter"].filter_time - info["filter"].halfspace_time, ms / 1e3)
            for info, ms in drive(env, steps, seed, lambda obs, _: actor.predict(obs)[0])]
    env.close()
    reference, halfspaces, qp, wrapper_ms = 1e3 * np.asarray(rows).T
    return (f"    in the control loop (MultiObstacle, the shipped PPO planner, roll-out "
            f"reference, DR-CVaR, the wrapper's defaults), {len(rows)} steps, medians: "
            f"reference {median(reference):.3f} ms, halfspaces {median(halfspaces):.3f} ms, "
            f"QP {median(qp):.3f} ms, whole wrapper step {median(wrapper_ms):.3f} ms; "
            f"reference / QP {median(reference / qp):.2f} (median of the per-step ratios)")


def run_benchmarks(filter_steps: int = 500, table_repeats: int = 100, seed: int = 0,
                   env_steps: int = 3000) -> str:
    """Run (a), (b) and (c) and return the printed report."""
    from agents.experiments.table_one import format_table_one, halfspace_timing_table
    from benchmarks.env import benchmark, normal_draws_per_second, render_frames
    from benchmarks.filter_qp import benchmark_filter_qp
    from benchmarks.policy import benchmark_rollout_reference, format_rollout_reference

    table = halfspace_timing_table((50, 500, 1500), table_repeats, seed)
    paper, _ = filter_step(filter_steps, seed)
    continuous, qp_ms = filter_step(filter_steps, seed, continuous=True)
    rollout = benchmark_rollout_reference(steps=filter_steps, seed=seed)
    policy = (f"    {format_rollout_reference(rollout)}\n    NumpyPolicy roll-out / the "
              f"continuous-time filter's QP above: {rollout['numpy']:.3f} / {qp_ms:.3f} ms = "
              f"{rollout['numpy'] / qp_ms:.2f}\n" + control_loop(filter_steps, seed))
    environment = ["(c) unfiltered environment, gym.make, N_s = 100, T = 10:"]
    for env_id, rate in benchmark(n_steps=env_steps, repeats=3, seed=seed).items():
        environment.append(f"    {env_id:<28} {rate:8.0f} steps/s {1e6 / rate:8.1f} µs/step")
    normals = normal_draws_per_second(seed=seed)
    frames = min(100, filter_steps)
    environment += [f"    machine reference: numpy draws {normals / 1e6:.0f} M normals/s, so "
                    f"the 6000 prediction normals of a MultiObstacle step take "
                    f"{6000 / normals * 1e6:.1f} µs",
                    f"    rgb_array frames with the DR-CVaR wrapper's halfspaces, {frames} "
                    "frames, render() alone:"]
    for env_id, (wall, cpu) in render_frames(frames, seed=seed).items():
        environment.append(f"    {env_id:<28} median {median(wall):5.2f} ms (CPU "
                           f"{median(cpu):5.2f} ms)  p90 {p90(wall):5.2f} ms  max "
                           f"{max(wall):6.2f} ms")
    return "\n\n".join([f"{machine()}; medians; ratios measured in this run",
                         "(a) " + format_table_one(table["result"]), paper, continuous, policy,
                         benchmark_filter_qp(n_steps=filter_steps, seed=seed),
                         "\n".join(environment)])

"""Where the filtered PPO training step's added microseconds go (issue 12, the 0.70 ratio).

What ``safe-nav bench --training`` runs (RandomCrossing, 8 in-process environments, the
wrapper's defaults), a plain and a filtered model trained in alternating chunks in one
process, with ``time.perf_counter`` clocks around the calls that make up a step:
SB3's rollout and update, the vector environment's step, the policy's forward pass,
the environment's ``step`` and ``reset``, :class:`agents.training.wrappers.EpisodeCostInfo`,
the filter wrapper's ``step`` and ``_filter``, the compiled hard QP
(:meth:`filters.mpc.fast.FastHardStep.solve_hard`) and the DAQP calls (the recovery
QP: soft rows). The reference, halfspace and QP times come from the filter reports.

Prints medians over the chunks, in µs per environment step. The clocks add about a
microsecond per clocked call, so the step times here are a little above the bench's;
the plain-against-filtered differences of the unfiltered parts (the environment step,
the policy's forward pass) are what the filter costs the rest of the loop.

Usage: ``python scripts/training_step_account.py [--chunks 6] [--chunk 2048]``
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

import numpy as np

CLOCKED = ("ppo.train", "collect_rollouts", "vec.step_wait", "policy.forward", "env.reset",
           "env.step", "costinfo.step", "wrapper.step", "_filter", "hard_step", "daqp_soft",
           "daqp_hard")


def _clock(owner: type, name: str, key: str | Callable[[Any], str], times: dict) -> None:
    """Replace ``owner.name`` by a clocked call that adds its wall time to ``times[key]``."""
    original = getattr(owner, name)

    def clocked(self: Any, *args: Any, **kwargs: Any) -> Any:
        begin = time.perf_counter()
        try:
            return original(self, *args, **kwargs)
        finally:
            label = key(self) if callable(key) else key
            times[label] = times.get(label, 0.0) + time.perf_counter() - begin

    setattr(owner, name, clocked)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--chunks", type=int, default=6, help="chunks of each kind")
    parser.add_argument("--chunk", type=int, default=2048, help="steps per chunk")
    args = parser.parse_args()

    from stable_baselines3 import PPO
    from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.common.vec_env import DummyVecEnv

    from agents.training.ppo import train_ppo
    from agents.training.wrappers import EpisodeCostInfo
    from benchmarks.suite import _filter_clock
    from filters.mpc.backends.daqp import DAQPBackend
    from filters.mpc.fast import FastHardStep
    from filters.wrapper import SafetyFilterWrapper
    from safe_nav_env.env import SafeNavEnv

    times: dict[str, float] = {}
    for owner, name, key in (
        (PPO, "train", "ppo.train"), (OnPolicyAlgorithm, "collect_rollouts", "collect_rollouts"),
        (DummyVecEnv, "step_wait", "vec.step_wait"),
        (ActorCriticPolicy, "forward", "policy.forward"), (SafeNavEnv, "reset", "env.reset"),
        (SafeNavEnv, "step", "env.step"), (EpisodeCostInfo, "step", "costinfo.step"),
        (SafetyFilterWrapper, "step", "wrapper.step"),
        (SafetyFilterWrapper, "_filter", "_filter"), (FastHardStep, "solve_hard", "hard_step"),
    ):
        _clock(owner, name, key, times)
    _clock(DAQPBackend, "solve_written",
           lambda backend: "daqp_soft" if backend._soft_weights is not None else "daqp_hard",
           times)

    models = {filtered: train_ppo(total_timesteps=args.chunk, seed=0,
                                  filter_kwargs={"risk": "dr_cvar"} if filtered else None,
                                  progress_bar=False)[0] for filtered in (False, True)}
    rows: dict[bool, list[dict[str, float]]] = {False: [], True: []}
    for _ in range(args.chunks):
        for filtered, model in models.items():
            times.clear()
            clock = _filter_clock()
            before = model.num_timesteps
            begin = time.perf_counter()
            model.learn(args.chunk, reset_num_timesteps=False, callback=clock)
            wall = time.perf_counter() - begin
            steps = model.num_timesteps - before
            row = {key: 1e6 * value / steps for key, value in times.items()}
            row.update({key: 1e6 * value / steps for key, value in clock.times.items()})
            row["step"] = 1e6 * wall / steps
            rows[filtered].append(row)
    for model in models.values():
        model.get_env().close()

    def median(filtered: bool, key: str) -> float:
        return float(np.median([row.get(key, 0.0) for row in rows[filtered]]))

    plain, filtered = median(False, "step"), median(True, "step")
    pairs = [a["step"] / b["step"] for a, b in zip(rows[False], rows[True], strict=True)]
    print(f"per environment step, medians of {args.chunks} chunks of {args.chunk} steps: "
          f"plain {plain:.0f} us, filtered {filtered:.0f} us (+{filtered - plain:.0f}); "
          f"ratio {plain / filtered:.3f}, median of the pairs {np.median(pairs):.3f}")
    print(f"  {'':18s} {'plain':>8s} {'filtered':>9s}")
    for key in (*CLOCKED, "reference", "halfspaces", "qp", "qp_not_optimal"):
        print(f"  {key:18s} {median(False, key):8.1f} {median(True, key):9.1f}")
    glue = [row["wrapper.step"] - row["_filter"] - row["env.step"] for row in rows[True]]
    inner = [row["_filter"] - row["reference"] - row["halfspaces"] - row["qp"]
             for row in rows[True]]
    print(f"  wrapper.step outside _filter and env.step: {np.median(glue):.1f}; _filter "
          f"outside reference, halfspaces and QP: {np.median(inner):.1f}")


if __name__ == "__main__":
    main()

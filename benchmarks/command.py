"""``safe-nav bench``: run the benchmark the parsed options ask for.

The command line (:mod:`agents.cli`) parses the options and hands them here, so the
runtime packages import :mod:`benchmarks` through this one function, on demand.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path


def add_arguments(bench: argparse.ArgumentParser, *, positive_int: Callable[[str], int],
                  seed: Callable[[str], int]) -> None:
    """Add ``safe-nav bench``'s options to its sub-parser ``bench``.

    ``positive_int`` and ``seed`` are the command line's argument types (integers
    ``>= 1`` and ``>= 0`` with its error messages).
    """
    add = bench.add_argument
    add("--steps", type=positive_int, default=None,
        help="filter steps timed (default 500; --scaling: per grid point, 100)")
    add("--repeats", type=positive_int, default=100, help="repeats of each halfspace timing (>= 1)")
    add("--scaling", action="store_true",
        help="scaling grid: obstacles x horizon x samples, ours vs CVXPY")
    add("--quick", action="store_true", help="--scaling on a small subset")
    for name, what in (("obstacles", "obstacle counts (default 1 3 10 20)"),
                       ("horizons", "horizons T in steps (default 10 20 40 80)"),
                       ("samples", "prediction samples N_s (default 100 1000)")):
        add(f"--{name}", type=positive_int, nargs="+", default=None, help=f"--scaling: {what}")
    add("--seed", type=seed, default=0, help="seed of the instances")
    add("--output", type=Path, default=None,
        help="--scaling: folder for scaling.csv, scaling.md, scaling.png")
    add("--no-plot", action="store_true", help="--scaling: no figure")
    add("--family", choices=("straight", "goal"), default="straight",
        help="--scaling: instances whose reference runs straight on (the issue's grid) or "
             "stops at a goal inside the arena")
    add("--no-policy", action="store_true",
        help="--scaling: skip the policy (SB3 vs numpy) timings")
    add("--training", action="store_true", help="PPO training steps per second with the DR-CVaR "
        "filter in the loop against without it (interleaved runs, same process)")
    add("--evaluation", type=positive_int, nargs="?", const=300, metavar="N",
        help="safe-nav evaluate (N per scenario, risk) on 1 vs 2 workers, 3 runs")
    add("--timesteps", type=positive_int, default=20_480,
        help="--training: timed steps of each kind (default 20480)")
    add("--chunk", type=positive_int, default=2048,
        help="--training: steps per alternating chunk (default 2048: one rollout and its update)")
    add("--envs", type=positive_int, default=8,
        help="--training: in-process vector environments of each model (default 8, train's)")


def run(args: argparse.Namespace) -> int:
    """Run ``safe-nav bench`` with the parsed options ``args``; print the report; return 0.

    ``--scaling``: :func:`benchmarks.scaling.run_scaling` on the full or ``--quick`` grid
    (``--obstacles/--horizons/--samples/--steps`` override its axes); ``--evaluation [N]``:
    :func:`benchmarks.evaluation.benchmark_evaluation` (N episodes per scenario and risk,
    3 runs on each worker count); ``--training``:
    :func:`benchmarks.training.benchmark_training`; otherwise
    :func:`benchmarks.suite.run_benchmarks`.
    """
    if args.scaling:
        from benchmarks.scaling import FULL_GRID, QUICK_GRID, run_scaling

        overrides = {name: tuple(getattr(args, name)) for name in
                     ("obstacles", "horizons", "samples") if getattr(args, name)}
        if args.steps:
            overrides["steps"] = max(2, args.steps)
        grid = replace(QUICK_GRID if args.quick else FULL_GRID, **overrides)
        print(run_scaling(grid, seed=args.seed, output=args.output, plot=not args.no_plot,
                          policy=not args.no_policy, family=args.family))
    elif args.evaluation:
        from benchmarks.evaluation import benchmark_evaluation

        print(benchmark_evaluation(args.evaluation, 3, progress=True).format())
    elif args.training:
        from benchmarks.training import benchmark_training

        print(benchmark_training(args.timesteps, args.chunk, args.seed, n_envs=args.envs).format())
    else:
        from benchmarks.suite import run_benchmarks

        print(run_benchmarks(filter_steps=args.steps or 500, table_repeats=args.repeats,
                             seed=args.seed))
    return 0

"""``safe-nav bench``: run the benchmark the parsed options ask for.

The command line (:mod:`agents.cli`) parses the options and hands them here, so the
runtime packages import :mod:`benchmarks` through this one function, on demand.
"""

from __future__ import annotations

import argparse
from dataclasses import replace


def run(args: argparse.Namespace) -> int:
    """Run ``safe-nav bench`` with the parsed options ``args``; print the report; return 0.

    ``--scaling``: :func:`benchmarks.suite.run_scaling` on the full or ``--quick`` grid
    (``--obstacles/--horizons/--samples/--steps`` override its axes); ``--training``:
    :func:`benchmarks.training.benchmark_training`; ``--evaluation [N]``:
    :func:`benchmarks.evaluation.benchmark_evaluation` (N episodes per scenario and risk,
    default 300, 3 runs on each worker count); otherwise
    :func:`benchmarks.suite.run_benchmarks`.
    """
    if args.scaling:
        from benchmarks.scaling import FULL_GRID, QUICK_GRID
        from benchmarks.suite import run_scaling

        grid = QUICK_GRID if args.quick else FULL_GRID
        overrides = {name: tuple(values) for name, values in (
            ("obstacles", args.obstacles), ("horizons", args.horizons),
            ("samples", args.samples)) if values}
        if args.steps:
            overrides["steps"] = max(2, args.steps)
        grid = replace(grid, **overrides)
        print(run_scaling(grid, seed=args.seed, output=args.output, plot=not args.no_plot,
                          policy=not args.no_policy, family=args.family))
        return 0
    if args.evaluation:
        from benchmarks.evaluation import benchmark_evaluation

        print(benchmark_evaluation(args.evaluation, 3, progress=True).format())
        return 0
    if args.training:
        from benchmarks.training import benchmark_training

        print(benchmark_training(args.timesteps, args.chunk, args.seed,
                                 n_envs=args.envs).format())
        return 0
    from benchmarks.suite import run_benchmarks

    print(run_benchmarks(filter_steps=args.steps or 500, table_repeats=args.repeats,
                         seed=args.seed))
    return 0

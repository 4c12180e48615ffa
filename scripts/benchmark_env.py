"""Print the unfiltered environment's steps per second for each scenario.

Usage: ``python scripts/benchmark_env.py [--steps 5000] [--repeats 5] [--n-samples 100]
[--horizon 10] [--raw]``.
"""

from __future__ import annotations

import argparse
import platform
import sys

import numpy as np

from benchmarks.env import benchmark, normal_draws_per_second


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print one line per scenario; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5000, help="steps per timed run")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs (median reported)")
    parser.add_argument("--n-samples", type=int, default=100, help="prediction samples")
    parser.add_argument("--horizon", type=int, default=10, help="prediction horizon (steps)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--raw", action="store_true",
                        help="time env.unwrapped instead of the gym.make wrappers")
    args = parser.parse_args(argv)
    print(f"python {platform.python_version()}, numpy {np.__version__}, "
          f"n_samples={args.n_samples}, horizon={args.horizon}, "
          f"{'unwrapped' if args.raw else 'gym.make'}; "
          f"median of {args.repeats} x {args.steps} steps")
    results = benchmark(n_steps=args.steps, repeats=args.repeats, seed=args.seed, raw=args.raw,
                        n_samples=args.n_samples, horizon=args.horizon)
    width = max(map(len, results))
    for env_id, rate in results.items():
        print(f"{env_id:<{width}}  {rate:8.0f} steps/s  {1e6 / rate:7.1f} µs/step")
    normals = normal_draws_per_second()
    print(f"reference: numpy draws {normals / 1e6:.0f} M normals/s here, so the 6000 prediction "
          f"normals of a MultiObstacle step take {6000 / normals * 1e6:.1f} µs")
    return 0


if __name__ == "__main__":
    sys.exit(main())

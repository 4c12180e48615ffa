"""The ``safe-nav`` command line: train, evaluate, reproduce, bench.

Every subcommand is a thin layer over a plain function of :mod:`agents`, and
:func:`main` takes ``argv`` so tests call it directly. Defaults run on the PPO
policy shipped with the package, with no other set-up.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from agents.evaluation import PAPER_SCENARIOS, PLANNERS, REFERENCES
from filters.wrapper import RISKS

SCENARIO_IDS = {
    "HeadOn": "SafeNav/HeadOn-v0",
    "Overtaking": "SafeNav/Overtaking-v0",
    "Intersection": "SafeNav/Intersection-v0",
    "MultiObstacle": "SafeNav/MultiObstacle-v0",
    "RandomCrossing": "SafeNav/RandomCrossing-v0",
}


def scenario_id(name: str) -> str:
    """Accept ``HeadOn`` or ``SafeNav/HeadOn-v0``."""
    if name in SCENARIO_IDS:
        return SCENARIO_IDS[name]
    if name in SCENARIO_IDS.values():
        return name
    raise argparse.ArgumentTypeError(
        f"unknown scenario {name!r}; choose from {sorted(SCENARIO_IDS)}"
    )


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="safe-nav",
        description="DR-CVaR safety filtering of learned motion planners.",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    train = sub.add_parser("train", help="train a PPO reference planner")
    train.add_argument("--env-id", type=scenario_id, default="SafeNav/RandomCrossing-v0")
    train.add_argument("--timesteps", type=_positive_int, default=400_000)
    train.add_argument("--seed", type=int, default=0)
    train.add_argument("--n-envs", type=_positive_int, default=8)
    train.add_argument("--output", type=Path, default=Path("runs/ppo_random_crossing.zip"))
    train.add_argument("--filter", choices=[r for r in RISKS if r != "none"], default=None,
                       help="train with the safety filter in the loop (safe exploration)")
    train.add_argument("--intervention-penalty", type=float, default=0.0)
    train.add_argument("--eval-freq", type=int, default=0)
    train.add_argument("--tensorboard", type=str, default=None)
    train.add_argument("--no-progress", action="store_true")

    evaluate = sub.add_parser("evaluate", help="Monte Carlo: filtered vs unfiltered policies")
    _add_evaluation_arguments(evaluate, episodes=300)
    evaluate.add_argument("--sweep", action="store_true",
                          help="sweep epsilon and delta (DR-CVaR) and plot collisions vs deviation")
    evaluate.add_argument("--epsilons", type=float, nargs="+", default=[0.0, 0.05, 0.1, 0.2])
    evaluate.add_argument("--deltas", type=float, nargs="+", default=[0.0, 0.1, 0.2])

    reproduce = sub.add_parser("reproduce", help="reproduce the paper's figures and tables")
    reproduce.add_argument("--episodes", type=_positive_int, default=300)
    reproduce.add_argument("--workers", type=_positive_int, default=2)
    reproduce.add_argument("--seed", type=int, default=0)
    reproduce.add_argument("--output", type=Path, default=Path("results/reproduce"))
    reproduce.add_argument("--timing-repeats", type=_positive_int, default=100)
    reproduce.add_argument("--no-progress", action="store_true")

    bench = sub.add_parser("bench", help="speed benchmarks (ratios in one run)")
    bench.add_argument("--steps", type=_positive_int, default=None,
                       help="filter steps timed (default 500; --scaling: per grid point, 100)")
    bench.add_argument("--repeats", type=_positive_int, default=100)
    bench.add_argument("--scaling", action="store_true",
                       help="scaling grid: obstacles x horizon x samples, ours vs CVXPY")
    bench.add_argument("--quick", action="store_true", help="--scaling on a small subset")
    bench.add_argument("--obstacles", type=_positive_int, nargs="+", default=None)
    bench.add_argument("--horizons", type=_positive_int, nargs="+", default=None)
    bench.add_argument("--samples", type=_positive_int, nargs="+", default=None)
    bench.add_argument("--seed", type=int, default=0)
    bench.add_argument("--output", type=Path, default=None,
                       help="--scaling: folder for scaling.csv, scaling.md, scaling.png")
    bench.add_argument("--no-plot", action="store_true")
    bench.add_argument("--no-policy", action="store_true",
                       help="--scaling: skip the policy (SB3 vs numpy) timings")
    return parser


def _add_evaluation_arguments(parser: argparse.ArgumentParser, *, episodes: int) -> None:
    parser.add_argument("--scenarios", type=scenario_id, nargs="+", default=list(PAPER_SCENARIOS))
    parser.add_argument("--risks", choices=RISKS, nargs="+", default=list(RISKS))
    parser.add_argument("--planner", choices=PLANNERS, default="ppo")
    parser.add_argument("--reference", choices=REFERENCES, default="rollout")
    parser.add_argument("--policy", type=str, default="", help="PPO .zip (default: shipped)")
    parser.add_argument("--episodes", type=_positive_int, default=episodes)
    parser.add_argument("--workers", type=_positive_int, default=2)
    parser.add_argument("--executor", choices=("process", "ray"), default="process")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--alpha", type=float, default=0.2)
    parser.add_argument("--delta", type=float, default=0.1)
    parser.add_argument("--epsilon", type=float, default=0.05)
    parser.add_argument("--noise", default="",
                        help="noise preset of the environment, e.g. authors_code "
                        "(default: the scenario's, as in the paper's text)")
    parser.add_argument("--output", type=Path, default=Path("results/evaluate"))
    parser.add_argument("--no-plots", action="store_true")
    parser.add_argument("--no-progress", action="store_true")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``safe-nav``; returns the exit code."""
    args = build_parser().parse_args(argv)
    if args.command == "train":
        return _train(args)
    if args.command == "evaluate":
        return _evaluate(args)
    if args.command == "reproduce":
        from agents.reproduce import reproduce

        print(reproduce(output=args.output, episodes=args.episodes, workers=args.workers,
                        seed=args.seed, timing_repeats=args.timing_repeats,
                        progress=not args.no_progress))
        return 0
    if args.command == "bench":
        if args.scaling:
            return _bench_scaling(args)
        from agents.bench import run_benchmarks

        print(run_benchmarks(filter_steps=args.steps or 500, table_repeats=args.repeats,
                             seed=args.seed))
        return 0
    return 2  # pragma: no cover - argparse rejects unknown commands


def _evaluate(args: argparse.Namespace) -> int:
    from agents.experiments import run_evaluation, run_sweep

    common = dict(episodes=args.episodes, workers=args.workers, seed=args.seed,
                  planner=args.planner, reference=args.reference, policy_path=args.policy,
                  alpha=args.alpha, noise=args.noise, executor=args.executor,
                  progress=not args.no_progress)
    if args.sweep:
        outputs = run_sweep(args.output, args.scenarios, epsilons=args.epsilons,
                            deltas=args.deltas, **common)
    else:
        outputs = run_evaluation(args.output, args.scenarios, args.risks, delta=args.delta,
                                 epsilon=args.epsilon, plots=not args.no_plots, **common)
    print(outputs)
    return 0


def _bench_scaling(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from agents.bench import run_scaling
    from filters.benchmarks.scaling import FULL_GRID, QUICK_GRID

    grid = QUICK_GRID if args.quick else FULL_GRID
    overrides = {name: tuple(values) for name, values in (
        ("obstacles", args.obstacles), ("horizons", args.horizons), ("samples", args.samples))
        if values}
    if args.steps:
        overrides["steps"] = max(2, args.steps)
    grid = replace(grid, **overrides)
    print(run_scaling(grid, seed=args.seed, output=args.output, plot=not args.no_plot,
                      policy=not args.no_policy))
    return 0


def _train(args: argparse.Namespace) -> int:
    from agents.training import train_ppo

    filter_kwargs = {"risk": args.filter} if args.filter else None
    _, report = train_ppo(
        args.env_id, args.timesteps, args.seed, n_envs=args.n_envs, filter_kwargs=filter_kwargs,
        intervention_penalty=args.intervention_penalty, eval_freq=args.eval_freq,
        tensorboard_log=args.tensorboard, progress_bar=not args.no_progress,
        save_path=args.output,
    )
    print(f"trained {report.total_timesteps} steps in {report.wall_time:.1f} s "
          f"({report.steps_per_second:.0f} steps/s); saved to {report.save_path}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

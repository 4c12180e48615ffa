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
from filters.wrapper import FALLBACKS, OBJECTIVES, RISKS

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


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="safe-nav",
        description="DR-CVaR safety filtering of learned motion planners.",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    train = sub.add_parser(
        "train", help="train a PPO reference planner (plain, filter in the loop, or Lagrangian)",
        description="Train PPO on a SafeNav scenario and print its safety metrics (episode "
        "collision rate in continuous time, episode cost, goal rate, filter intervention and "
        "statuses) after every rollout; they are also written to <output>.metrics.csv.")
    train.add_argument("--env-id", type=scenario_id, default="SafeNav/RandomCrossing-v0")
    train.add_argument("--timesteps", type=_positive_int, default=400_000)
    train.add_argument("--seed", type=_non_negative_int, default=0)
    train.add_argument("--n-envs", type=_positive_int, default=8)
    train.add_argument("--vec-env", choices=("dummy", "subproc"), default="dummy",
                       help="in-process environments (default) or one process each")
    train.add_argument("--output", type=Path, default=Path("runs/ppo_random_crossing.zip"))
    train.add_argument("--filter", choices=[r for r in RISKS if r != "none"], default=None,
                       help="train with the safety filter in the loop (safe exploration)")
    train.add_argument("--alpha", type=float, default=None,
                       help="filter: CVaR tail mass in (0, 1] (default: the wrapper's)")
    train.add_argument("--delta", type=float, default=None,
                       help="filter: risk bound on the intrusion depth, m (default: the wrapper's)")
    train.add_argument("--epsilon", type=float, default=None,
                       help="filter: Wasserstein radius, m (default: the wrapper's)")
    train.add_argument("--objective", choices=OBJECTIVES, default=None,
                       help="filter objective (default: the wrapper's choice for the planner)")
    train.add_argument("--fallback", choices=FALLBACKS, default=None,
                       help="filter fallback on an infeasible QP (default: the wrapper's)")
    train.add_argument("--reference", choices=("default", "rollout"), default="default",
                       help="filter reference: the wrapper's, or the policy being trained "
                       "rolled out over the horizon")
    train.add_argument("--filter-option", action="append", default=[], metavar="KEY=VALUE",
                       help="any other keyword of SafetyFilterWrapper; VALUE is read as JSON "
                       "(numbers, true/false, lists), else as a string; repeatable")
    train.add_argument("--intervention-penalty", type=float, default=0.0,
                       help="filter: reward penalty per (m/s^2)^2 of ||u_safe - u_ref||^2")
    train.add_argument("--lagrangian", action="store_true",
                       help="train PPO-Lagrangian (cost: the continuous-time collision indicator)")
    train.add_argument("--cost-limit", type=float, default=0.0,
                       help="PPO-Lagrangian: allowed mean episode cost (default 0)")
    train.add_argument("--lambda-lr", type=float, default=0.05,
                       help="PPO-Lagrangian: dual step size of the multiplier")
    train.add_argument("--eval-freq", type=_non_negative_int, default=0,
                       help="evaluate every N steps on held-out seeds (0: off); saves the best "
                       "model to <output>_best/")
    train.add_argument("--eval-episodes", type=_positive_int, default=20)
    train.add_argument("--tensorboard", type=str, default=None, metavar="DIR",
                       help="write TensorBoard event files to DIR (pip install 'safe-nav[train]')")
    train.add_argument("--physical-actions", action="store_true",
                       help="let the learner act on the ±10 m/s² box instead of [-1, 1] (as the "
                       "shipped policy was trained)")
    train.add_argument("--quiet", action="store_true", help="do not print the metrics table")
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
    bench.add_argument("--steps", type=_positive_int, default=500)
    bench.add_argument("--repeats", type=_positive_int, default=100)
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
        from agents.bench import run_benchmarks

        print(run_benchmarks(filter_steps=args.steps, table_repeats=args.repeats))
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


def _filter_options(args: argparse.Namespace) -> dict:
    """The SafetyFilterWrapper keywords given on the command line."""
    import json

    options: dict = {}
    for text in args.filter_option:
        key, sep, raw = text.partition("=")
        if not sep or not key.isidentifier():
            raise ValueError(f"--filter-option expects KEY=VALUE, got {text!r}")
        try:
            options[key] = json.loads(raw)
        except json.JSONDecodeError:
            options[key] = raw
    for name in ("alpha", "delta", "epsilon", "objective", "fallback"):
        value = getattr(args, name)
        if value is not None:
            options[name] = value
    return options


def _train(args: argparse.Namespace) -> int:
    from agents.training import train_ppo

    try:
        options = _filter_options(args)
    except ValueError as exc:
        print(f"safe-nav train: error: {exc}", file=sys.stderr)
        return 2
    if args.filter is None and (options or args.reference != "default"
                                or args.intervention_penalty):
        print("safe-nav train: error: --alpha/--delta/--epsilon/--objective/--fallback/"
              "--reference/--filter-option/--intervention-penalty need --filter",
              file=sys.stderr)
        return 2
    if not args.lagrangian and (args.cost_limit != 0.0 or args.lambda_lr != 0.05):
        print("safe-nav train: error: --cost-limit/--lambda-lr need --lagrangian",
              file=sys.stderr)
        return 2
    from filters.errors import SafeNavError

    filter_kwargs = {"risk": args.filter, **options} if args.filter else None
    try:
        _, report = train_ppo(
            args.env_id, args.timesteps, args.seed, n_envs=args.n_envs,
            filter_kwargs=filter_kwargs, intervention_penalty=args.intervention_penalty,
            filter_reference=args.reference, lagrangian=args.lagrangian,
            cost_limit=args.cost_limit, lambda_lr=args.lambda_lr, eval_freq=args.eval_freq,
            eval_episodes=args.eval_episodes, vec_env=args.vec_env,
            tensorboard_log=args.tensorboard, print_metrics=not args.quiet,
            normalise_actions=not args.physical_actions,
            progress_bar=not args.no_progress, save_path=args.output,
        )
    except SafeNavError as exc:  # bad options, found before any training
        print(f"safe-nav train: error: {exc}", file=sys.stderr)
        return 2
    print(f"trained {report.total_timesteps} steps in {report.wall_time:.1f} s "
          f"({report.steps_per_second:.0f} steps/s); saved to {report.save_path}; "
          f"metrics in {report.metrics_path}")
    if report.safety:
        print("last rollout: " + ", ".join(f"{k} {v:.3g}" for k, v in report.safety.items()))
    if report.lagrange_multiplier is not None:
        print(f"final Lagrange multiplier {report.lagrange_multiplier:.4g}")
    if report.best_model_path is not None:
        print(f"best model (evaluation return) in {report.best_model_path}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

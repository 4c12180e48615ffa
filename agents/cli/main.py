"""The ``safe-nav`` command line: train, evaluate, reproduce, bench.

Every subcommand is a thin layer over a plain function of :mod:`agents`, and
:func:`main` takes ``argv`` so tests call it directly. Defaults run on the PPO
policy shipped with the package, with no other set-up. ``safe-nav evaluate --help``
shows every option with its default and unit.

Exit codes (one line on stderr, no traceback):

* 0 -- done;
* 1 -- some episode failed (the CSV's ``error`` column says why; running the same
  command again re-runs the failed episodes), or the workers kept dying or the Ray
  cluster could not be reached (the finished episodes are saved);
* 2 -- a bad option or setting, a missing or corrupt policy file, an output path
  that is a file, an output folder holding another run;
* 130 -- Ctrl-C (the finished episodes are saved; the same command resumes).
"""

from __future__ import annotations

import argparse
import inspect
import itertools
import json
import math
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from agents.evaluation.records import PAPER_SCENARIOS, PLANNERS, REFERENCES, package_version
from filters.config import FIELDS, RISKS, FilterConfig
from filters.risk import PAPER_RISKS

_CUSTOM_EXAMPLE = ('{"name": "mine", "ego_start": [-4, 0], "goal": [4, 0], "obstacles": '
                   '[{"start": [2, 0], "velocity": [-1, 0]}]}')
"""A scenario of ``--scenarios Custom`` given on the command line (the fields of
:class:`safe_nav_env.Scenario` as JSON)."""

EXIT_FAILED_EPISODES = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130


def _canonical_scenario(name: str, *, gym_id_ok: bool = False) -> str:
    from safe_nav_env.errors import ScenarioError
    from safe_nav_env.scenarios import env_id, scenario_name

    try:
        canonical = scenario_name(name, warn=False)
    except ScenarioError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    if canonical != name and not (gym_id_ok and name == env_id(canonical)):
        print(f"safe-nav: note: scenario {name!r} is called {canonical!r}; use {canonical!r}",
              file=sys.stderr)
    return canonical


def scenario_id(name: str) -> str:
    """The gym id of a scenario spelled ``HeadOn``, ``head_on`` or ``SafeNav/HeadOn-v0``."""
    from safe_nav_env.scenarios import env_id

    return env_id(_canonical_scenario(name, gym_id_ok=True))


def scenario(name: str) -> str:
    """The canonical name (``HeadOn``) of a scenario in any of its spellings."""
    return _canonical_scenario(name)


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from None
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


_seed = _non_negative_int


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def _metres(text: str) -> float:
    value = _number(text)
    if value < 0.0:
        raise argparse.ArgumentTypeError(f"expected a distance >= 0 (in m), got {text!r}")
    return value


def _noise(text: str) -> str:
    from safe_nav_env import NOISE_PRESETS

    if text and text not in NOISE_PRESETS:
        raise argparse.ArgumentTypeError(
            f"unknown noise preset {text!r}; choose one of {sorted(NOISE_PRESETS)} (or '' for "
            "the scenario's own)")
    return text


def _policy(text: str) -> str:
    from agents.errors import PolicyFileError
    from agents.evaluation.runner import check_policy

    if not text:  # the shipped policy: checked (and loaded) before the run, if the PPO runs
        return text
    try:
        check_policy(text)
    except PolicyFileError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def _output(text: str) -> Path:
    from agents.errors import OutputPathError
    from agents.evaluation.evaluate import output_folder

    try:
        return output_folder(text)
    except OutputPathError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _json(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def _filter_setting(name: str) -> Any:
    """An argparse type: the value of :class:`filters.FilterConfig`'s ``name``, checked there."""
    from filters.errors import SafeNavError

    def parse(text: str) -> Any:
        try:
            return getattr(FilterConfig(**{name: _json(text)}), name)
        except SafeNavError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    return parse


def _setting_help(name: str) -> str:
    """The first clause of ``name``'s entry in FilterConfig's docstring, its one description."""
    lines = inspect.getdoc(FilterConfig).split(f"\n{name}\n", 1)[1].splitlines()
    text = " ".join(line.strip() for line in itertools.takewhile(
        lambda line: line.startswith("    "), lines))
    return re.split(r"[.;:](?:\s|$)", text)[0].replace("``", "").replace("%", "%%")


def add_filter_flags(parser: argparse.ArgumentParser, names: Sequence[str], *,
                     defaults: bool) -> None:
    """``--name`` for the given fields of :class:`filters.FilterConfig`: its help, choices
    and checks; the config's defaults (``defaults``) or ``None`` ("not given")."""
    for name in names:
        field = FIELDS[name]
        parser.add_argument(
            f"--{name.replace('_', '-')}", type=_filter_setting(name),
            choices=field.metadata.get("choices"), default=field.default if defaults else None,
            help=_setting_help(name) + ("" if defaults else " (default: the wrapper's)"))


def filter_config(args: argparse.Namespace, risk: str, names: Sequence[str]) -> FilterConfig:
    """The one :class:`filters.FilterConfig` of a command line: ``risk``, the
    ``--filter-option`` settings, then the filter flags ``names`` that were given."""
    given = {name: getattr(args, name) for name in names if getattr(args, name) is not None}
    return FilterConfig.from_dict({**dict(args.filter_options), **given, "risk": risk})


_TRAIN_FILTER_FLAGS = ("alpha", "delta", "epsilon", "objective", "fallback",
                       "intervention_penalty")
_EVALUATE_FILTER_FLAGS = ("alpha", "delta", "epsilon")


def _option(text: str) -> tuple[str, Any]:
    key, sep, raw = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    return key, _json(raw)


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (no usage block)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


_FORMAT = dict(formatter_class=argparse.ArgumentDefaultsHelpFormatter)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="safe-nav",
        description="DR-CVaR safety filtering of learned motion planners.",
    )
    parser.add_argument("--version", action="version", version=f"safe-nav {package_version()}",
                        help="print the installed package's version and exit")
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
    add_filter_flags(train, _TRAIN_FILTER_FLAGS, defaults=False)
    train.add_argument("--reference", choices=("default", "rollout"), default="default",
                       help="filter reference: the wrapper's, or the policy being trained "
                       "rolled out over the horizon")
    train.add_argument("--filter-option", type=_option, action="append", default=[],
                       metavar="KEY=VALUE", dest="filter_options",
                       help="any other field of filters.FilterConfig; VALUE is read as JSON "
                       "(numbers, true/false, lists), else as a string; repeatable")
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
    train.add_argument("--env-option", type=_option, action="append", default=[],
                       metavar="KEY=VALUE", dest="env_options",
                       help="gym.make keyword of the training environments (VALUE as JSON, else "
                       "a string), e.g. random_start=0.5 or time_penalty=0.05; repeatable")
    train.add_argument("--physical-actions", action="store_true",
                       help="let the learner act on the ±10 m/s² box instead of [-1, 1] (as the "
                       "shipped policy was trained)")
    train.add_argument("--quiet", action="store_true", help="do not print the metrics table")
    train.add_argument("--no-progress", action="store_true")

    evaluate = sub.add_parser("evaluate", help="Monte Carlo: filtered vs unfiltered policies",
                              **_FORMAT)
    _add_evaluation_arguments(evaluate, episodes=300)
    evaluate.add_argument("--sweep", action="store_true",
                          help="sweep epsilon and delta (DR-CVaR) and plot collisions vs "
                          "deviation (writes sweep.csv, sweep.md, figures/sweep.png)")
    evaluate.add_argument("--epsilons", type=_metres, nargs="+", default=[0.0, 0.05, 0.1, 0.2],
                          help="--sweep: Wasserstein radii, in m (>= 0)")
    evaluate.add_argument("--deltas", type=_metres, nargs="+", default=[0.0, 0.1, 0.2],
                          help="--sweep: risk bounds, in m (>= 0)")
    from agents.experiments.crowd import CROWD_SETTINGS
    from agents.experiments.pedestrians import PEDESTRIAN_SETTINGS
    from agents.experiments.stress import (
        DEFAULT_CASES,
        DEFAULT_METHODS,
        DEFAULT_PLANNERS,
        STRESS_METHODS,
    )
    from safe_nav_env.stress import STRESS_SUITE

    evaluate.add_argument("--suite", choices=("scenarios", "stress", "crowd", "pedestrians"),
                          default="scenarios",
                          help="scenarios: --scenarios x --risks; stress: the stress table by "
                          "failure class (--cases x --planners x --methods, output default "
                          "results/stress); crowd: "
                          "CrowdNav's circle crossing (--crowd-settings x --risks, "
                          "--episodes test cases, output default results/crowd); "
                          "pedestrians: the ETH/UCY scenes (--scenes x --risks, output "
                          "default results/pedestrians)")
    evaluate.add_argument("--scenes", choices=list(PEDESTRIAN_SETTINGS), nargs="+",
                          default=list(PEDESTRIAN_SETTINGS),
                          help="--suite pedestrians: the recorded scenes")
    evaluate.add_argument("--crowd-settings", choices=list(CROWD_SETTINGS), nargs="+",
                          default=["orca_invisible"],
                          help="--suite crowd: human model and robot visibility")
    evaluate.add_argument("--cases", choices=list(STRESS_SUITE), nargs="+",
                          default=list(DEFAULT_CASES), help="--suite stress: the failure classes")
    evaluate.add_argument("--methods", choices=list(STRESS_METHODS), nargs="+",
                          default=list(DEFAULT_METHODS),
                          help="--suite stress: the filter settings (default: the wrapper's "
                          "defaults, action held; dr_cvar: fixed --epsilon; dr_cvar_auto: "
                          "epsilon='auto'; all but default track --reference)")
    evaluate.add_argument("--planners", choices=list(PLANNERS), nargs="+",
                          default=list(DEFAULT_PLANNERS),
                          help="--suite stress: the reference planners (goal: the "
                          "obstacle-blind go-to-goal controller; --planner mpc or goal "
                          "alone replaces them)")

    reproduce = sub.add_parser("reproduce", help="reproduce the paper's figures and tables",
                               **_FORMAT)
    reproduce.add_argument("--episodes", type=_positive_int, default=300,
                           help="Monte Carlo episodes per scenario and risk (>= 1)")
    reproduce.add_argument("--workers", type=_positive_int, default=2,
                           help="local worker processes (>= 1)")
    reproduce.add_argument("--seed", type=_seed, default=0,
                           help="seed of the first episode (episode i uses seed + i)")
    reproduce.add_argument("--output", type=_output, default=Path("results/reproduce"),
                           help="output folder")
    reproduce.add_argument("--timing-repeats", type=_positive_int, default=100,
                           help="repeats of each Table I timing (>= 1)")
    reproduce.add_argument("--no-progress", action="store_true", help="no progress bar")

    bench = sub.add_parser("bench", help="speed benchmarks (ratios in one run)", **_FORMAT)
    from benchmarks.command import add_arguments

    add_arguments(bench, positive_int=_positive_int, seed=_seed)
    return parser


def _add_evaluation_arguments(parser: argparse.ArgumentParser, *, episodes: int) -> None:
    parser.add_argument("--scenarios", type=scenario, nargs="+", default=list(PAPER_SCENARIOS),
                        help="scenario names (HeadOn, Overtaking, Intersection, MultiObstacle, "
                        "RandomCrossing; Custom with --env-option scenario=JSON, a "
                        "safe_nav_env.Scenario's fields, e.g. "
                        f"scenario='{_CUSTOM_EXAMPLE}')")
    parser.add_argument("--risks", choices=RISKS, nargs="+",
                        default=["none", *PAPER_RISKS],
                        help="risk settings; none is the unfiltered planner (the default is "
                        "the paper's comparison; gaussian_cc, moment_dr and conformal on "
                        "request)")
    parser.add_argument("--planner", choices=PLANNERS, default="ppo",
                        help="reference planner: the PPO policy, the paper's "
                        "obstacle-agnostic MPC or the obstacle-blind go-to-goal controller")
    parser.add_argument("--reference", choices=REFERENCES, default="rollout",
                        help="PPO reference trajectory: roll the policy out on the predicted "
                        "obstacle motion, or hold its action")
    parser.add_argument("--policy", type=_policy, default="",
                        help="PPO policy .zip (default: the shipped one)%(default).0s")
    parser.add_argument("--episodes", type=_positive_int, default=episodes,
                        help="episodes per scenario and risk (>= 1)")
    parser.add_argument("--workers", type=_positive_int, default=2,
                        help="local worker processes (>= 1; 1 runs in this process)")
    parser.add_argument("--executor", choices=("process", "ray"), default="process",
                        help="where episodes run: local processes or a Ray cluster")
    parser.add_argument("--address", default=None, metavar="HOST:PORT",
                        help="--executor ray: the cluster to run on, HOST:PORT of its head "
                        "(ray start --head --port=PORT) or auto (the one started on this "
                        "machine); default: RAY_ADDRESS if set, else a local Ray")
    parser.add_argument("--seed", type=_seed, default=0,
                        help="seed of the first episode (episode i uses seed + i)")
    add_filter_flags(parser, _EVALUATE_FILTER_FLAGS, defaults=True)
    parser.add_argument("--noise", type=_noise, default="",
                        help="noise preset of the environment, e.g. authors_code (default: the "
                        "scenario's own, as in the paper's text)%(default).0s")
    parser.add_argument("--filter-option", type=_option, action="append", default=[],
                        metavar="KEY=VALUE", dest="filter_options",
                        help="further SafetyFilterWrapper keyword (VALUE as JSON, else a "
                        "string), e.g. soft=true; repeatable (default: none)%(default).0s")
    parser.add_argument("--env-option", type=_option, action="append", default=[],
                        metavar="KEY=VALUE", dest="env_options",
                        help="further gym.make keyword, e.g. n_samples=50; repeatable "
                        "(default: none)%(default).0s")
    parser.add_argument("--output", type=_output, default=Path("results/evaluate"),
                        help="output folder (CSV, run key, summary, figures)")
    parser.add_argument("--overwrite", action="store_true",
                        help="discard the results already in --output instead of resuming")
    parser.add_argument("--no-plots", action="store_true", help="no figures")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``safe-nav``; returns the exit code (see the module docstring)."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help (0) or a bad option (2, one line already printed)
        return exc.code if isinstance(exc.code, int) else EXIT_BAD_INPUT
    prog = f"safe-nav {args.command}"
    try:
        return _dispatch(args)
    except KeyboardInterrupt as exc:
        print(_interrupted_message(prog, exc, args), file=sys.stderr)
        return EXIT_INTERRUPTED
    except _bad_input_errors() as exc:
        from agents.errors import WorkersLostError

        print(f"{prog}: error: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}",
              file=sys.stderr)
        return EXIT_FAILED_EPISODES if isinstance(exc, WorkersLostError) else EXIT_BAD_INPUT


def _bad_input_errors() -> tuple[type[BaseException], ...]:
    from agents.errors import AgentsError
    from filters.errors import SafeNavError
    from safe_nav_env.errors import SafeNavEnvError

    return (AgentsError, SafeNavError, SafeNavEnvError)


def _interrupted_message(prog: str, exc: KeyboardInterrupt, args: argparse.Namespace) -> str:
    from agents.evaluation.evaluate import EvaluationInterrupted

    if isinstance(exc, EvaluationInterrupted) and exc.csv_path is not None:
        reused = f" ({exc.reused} of them reused from an earlier run)" if exc.reused else ""
        return (f"{prog}: interrupted: {exc.finished} of {exc.total} episodes finished{reused}, "
                f"saved in {exc.csv_path}; run the same command again to resume")
    where = f" in {args.output}" if getattr(args, "output", None) else ""
    return (f"{prog}: interrupted; the finished episodes are saved{where}; run the same command "
            "again to resume")


def _dispatch(args: argparse.Namespace) -> int:
    if args.command == "train":
        return _train(args)
    if args.command == "evaluate":
        return _evaluate(args)
    if args.command == "reproduce":
        from agents.experiments.reproduce import reproduce

        print(reproduce(output=args.output, episodes=args.episodes, workers=args.workers,
                        seed=args.seed, timing_repeats=args.timing_repeats,
                        progress=not args.no_progress))
        return 0
    if args.command == "bench":
        from benchmarks.command import run  # the one import of benchmarks: on demand

        return run(args)
    return EXIT_BAD_INPUT  # pragma: no cover - argparse rejects unknown commands


def _evaluation_config(args: argparse.Namespace):
    """The command's :class:`~agents.evaluation.config.EvaluationConfig` (a suite's output
    folder is ``results/<suite>`` unless ``--output`` is given)."""
    from agents.evaluation.config import EvaluationConfig

    output = args.output
    if args.suite != "scenarios" and output == Path("results/evaluate"):
        output = Path(f"results/{args.suite}")
    return EvaluationConfig(output=output, workers=args.workers, executor=args.executor,
                            address=args.address, overwrite=args.overwrite,
                            plots=not args.no_plots, progress=not args.no_progress)


def _evaluate(args: argparse.Namespace) -> int:
    from agents.evaluation.campaign import run_evaluation, run_sweep
    from safe_nav_env.scenarios import CUSTOM

    if (args.suite == "scenarios" and CUSTOM in args.scenarios
            and "scenario" not in dict(args.env_options)):
        print(f"safe-nav evaluate: error: --scenarios {CUSTOM} needs its scenario: add "
              f"--env-option scenario='{_CUSTOM_EXAMPLE}' (the fields of "
              "safe_nav_env.Scenario as JSON) or --env-option scenario=HeadOn (a scenario "
              "name)", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.suite != "scenarios":
        clash = [flag for flag, given in (
            ("--sweep", args.sweep), ("--noise", args.noise),
            ("--scenarios", args.scenarios != list(PAPER_SCENARIOS)),
            ("--risks", args.suite == "stress" and args.risks != ["none", *PAPER_RISKS]))
            if given]
        if clash:
            sets, use = (("the cases, methods and noise", "--cases/--methods")
                         if args.suite == "stress" else
                         ("the scene", "--crowd-settings" if args.suite == "crowd"
                          else "--scenes"))
            print(f"safe-nav evaluate: error: --suite {args.suite} sets {sets} itself; drop "
                  f"{', '.join(clash)} (use {use})", file=sys.stderr)
            return EXIT_BAD_INPUT

    common = dict(config=_evaluation_config(args), episodes=args.episodes,
                  seed=args.seed, reference=args.reference, policy_path=args.policy,
                  alpha=args.alpha, filter_options=dict(args.filter_options),
                  env_options=dict(args.env_options))
    if args.suite == "stress":
        from agents.experiments.stress import run_stress

        # One --planner other than ppo replaces --planners.
        planners = args.planners if args.planner == "ppo" else [args.planner]
        outputs = run_stress(None, args.cases, args.methods, planners=planners,
                             delta=args.delta, epsilon=args.epsilon, **common)
    elif args.suite in ("crowd", "pedestrians"):
        from agents.experiments.crowd import run_crowd
        from agents.experiments.pedestrians import run_pedestrians

        run, settings = ((run_crowd, args.crowd_settings) if args.suite == "crowd"
                         else (run_pedestrians, args.scenes))
        outputs = run(None, settings, args.risks, planner=args.planner, delta=args.delta,
                      epsilon=args.epsilon, **common)
    elif args.sweep:
        outputs = run_sweep(None, args.scenarios, epsilons=args.epsilons, deltas=args.deltas,
                            planner=args.planner, noise=args.noise, **common)
    else:
        outputs = run_evaluation(None, args.scenarios, args.risks, planner=args.planner,
                                 delta=args.delta, epsilon=args.epsilon, noise=args.noise,
                                 **common)
    print(outputs)
    failed = outputs.failed
    if failed:
        first = failed[0]
        print(f"safe-nav evaluate: error: {len(failed)} of {len(outputs.records)} episodes "
              f"failed (first: {first.case or first.scenario} {first.risk} seed {first.seed}: "
              f"{first.error.split(' | ')[0][:200]}); see the error column of "
              f"{outputs.files['episodes']}; run the same command again to re-run them",
              file=sys.stderr)
        return EXIT_FAILED_EPISODES
    return 0


def _train(args: argparse.Namespace) -> int:
    from agents.training.ppo import train_ppo

    given = [f"--{name.replace('_', '-')}" for name in _TRAIN_FILTER_FLAGS
             if getattr(args, name) is not None]
    given += ["--filter-option"] * bool(args.filter_options) + ["--reference"] * (
        args.reference != "default")
    if args.filter is None and given:
        print(f"safe-nav train: error: {', '.join(given)} need --filter", file=sys.stderr)
        return 2
    if not args.lagrangian and (args.cost_limit != 0.0 or args.lambda_lr != 0.05):
        print("safe-nav train: error: --cost-limit/--lambda-lr need --lagrangian",
              file=sys.stderr)
        return 2
    from filters.errors import SafeNavError

    try:
        config = filter_config(args, args.filter, _TRAIN_FILTER_FLAGS) if args.filter else None
        _, report = train_ppo(
            args.env_id, args.timesteps, args.seed, n_envs=args.n_envs,
            env_kwargs=dict(args.env_options), filter_kwargs=config,
            filter_reference=args.reference,
            lagrangian=args.lagrangian,
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

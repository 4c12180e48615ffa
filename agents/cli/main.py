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
from collections.abc import Callable, Sequence
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


def _argument_type(check: Callable[[str], Any]) -> Callable[[str], Any]:
    """An argparse type calling ``check``: its error (the project's errors are ValueErrors
    or TypeErrors, naming the value) becomes argparse's one-line error."""

    def parse(text: str) -> Any:
        try:
            return check(text)
        except (ValueError, TypeError) as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    return parse


def _at_least(convert: Callable[[str], float], low: int, what: str) -> Callable[[str], Any]:
    """An argparse type: a finite ``convert(text) >= low`` (``what`` names it in the error)."""

    def parse(text: str) -> Any:
        try:
            value = convert(text)
        except ValueError:
            value = math.nan
        if not low <= value < math.inf:  # nan too
            raise argparse.ArgumentTypeError(f"expected {what} >= {low}, got {text!r}")
        return value

    return parse


_positive_int, _seed = _at_least(int, 1, "an integer"), _at_least(int, 0, "an integer")
_metres = _at_least(float, 0, "a distance in m")


def _canonical_scenario(name: str, *, gym_id_ok: bool = False) -> str:
    """The canonical name (``HeadOn``) of a scenario in any of its spellings, with a note
    on stderr for another spelling (the gym id too, unless ``gym_id_ok``)."""
    from safe_nav_env.scenarios import env_id, scenario_name

    canonical = scenario_name(name, warn=False)
    if canonical != name and not (gym_id_ok and name == env_id(canonical)):
        print(f"safe-nav: note: scenario {name!r} is called {canonical!r}; use {canonical!r}",
              file=sys.stderr)
    return canonical


def scenario_id(name: str) -> str:
    """The gym id of a scenario spelled ``HeadOn``, ``head_on`` or ``SafeNav/HeadOn-v0``."""
    from safe_nav_env.scenarios import env_id

    return env_id(_canonical_scenario(name, gym_id_ok=True))


def _policy(text: str) -> str:
    """A ``--policy`` file, checked; ``""`` (the shipped one) is checked when the PPO runs."""
    from agents.evaluation.policy_files import check_policy

    return text and check_policy(text) and text


def _json(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def _option(text: str) -> tuple[str, Any]:
    key, sep, raw = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    return key, _json(raw)


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
        parser.add_argument(
            f"--{name.replace('_', '-')}", choices=FIELDS[name].metadata.get("choices"),
            type=_argument_type(lambda text, name=name: getattr(
                FilterConfig(**{name: _json(text)}), name)),
            default=FIELDS[name].default if defaults else None,
            help=_setting_help(name) + ("" if defaults else " (default: the wrapper's)"))


def filter_config(args: argparse.Namespace, risk: str, names: Sequence[str]) -> FilterConfig:
    """The one :class:`filters.FilterConfig` of a command line: ``risk``, the
    ``--filter-option`` settings, then the filter flags ``names`` that were given."""
    given = {name: getattr(args, name) for name in names if getattr(args, name) is not None}
    return FilterConfig.from_dict({**dict(args.filter_option), **given, "risk": risk})


def _given(args: argparse.Namespace, *names: str) -> list[str]:
    """The flags ``--name`` among ``names`` (their argparse dests) whose value differs
    from their subcommand's default."""
    return [f"--{name.replace('_', '-')}" for name in names
            if getattr(args, name) != args.parser.get_default(name)]


_TRAIN_FILTER_FLAGS = ("alpha", "delta", "epsilon", "objective", "fallback",
                       "intervention_penalty")


def _add_options(parser: argparse.ArgumentParser, kind: str, help: str) -> None:
    """The repeatable ``--{kind}-option KEY=VALUE`` (VALUE as JSON, else a string), a list
    of ``(KEY, VALUE)`` in ``args.{kind}_option``."""
    parser.add_argument(f"--{kind}-option", type=_option, action="append", default=[],
                        metavar="KEY=VALUE", help=f"{help} (VALUE as JSON, else a string); "
                        "repeatable")


def _add_run_flags(parser: argparse.ArgumentParser, *, episodes: int, output: str) -> None:
    """The flags of ``evaluate`` and ``reproduce``: how many episodes, where they run and go."""
    from agents.evaluation.evaluate import output_folder

    parser.add_argument("--episodes", type=_positive_int, default=episodes,
                        help="Monte Carlo episodes per scenario and risk (>= 1)")
    parser.add_argument("--workers", type=_positive_int, default=2,
                        help="local worker processes (>= 1; 1 runs in this process)")
    parser.add_argument("--seed", type=_seed, default=0,
                        help="seed of the first episode (episode i uses seed + i)")
    parser.add_argument("--output", type=_argument_type(output_folder), default=Path(output),
                        help="output folder (CSV, run key, summary, figures)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (no usage block)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    from agents.evaluation.executors import EXECUTORS
    from agents.experiments import crowd, pedestrians, stress
    from agents.training.ppo import FILTER_REFERENCES, VEC_ENVS, train_ppo
    from benchmarks.command import add_arguments, run
    from safe_nav_env import NOISE_PRESETS
    from safe_nav_env.stress import STRESS_SUITE

    parser = _Parser(prog="safe-nav",
                     description="DR-CVaR safety filtering of learned motion planners.")
    parser.add_argument("--version", action="version", version=f"safe-nav {package_version()}",
                        help="print the installed package's version and exit")
    sub = parser.add_subparsers(dest="command", required=True)
    formatted = dict(formatter_class=argparse.ArgumentDefaultsHelpFormatter)

    train = sub.add_parser(
        "train", help="train a PPO reference planner (plain, filter in the loop, or Lagrangian)",
        description="Train PPO on a SafeNav scenario and print its safety metrics (episode "
        "collision rate in continuous time, episode cost, goal rate, filter intervention and "
        "statuses) after every rollout; they are also written to <output>.metrics.csv.")
    train.set_defaults(run=_train, parser=train)
    ppo = {name: p.default for name, p in inspect.signature(train_ppo).parameters.items()}
    train.add_argument("--env-id", type=_argument_type(scenario_id), default=ppo["env_id"])
    train.add_argument("--timesteps", type=_positive_int, default=ppo["total_timesteps"])
    train.add_argument("--seed", type=_seed, default=ppo["seed"])
    train.add_argument("--n-envs", type=_positive_int, default=ppo["n_envs"])
    train.add_argument("--vec-env", choices=VEC_ENVS, default=ppo["vec_env"],
                       help="in-process environments (default) or one process each")
    train.add_argument("--output", type=Path, default=Path("runs/ppo_random_crossing.zip"))
    train.add_argument("--filter", choices=[r for r in RISKS if r != "none"], default=None,
                       help="train with the safety filter in the loop (safe exploration)")
    add_filter_flags(train, _TRAIN_FILTER_FLAGS, defaults=False)
    train.add_argument("--reference", choices=FILTER_REFERENCES, default=ppo["filter_reference"],
                       help="filter reference: the wrapper's, or the policy being trained "
                       "rolled out over the horizon")
    _add_options(train, "filter", "any other field of filters.FilterConfig")
    train.add_argument("--lagrangian", action="store_true",
                       help="train PPO-Lagrangian (cost: the continuous-time collision indicator)")
    train.add_argument("--cost-limit", type=float, default=ppo["cost_limit"],
                       help="PPO-Lagrangian: allowed mean episode cost (default 0)")
    train.add_argument("--lambda-lr", type=float, default=ppo["lambda_lr"],
                       help="PPO-Lagrangian: dual step size of the multiplier")
    train.add_argument("--eval-freq", type=_seed, default=ppo["eval_freq"],
                       help="evaluate every N steps on held-out seeds (0: off); saves the best "
                       "model to <output>_best/")
    train.add_argument("--eval-episodes", type=_positive_int, default=ppo["eval_episodes"])
    train.add_argument("--tensorboard", metavar="DIR",
                       help="write TensorBoard event files to DIR (pip install 'safe-nav[train]')")
    _add_options(train, "env", "gym.make keyword of the training environments, e.g. "
                 "random_start=0.5 or time_penalty=0.05")
    train.add_argument("--physical-actions", action="store_true",
                       help="let the learner act on the ±10 m/s² box instead of [-1, 1] (as the "
                       "shipped policy was trained)")
    train.add_argument("--quiet", action="store_true", help="do not print the metrics table")
    train.add_argument("--no-progress", action="store_true")

    evaluate = sub.add_parser("evaluate", help="Monte Carlo: filtered vs unfiltered policies",
                              **formatted)
    evaluate.set_defaults(run=_evaluate, parser=evaluate)
    evaluate.add_argument("--scenarios", type=_argument_type(_canonical_scenario), nargs="+",
                          default=list(PAPER_SCENARIOS),
                          help="scenario names (HeadOn, Overtaking, Intersection, "
                          "MultiObstacle, RandomCrossing; Custom with --env-option "
                          "scenario=JSON, a safe_nav_env.Scenario's fields, e.g. "
                          f"scenario='{_CUSTOM_EXAMPLE}')")
    evaluate.add_argument("--risks", choices=RISKS, nargs="+", default=["none", *PAPER_RISKS],
                          help="risk settings; none is the unfiltered planner (the default is "
                          "the paper's comparison; gaussian_cc, moment_dr and conformal on "
                          "request)")
    evaluate.add_argument("--planner", choices=PLANNERS, default="ppo",
                          help="reference planner: the PPO policy, the paper's "
                          "obstacle-agnostic MPC or the obstacle-blind go-to-goal controller")
    evaluate.add_argument("--reference", choices=REFERENCES, default="rollout",
                          help="PPO reference trajectory: roll the policy out on the predicted "
                          "obstacle motion, or hold its action")
    evaluate.add_argument("--policy", type=_argument_type(_policy), default="",
                          help="PPO policy .zip (default: the shipped one)%(default).0s")
    _add_run_flags(evaluate, episodes=300, output="results/evaluate")
    evaluate.add_argument("--executor", choices=EXECUTORS, default=EXECUTORS[0],
                          help="where episodes run: local processes or a Ray cluster")
    evaluate.add_argument("--address", default=None, metavar="HOST:PORT",
                          help="--executor ray: the cluster to run on, HOST:PORT of its head "
                          "(ray start --head --port=PORT) or auto (the one started on this "
                          "machine); default: RAY_ADDRESS if set, else a local Ray")
    add_filter_flags(evaluate, ("alpha", "delta", "epsilon"), defaults=True)
    evaluate.add_argument("--noise", choices=["", *NOISE_PRESETS], default="", metavar="NOISE",
                          help="noise preset of the environment, e.g. authors_code (default: "
                          "the scenario's own, as in the paper's text)%(default).0s")
    _add_options(evaluate, "filter", "further SafetyFilterWrapper keyword, e.g. soft=true")
    _add_options(evaluate, "env", "further gym.make keyword, e.g. n_samples=50")
    evaluate.add_argument("--overwrite", action="store_true",
                          help="discard the results already in --output instead of resuming")
    evaluate.add_argument("--no-plots", action="store_true", help="no figures")
    evaluate.add_argument("--sweep", action="store_true",
                          help="sweep epsilon and delta (DR-CVaR) and plot collisions vs "
                          "deviation (writes sweep.csv, sweep.md, figures/sweep.png)")
    evaluate.add_argument("--epsilons", type=_metres, nargs="+", default=[0.0, 0.05, 0.1, 0.2],
                          help="--sweep: Wasserstein radii, in m (>= 0)")
    evaluate.add_argument("--deltas", type=_metres, nargs="+", default=[0.0, 0.1, 0.2],
                          help="--sweep: risk bounds, in m (>= 0)")
    evaluate.add_argument("--suite", choices=("scenarios", "stress", "crowd", "pedestrians"),
                          default="scenarios",
                          help="scenarios: --scenarios x --risks; stress: the stress table by "
                          "failure class (--cases x --planners x --methods); crowd: CrowdNav's "
                          "circle crossing (--crowd-settings x --risks, --episodes test "
                          "cases); pedestrians: the ETH/UCY scenes (--scenes x --risks); "
                          "a suite's output default is results/<suite>")
    for flag, choices, default, help in (
            ("--scenes", pedestrians.PEDESTRIAN_SETTINGS, pedestrians.PEDESTRIAN_SETTINGS,
             "--suite pedestrians: the recorded scenes"),
            ("--crowd-settings", crowd.CROWD_SETTINGS, ["orca_invisible"],
             "--suite crowd: human model and robot visibility"),
            ("--cases", STRESS_SUITE, stress.DEFAULT_CASES, "--suite stress: the failure classes"),
            ("--methods", stress.STRESS_METHODS, stress.DEFAULT_METHODS,
             "--suite stress: the filter settings (default: the wrapper's defaults, action "
             "held; dr_cvar: fixed --epsilon; dr_cvar_auto: epsilon='auto'; all but default "
             "track --reference)"),
            ("--planners", PLANNERS, stress.DEFAULT_PLANNERS,
             "--suite stress: the reference planners (goal: the obstacle-blind go-to-goal "
             "controller; --planner mpc or goal alone replaces them)")):
        evaluate.add_argument(flag, choices=list(choices), nargs="+", default=list(default),
                              help=help)

    reproduce = sub.add_parser("reproduce", help="reproduce the paper's figures and tables",
                               **formatted)
    reproduce.set_defaults(run=_reproduce)
    _add_run_flags(reproduce, episodes=300, output="results/reproduce")
    reproduce.add_argument("--timing-repeats", type=_positive_int, default=100,
                           help="repeats of each Table I timing (>= 1)")

    bench = sub.add_parser("bench", help="speed benchmarks (ratios in one run)", **formatted)
    bench.set_defaults(run=run)
    add_arguments(bench, positive_int=_positive_int, seed=_seed)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``safe-nav``; returns the exit code (see the module docstring)."""
    from agents.errors import AgentsError, WorkersLostError
    from filters.errors import SafeNavError
    from safe_nav_env.errors import SafeNavEnvError

    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help (0) or a bad option (2, one line already printed)
        return exc.code if isinstance(exc.code, int) else EXIT_BAD_INPUT
    try:
        return args.run(args)
    except KeyboardInterrupt as exc:
        print(_interrupted_message(f"safe-nav {args.command}", exc, args), file=sys.stderr)
        return EXIT_INTERRUPTED
    except (AgentsError, SafeNavError, SafeNavEnvError) as exc:
        return _error(args, str(exc).splitlines()[0] if str(exc) else type(exc).__name__,
                      EXIT_FAILED_EPISODES if isinstance(exc, WorkersLostError) else
                      EXIT_BAD_INPUT)


def _error(args: argparse.Namespace, message: str, code: int = EXIT_BAD_INPUT) -> int:
    """Print ``safe-nav <command>: error: message`` on stderr; return the exit ``code``."""
    print(f"safe-nav {args.command}: error: {message}", file=sys.stderr)
    return code


def _interrupted_message(prog: str, exc: KeyboardInterrupt, args: argparse.Namespace) -> str:
    from agents.evaluation.evaluate import EvaluationInterrupted

    if isinstance(exc, EvaluationInterrupted) and exc.csv_path is not None:
        reused = f" ({exc.reused} of them reused from an earlier run)" if exc.reused else ""
        return (f"{prog}: interrupted: {exc.finished} of {exc.total} episodes finished{reused}, "
                f"saved in {exc.csv_path}; run the same command again to resume")
    where = f" in {args.output}" if getattr(args, "output", None) else ""
    return (f"{prog}: interrupted; the finished episodes are saved{where}; run the same command "
            "again to resume")


def _reproduce(args: argparse.Namespace) -> int:
    from agents.experiments.reproduce import reproduce

    print(reproduce(output=args.output, episodes=args.episodes, workers=args.workers,
                    seed=args.seed, timing_repeats=args.timing_repeats,
                    progress=not args.no_progress))
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    from agents.evaluation.campaign import run_evaluation, run_sweep
    from agents.evaluation.config import EvaluationConfig
    from agents.experiments import crowd, pedestrians, stress
    from safe_nav_env.scenarios import CUSTOM

    suite = args.suite != "scenarios"
    if not suite and CUSTOM in args.scenarios and "scenario" not in dict(args.env_option):
        return _error(args, f"--scenarios {CUSTOM} needs its scenario: add --env-option "
                      f"scenario='{_CUSTOM_EXAMPLE}' (the fields of safe_nav_env.Scenario as "
                      "JSON) or --env-option scenario=HeadOn (a scenario name)")
    # a suite sets these flags itself
    if suite and (clash := _given(args, "sweep", "noise", "scenarios",
                                  *["risks"] * (args.suite == "stress"))):
        sets, use = {"stress": ("the cases, methods and noise", "--cases/--methods"),
                     "crowd": ("the scene", "--crowd-settings")}.get(args.suite,
                                                                      ("the scene", "--scenes"))
        return _error(args, f"--suite {args.suite} sets {sets} itself; drop "
                      f"{', '.join(clash)} (use {use})")
    config = EvaluationConfig(  # a suite's output folder is results/<suite> unless given
        output=Path(f"results/{args.suite}") if suite and not _given(args, "output")
        else args.output,
        workers=args.workers, executor=args.executor, address=args.address,
        overwrite=args.overwrite, plots=not args.no_plots, progress=not args.no_progress)
    common = dict(config=config, episodes=args.episodes, seed=args.seed,
                  reference=args.reference, policy_path=args.policy, alpha=args.alpha,
                  filter_options=dict(args.filter_option), env_options=dict(args.env_option))
    radii = dict(delta=args.delta, epsilon=args.epsilon)
    if args.suite == "stress":  # one --planner other than ppo replaces --planners
        outputs = stress.run_stress(None, args.cases, args.methods, **radii, **common,
                             planners=args.planners if args.planner == "ppo" else [args.planner])
    elif suite:
        run, settings = ((crowd.run_crowd, args.crowd_settings) if args.suite == "crowd"
                         else (pedestrians.run_pedestrians, args.scenes))
        outputs = run(None, settings, args.risks, planner=args.planner, **radii, **common)
    elif args.sweep:
        outputs = run_sweep(None, args.scenarios, epsilons=args.epsilons, deltas=args.deltas,
                            planner=args.planner, noise=args.noise, **common)
    else:
        outputs = run_evaluation(None, args.scenarios, args.risks, planner=args.planner,
                                 noise=args.noise, **radii, **common)
    print(outputs)
    if not outputs.failed:
        return 0
    first = outputs.failed[0]
    return _error(args, f"{len(outputs.failed)} of {len(outputs.records)} episodes failed "
                  f"(first: {first.case or first.scenario} {first.risk} seed {first.seed}: "
                  f"{first.error.split(' | ')[0][:200]}); see the error column of "
                  f"{outputs.files['episodes']}; run the same command again to re-run them",
                  EXIT_FAILED_EPISODES)


def _train(args: argparse.Namespace) -> int:
    from agents.training.ppo import train_ppo

    for needed, names in (("filter", (*_TRAIN_FILTER_FLAGS, "filter_option", "reference")),
                          ("lagrangian", ("cost_limit", "lambda_lr"))):
        if not getattr(args, needed) and (given := _given(args, *names)):
            return _error(args, f"{', '.join(given)} need --{needed}")
    _, report = train_ppo(  # bad options raise before any training (main prints them)
        args.env_id, args.timesteps, args.seed, n_envs=args.n_envs,
        env_kwargs=dict(args.env_option), lagrangian=args.lagrangian,
        filter_kwargs=filter_config(args, args.filter, _TRAIN_FILTER_FLAGS) if args.filter
        else None, filter_reference=args.reference, cost_limit=args.cost_limit,
        lambda_lr=args.lambda_lr, eval_freq=args.eval_freq, eval_episodes=args.eval_episodes,
        vec_env=args.vec_env, tensorboard_log=args.tensorboard, print_metrics=not args.quiet,
        normalise_actions=not args.physical_actions, progress_bar=not args.no_progress,
        save_path=args.output)
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

"""Campaigns: a list of episodes run under an :class:`EvaluationConfig`, with their outputs.

:func:`run_campaign` is the one pipeline of every evaluation command: it runs a
campaign's :class:`~agents.evaluation.records.EpisodeSpec` through
:func:`agents.evaluation.evaluate.evaluate` (resume, run key, fault tolerance) on the
config's executor, then writes the campaign's summary page and figures.
:func:`run_evaluation` (``safe-nav evaluate``) and :func:`run_sweep` (``--sweep``) are
campaigns, like the stress, crowd and pedestrian suites of :mod:`agents.experiments`.

Output folder layout::

    episodes.csv        one row per episode, appended as episodes finish
    episodes.run.json   the run key: every setting the rows share (policy hash, filter and
                        environment settings, noise, package version); a resumed run
                        must match it
    summary.md          the summary tables (Markdown), naming the policy, the settings
                        and the code version, and the guarantee audit (agents/evaluation/audit.py)
    figures/            trajectories_<scenario>.png, distance_boxplots.png,
                        collision_rates.png, safe_polytopes.png, episode.gif
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from agents.evaluation.config import EvaluationConfig, split_options
from agents.evaluation.evaluate import EvaluationRecords, episode_specs, evaluate
from agents.evaluation.records import (
    PAPER_SCENARIOS,
    PLANNERS,
    EpisodeRecord,
    EpisodeSpec,
    package_version,
)
from agents.evaluation.runner import policy_file, run_episode
from agents.evaluation.summary import (
    SummaryRow,
    audit_section,
    markdown_table,
    short_name,
    status_table,
    summarise,
    table,
)
from filters.errors import InvalidParameterError
from filters.wrapper import RISKS
from safe_nav_env.scenarios import scenario_name

__all__ = ["EvaluationConfig", "EvaluationOutputs", "Report", "run_campaign", "run_evaluation",
           "run_sweep"]


@dataclass
class EvaluationOutputs:
    """What an evaluation produced."""

    records: list[EpisodeRecord]
    rows: Sequence[Any]
    markdown: str
    wall_time: float
    files: dict[str, Path] = field(default_factory=dict)
    reused: int = 0
    """Episodes read back from the results CSV of an earlier run, not run again."""

    def __str__(self) -> str:
        listing = "\n".join(f"  {name}: {path}" for name, path in self.files.items())
        count = f"{len(self.records)} episodes"
        if self.reused:
            count += (f" ({self.reused} reused from {self.files.get('episodes', 'the results CSV')}"
                      f", {len(self.records) - self.reused} run now)")
        return f"{self.markdown}\n{count} in {self.wall_time:.1f} s\n{listing}"

    @property
    def failed(self) -> list[EpisodeRecord]:
        """The records of the episodes that failed."""
        return [r for r in self.records if r.error]


@dataclass(frozen=True)
class Report:
    """What a campaign makes of its records (:func:`run_campaign` writes it).

    Attributes
    ----------
    title
        The summary page's title.
    body
        Markdown after the run's description (:func:`describe_run`).
    rows, markdown
        The campaign's table, as values and as Markdown (:class:`EvaluationOutputs`).
    files
        Further files the report wrote, by name.
    figures
        ``folder -> {name: path}``: draws the figures into ``folder`` (called unless the
        config says ``plots=False``).
    """

    title: str
    body: str
    rows: Sequence[Any] = ()
    markdown: str = ""
    files: Mapping[str, Path] = field(default_factory=dict)
    figures: Callable[[Path], Mapping[str, Path]] | None = None


def _values(records: Sequence[EpisodeRecord], name: str) -> str:
    values = dict.fromkeys(getattr(r, name) for r in records)
    return ", ".join(f"{v:g}" if isinstance(v, float) else str(v or "scenario")
                     for v in values)


_PLANNER_NAMES = {"goal": "obstacle-blind go-to-goal controller", "mpc": "obstacle-agnostic MPC"}


def describe_run(records: Sequence[EpisodeRecord]) -> str:
    """The Markdown lines that name the policies (path and hash), the settings shared by the
    records (each value they take) and the code."""
    planners = [p for p in PLANNERS if any(r.planner == p for r in records)]
    lines = [f"- policy: `{policy_file(path)}` (SHA-256 `{sha or 'unknown'}`)" for path, sha
             in sorted({(r.policy, r.policy_sha256) for r in records if r.planner == "ppo"})]
    lines += [f"- planner `{planner}`: the {_PLANNER_NAMES[planner]} (no policy file)"
              for planner in planners if planner != "ppo"]
    seeds = sorted({r.seed for r in records}) or [0]
    lines.append(f"- planner {', '.join(planners)}, reference {_values(records, 'reference')}, "
                 f"alpha {_values(records, 'alpha')}, delta {_values(records, 'delta')} m, "
                 f"epsilon {_values(records, 'epsilon')} m, noise "
                 f"`{_values(records, 'noise')}`, {len(seeds)} episodes per cell, seeds "
                 f"{seeds[0]}..{seeds[-1]} in every cell")
    lines += [f"- filter options `{filter_options or '{}'}`, environment options "
              f"`{env_options or '{}'}`" for filter_options, env_options
              in sorted({(r.filter_options, r.env_options) for r in records})
              if filter_options or env_options]
    versions = sorted({r.version for r in records if r.version}) or [package_version()]
    lines.append(f"- safe-nav {', '.join(versions)}")
    lines.append("- collisions in continuous time (the exact clearance over each step) unless "
                 "the column says sampled")
    return "\n".join(lines) + "\n"


def run_campaign(specs: Sequence[EpisodeSpec], config: EvaluationConfig,
                 report: Callable[[EvaluationRecords], Report], *, vary: Sequence[str] = (),
                 name: str = "episodes", summary: str = "summary.md") -> EvaluationOutputs:
    """Run ``specs`` under ``config``; write ``<name>.csv``, its run key, ``summary`` and the
    figures of ``report(records)`` into ``config.output``.

    Episodes already in the CSV from the same run (its run key ``<name>.run.json`` must
    match) are not run again, so an interrupted run resumes; failed rows are run again.
    ``vary`` names the key fields besides scenario, risk and seed that differ between
    the specs (:func:`agents.evaluation.records.run_key`).

    Raises
    ------
    InvalidParameterError, PolicyFileError, RunMismatchError, ...
        As :func:`agents.evaluation.evaluate.evaluate`, before any episode runs.
    """
    if config.output is None:
        raise InvalidParameterError("run_campaign needs an output folder: config.output is None "
                                    "(split_options sets the campaign's default)")
    output = config.output
    start = time.perf_counter()
    records = evaluate(specs=specs, vary=vary, workers=config.workers,
                       executor=config.executor, address=config.address,
                       csv_path=output / f"{name}.csv", progress=config.progress,
                       overwrite=config.overwrite)
    wall = time.perf_counter() - start
    result = report(records)
    (output / summary).write_text(
        f"# {result.title}\n\n" + describe_run(records)
        + f"- this call: {wall:.1f} s wall time on {config.workers} worker(s) for the "
        f"{len(records)} episodes it returned ({records.reused} read back from the CSV)\n"
        + result.body)
    files = {"episodes": output / f"{name}.csv", "run_key": output / f"{name}.run.json",
             "summary": output / summary, **result.files}
    if config.plots and result.figures is not None:
        files.update(result.figures(output / "figures"))
    return EvaluationOutputs(records, result.rows, result.markdown,
                             time.perf_counter() - start, files, reused=records.reused)


def run_evaluation(output: str | Path | None = None, scenarios: Sequence[str] = PAPER_SCENARIOS,
                   risks: Sequence[str] = RISKS, *, config: EvaluationConfig | None = None,
                   episodes: int = 300, seed: int = 0, **options: Any) -> EvaluationOutputs:
    """Evaluate every (scenario, risk) on ``episodes`` seeds; write the CSV, the summary and
    the figures into ``output`` (default ``results/evaluate``).

    ``options`` are how to run (fields of :class:`EvaluationConfig`: ``workers``,
    ``executor``, ``address``, ``overwrite``, ``plots``, ``progress``; they override
    ``config``) and the episodes' settings (fields of :class:`EpisodeSpec`: ``planner``,
    ``reference``, ``policy_path``, ``alpha``, ``delta``, ``epsilon``, ``noise``,
    ``filter_options``, ``env_options``). Raises what :func:`run_campaign` raises.
    """
    config, settings = split_options(config, output, options, default="results/evaluate")
    scenarios = [scenario_name(s) for s in scenarios]
    specs = episode_specs(scenarios, risks, episodes, seed, **settings)

    def report(records: EvaluationRecords) -> Report:
        rows = summarise(records)
        markdown = markdown_table(rows)
        sha = next((r.policy_sha256 for r in records if r.policy_sha256), "")
        return Report(
            "Evaluation summary",
            f"\n{markdown}\n## Filter statuses (share of steps) and collision causes\n\n"
            + status_table(rows) + audit_section(records), rows, markdown,
            figures=lambda folder: make_figures(folder, records, rows, scenarios, risks,
                                                template=replace(specs[0], seed=seed,
                                                                 policy_sha256=sha)))

    return run_campaign(specs, config, report)


def make_figures(folder: Path, records: Sequence[EpisodeRecord], rows: Sequence[SummaryRow],
                 scenarios: Sequence[str], risks: Sequence[str], *,
                 template: EpisodeSpec) -> dict[str, Path]:
    """Figures of an evaluation, re-running ``template``'s seed of each scenario and risk
    (its other settings too) with trajectories."""
    from agents.evaluation import plots

    files: dict[str, Path] = {}
    seed = template.seed
    # One rendered run (MultiObstacle if evaluated, DR-CVaR if evaluated) also gives the
    # safe-polytope figure and the animation; every other run only its trajectory.
    featured = plots.featured_run(scenarios, risks)
    featured_trajectory = None
    for scenario in scenarios:
        trajectories = {}
        for risk in risks:
            render = (scenario, risk) == featured
            _, traj = run_episode(replace(template, scenario=scenario, risk=risk),
                                  record_trajectory=True, render=render)
            if traj is not None:
                trajectories[risk] = traj
                if render:
                    featured_trajectory = traj
        name = short_name(scenario)
        files[f"trajectories_{name}"] = plots.plot_trajectories(
            trajectories, folder / f"trajectories_{name}.png", title=f"{name}, seed {seed}")
    files["distance_boxplots"] = plots.plot_distance_boxplots(records,
                                                              folder / "distance_boxplots.png")
    files["collision_rates"] = plots.plot_collision_rates(rows, folder / "collision_rates.png")
    if featured_trajectory is not None:
        name, risk = short_name(featured[0]), featured[1]
        files.update(plots.polytope_figures(
            featured_trajectory, folder, title=f"{name}: {risk} safe polytopes",
            label=f"{plots.RISK_LABELS.get(risk, risk)}, {name}, seed {seed}"))
    return files


SWEEP_MEANS = {"collision_rate": "collision", "sampled_collision_rate": "sampled_collision",
               "goal_rate": "goal_reached", "mean_intervention": "mean_intervention"}
"""A sweep point's columns: the mean of these record fields over its episodes."""


def run_sweep(output: str | Path | None = None, scenarios: Sequence[str] = PAPER_SCENARIOS, *,
              epsilons: Sequence[float] = (0.0, 0.05, 0.1, 0.2),
              deltas: Sequence[float] = (0.0, 0.1, 0.2), config: EvaluationConfig | None = None,
              episodes: int = 50, seed: int = 0, **options: Any) -> EvaluationOutputs:
    """DR-CVaR over a grid of (epsilon, delta): collision rate against mean intervention.

    The whole grid is one campaign (one worker pool, started once). Writes, into
    ``output`` (default ``results/sweep``), ``sweep.csv`` (all episodes, with its run key
    ``sweep.run.json``), ``sweep.md`` and ``figures/sweep.png``. ``options`` as for
    :func:`run_evaluation`, except ``delta`` and ``epsilon``, which the grid sets.
    """
    from agents.evaluation import plots

    config, settings = split_options(config, output, options, default="results/sweep",
                                     fixed=("delta", "epsilon"))
    scenarios = [scenario_name(s) for s in scenarios]
    specs = [spec for delta in deltas for epsilon in epsilons
             for spec in episode_specs(scenarios, ["dr_cvar"], episodes, seed, delta=delta,
                                       epsilon=epsilon, **settings)]

    def report(records: EvaluationRecords) -> Report:
        points = []
        for delta in deltas:
            for epsilon in epsilons:
                ok = [r for r in records if not r.error and r.delta == float(delta)
                      and r.epsilon == float(epsilon)]
                points.append(dict(epsilon=epsilon, delta=delta, episodes=len(ok), **{
                    column: sum(getattr(r, name) for r in ok) / max(1, len(ok))
                    for column, name in SWEEP_MEANS.items()}))
        markdown = table(
            ("delta (m)", "epsilon (m)", "episodes", "collision rate", "sampled collision rate",
             "goal rate", "mean intervention (m/s²)"),
            ([f"{p['delta']:g}", f"{p['epsilon']:g}", f"{p['episodes']}",
              f"{p['collision_rate']:.1%}", f"{p['sampled_collision_rate']:.1%}",
              f"{p['goal_rate']:.1%}", f"{p['mean_intervention']:.3f}"] for p in points))
        return Report("DR-CVaR epsilon/delta sweep", f"\n{markdown}", summarise(records),
                      markdown, figures=lambda folder: {
                          "sweep": plots.plot_sweep(points, folder / "sweep.png")})

    return run_campaign(specs, config, report, vary=("epsilon", "delta"), name="sweep",
                        summary="sweep.md")

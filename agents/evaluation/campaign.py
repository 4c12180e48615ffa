"""Evaluation runs with their outputs: CSV, Markdown summary, figures.

:func:`run_evaluation` is what ``safe-nav evaluate`` runs; :func:`run_sweep` is
``safe-nav evaluate --sweep``. Both are plain functions the tests call too.

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
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from agents.errors import OutputPathError
from agents.evaluation.evaluate import episode_specs, evaluate
from agents.evaluation.executors import Executor
from agents.evaluation.records import (
    PAPER_SCENARIOS,
    EpisodeRecord,
    EpisodeSpec,
    package_version,
)
from agents.evaluation.runner import policy_file, run_episode
from agents.evaluation.summary import (
    AUDIT_NOTE,
    SummaryRow,
    audit_rows,
    audit_table,
    markdown_table,
    short_name,
    status_table,
    summarise,
)
from filters.constants import ALPHA, DELTA, EPSILON
from filters.wrapper import RISKS
from safe_nav_env.scenarios import scenario_name


@dataclass
class EvaluationOutputs:
    """What an evaluation produced."""

    records: list[EpisodeRecord]
    rows: list[SummaryRow]
    markdown: str
    wall_time: float
    files: dict[str, Path] = field(default_factory=dict)
    reused: int = 0
    """Episodes read back from the results CSV of an earlier run, not run again."""

    def __str__(self) -> str:
        listing = "\n".join(f"  {name}: {path}" for name, path in self.files.items())
        count = f"{len(self.records)} episodes"
        if self.reused:
            where = self.files.get("episodes", "the results CSV")
            count += (f" ({self.reused} reused from {where}, {len(self.records) - self.reused} "
                      "run now)")
        return f"{self.markdown}\n{count} in {self.wall_time:.1f} s\n{listing}"

    @property
    def failed(self) -> list[EpisodeRecord]:
        """The records of the episodes that failed."""
        return [r for r in self.records if r.error]


def output_folder(output: str | Path) -> Path:
    """Check that ``output`` can be an output folder; return it as a path.

    The folder (and its parents) is not made here but by the first file written into
    it (the run key, once every setting is checked), so that a run failing before it
    has anything to write leaves no empty folder behind.

    Raises
    ------
    OutputPathError
        If ``output`` or one of its parents is a file.
    """
    output = Path(output)
    for folder in (output, *output.parents):
        if folder.exists():
            if not folder.is_dir():
                raise OutputPathError(f"output folder {output} cannot be made: {folder} is a "
                                      "file; choose another --output")
            break
    return output


def describe_run(records: Sequence[EpisodeRecord], *, planner: str, reference: str,
                 settings: str) -> str:
    """The Markdown lines that name the policy (path and hash), the settings and the code."""
    policies = sorted({(r.policy, r.policy_sha256) for r in records if r.planner == "ppo"})
    lines = []
    if planner == "ppo":
        for path, sha in policies or [("", "")]:
            lines.append(f"- policy: `{policy_file(path)}` (SHA-256 `{sha or 'unknown'}`)")
    else:
        blind = "obstacle-blind go-to-goal controller" if planner == "goal" else (
            "obstacle-agnostic MPC")
        lines.append(f"- planner: the {blind} (no policy file)")
    lines.append(f"- planner `{planner}`, reference `{reference}`, {settings}")
    options = sorted({(r.filter_options, r.env_options) for r in records})
    for filter_options, env_options in options:
        if filter_options or env_options:
            lines.append(f"- filter options `{filter_options or '{}'}`, environment options "
                         f"`{env_options or '{}'}`")
    versions = sorted({r.version for r in records if r.version}) or [package_version()]
    lines.append(f"- safe-nav {', '.join(versions)}")
    lines.append("- collisions in continuous time (the exact clearance over each step) unless "
                 "the column says sampled")
    return "\n".join(lines) + "\n"


def run_evaluation(
    output: str | Path = "results/evaluate",
    scenarios: Sequence[str] = PAPER_SCENARIOS,
    risks: Sequence[str] = RISKS,
    *,
    episodes: int = 300,
    workers: int = 2,
    seed: int = 0,
    planner: str = "ppo",
    reference: str = "rollout",
    policy_path: str = "",
    alpha: float = ALPHA,
    delta: float = DELTA,
    epsilon: float = EPSILON,
    noise: str = "",
    filter_options: dict[str, Any] | str | None = None,
    env_options: dict[str, Any] | str | None = None,
    executor: str | Executor = "process",
    plots: bool = True,
    progress: bool = True,
    overwrite: bool = False,
) -> EvaluationOutputs:
    """Evaluate, then write the summary and the figures into ``output``.

    Episodes already in ``output/episodes.csv`` from the same run (its run key
    ``episodes.run.json`` must match) are not run again, so an interrupted run
    resumes; failed rows are run again. See :func:`agents.evaluation.evaluate.evaluate` for
    the errors raised before anything runs.
    """
    output = output_folder(output)
    scenarios = [scenario_name(s) for s in scenarios]
    spec_kwargs: dict[str, Any] = dict(planner=planner, reference=reference,
                                       policy_path=policy_path, alpha=alpha, delta=delta,
                                       epsilon=epsilon, noise=noise,
                                       filter_options=filter_options or "",
                                       env_options=env_options or "")
    start = time.perf_counter()
    records = evaluate(scenarios, risks, episodes=episodes, seed=seed, workers=workers,
                       executor=executor, csv_path=output / "episodes.csv", progress=progress,
                       overwrite=overwrite, **spec_kwargs)
    rows = summarise(records)
    markdown = markdown_table(rows)
    files = {"episodes": output / "episodes.csv", "run_key": output / "episodes.run.json",
             "summary": output / "summary.md"}
    settings = (f"alpha {alpha}, delta {delta} m, epsilon {epsilon} m, noise "
                f"`{noise or 'scenario'}`, {episodes} episodes per row, seeds "
                f"{seed}..{seed + episodes - 1}")
    (output / "summary.md").write_text(
        "# Evaluation summary\n\n"
        + describe_run(records, planner=planner, reference=reference, settings=settings)
        + f"\n{markdown}\n## Filter statuses (share of steps) and collision causes\n\n"
        + status_table(rows)
        + "\n## Guarantee audit (realised loss at the step-1 halfspaces)\n\n"
        + audit_table(audit_rows(records)) + "\n" + AUDIT_NOTE
    )
    if plots:
        sha = next((r.policy_sha256 for r in records if r.policy_sha256), "")
        files.update(make_figures(output / "figures", records, rows, scenarios, risks,
                                  seed=seed, spec_kwargs=dict(spec_kwargs, policy_sha256=sha)))
    return EvaluationOutputs(records, rows, markdown, time.perf_counter() - start, files,
                             reused=records.reused)


def make_figures(
    folder: Path,
    records: Sequence[EpisodeRecord],
    rows: Sequence[SummaryRow],
    scenarios: Sequence[str],
    risks: Sequence[str],
    *,
    seed: int,
    spec_kwargs: dict[str, Any],
) -> dict[str, Path]:
    """Figures of an evaluation (re-running the first seed of each scenario with trajectories)."""
    from agents.evaluation import plots

    files: dict[str, Path] = {}
    scenarios = [scenario_name(s) for s in scenarios]
    # One rendered run (MultiObstacle if evaluated, DR-CVaR if evaluated) also gives the
    # safe-polytope figure and the animation; every other run only its trajectory.
    featured = plots.featured_run(scenarios, risks)
    featured_trajectory = None
    for scenario in scenarios:
        trajectories = {}
        for risk in risks:
            render = (scenario, risk) == featured
            _, traj = run_episode(EpisodeSpec(scenario, risk, seed, **spec_kwargs),
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


def run_sweep(
    output: str | Path = "results/sweep",
    scenarios: Sequence[str] = PAPER_SCENARIOS,
    *,
    epsilons: Sequence[float] = (0.0, 0.05, 0.1, 0.2),
    deltas: Sequence[float] = (0.0, 0.1, 0.2),
    episodes: int = 50,
    workers: int = 2,
    seed: int = 0,
    planner: str = "ppo",
    reference: str = "rollout",
    policy_path: str = "",
    alpha: float = ALPHA,
    noise: str = "",
    filter_options: dict[str, Any] | str | None = None,
    env_options: dict[str, Any] | str | None = None,
    executor: str | Executor = "process",
    progress: bool = True,
    overwrite: bool = False,
) -> EvaluationOutputs:
    """DR-CVaR over a grid of (epsilon, delta): collision rate against mean intervention.

    The whole grid is one batch of episodes on one executor (one worker pool, started
    once). Writes ``sweep.csv`` (all episodes, with its run key ``sweep.run.json``),
    ``sweep.md`` and ``figures/sweep.png``.
    """
    from agents.evaluation import plots

    output = output_folder(output)
    scenarios = [scenario_name(s) for s in scenarios]
    start = time.perf_counter()
    common = dict(planner=planner, reference=reference, policy_path=policy_path, alpha=alpha,
                  noise=noise, filter_options=filter_options or "",
                  env_options=env_options or "")
    specs = [spec for delta in deltas for epsilon in epsilons
             for spec in episode_specs(scenarios, ["dr_cvar"], episodes, seed, delta=delta,
                                       epsilon=epsilon, **common)]
    all_records = evaluate(specs=specs, vary=("epsilon", "delta"), workers=workers,
                           executor=executor, csv_path=output / "sweep.csv",
                           progress=progress, overwrite=overwrite)
    points = []
    for delta in deltas:
        for epsilon in epsilons:
            ok = [r for r in all_records if not r.error and r.delta == float(delta)
                  and r.epsilon == float(epsilon)]
            n = max(1, len(ok))
            points.append(dict(
                epsilon=epsilon, delta=delta, episodes=len(ok),
                collision_rate=sum(r.collision for r in ok) / n,
                sampled_collision_rate=sum(r.sampled_collision for r in ok) / n,
                goal_rate=sum(r.goal_reached for r in ok) / n,
                mean_intervention=sum(r.mean_intervention for r in ok) / n,
            ))
    lines = ["| delta (m) | epsilon (m) | episodes | collision rate | sampled collision rate | "
             "goal rate | mean intervention (m/s²) |",
             "|---|---|---|---|---|---|---|"]
    lines += [f"| {p['delta']:g} | {p['epsilon']:g} | {p['episodes']} | "
              f"{p['collision_rate']:.1%} | {p['sampled_collision_rate']:.1%} | "
              f"{p['goal_rate']:.1%} | {p['mean_intervention']:.3f} |" for p in points]
    markdown = "\n".join(lines) + "\n"
    settings = (f"alpha {alpha}, noise `{noise or 'scenario'}`, {episodes} episodes per point "
                f"and scenario, seeds {seed}..{seed + episodes - 1}")
    (output / "sweep.md").write_text(
        "# DR-CVaR epsilon/delta sweep\n\n"
        + describe_run(all_records, planner=planner, reference=reference, settings=settings)
        + f"\n{markdown}")
    files = {"episodes": output / "sweep.csv", "run_key": output / "sweep.run.json",
             "summary": output / "sweep.md",
             "sweep": plots.plot_sweep(points, output / "figures" / "sweep.png")}
    return EvaluationOutputs(all_records, summarise(all_records), markdown,
                             time.perf_counter() - start, files,
                             reused=all_records.reused)

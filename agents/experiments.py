"""Evaluation runs with their outputs: CSV, Markdown summary, figures.

:func:`run_evaluation` is what ``safe-nav evaluate`` runs; :func:`run_sweep` is
``safe-nav evaluate --sweep``. Both are plain functions the tests call too.

Output folder layout::

    episodes.csv        one row per episode, appended as episodes finish
    summary.md          the summary table (Markdown)
    figures/            trajectories_<scenario>.png, distance_boxplots.png,
                        collision_rates.png, safe_polytopes.png, episode.gif
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from agents.evaluation import (
    PAPER_SCENARIOS,
    EpisodeRecord,
    EpisodeSpec,
    evaluate,
    run_episode,
)
from agents.summary import SummaryRow, markdown_table, short_name, summarise
from filters.wrapper import RISKS


@dataclass
class EvaluationOutputs:
    """What an evaluation produced."""

    records: list[EpisodeRecord]
    rows: list[SummaryRow]
    markdown: str
    wall_time: float
    files: dict[str, Path] = field(default_factory=dict)

    def __str__(self) -> str:
        listing = "\n".join(f"  {name}: {path}" for name, path in self.files.items())
        return (f"{self.markdown}\n{len(self.records)} episodes in {self.wall_time:.1f} s\n"
                f"{listing}")


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
    alpha: float = 0.2,
    delta: float = 0.1,
    epsilon: float = 0.05,
    noise: str = "",
    executor: str = "process",
    plots: bool = True,
    progress: bool = True,
) -> EvaluationOutputs:
    """Evaluate, then write the summary and the figures into ``output``.

    Episodes already in ``output/episodes.csv`` (same scenario, risk, seed and
    parameters) are not run again, so an interrupted run resumes.
    """
    output = Path(output)
    output.mkdir(parents=True, exist_ok=True)
    spec_kwargs: dict[str, Any] = dict(planner=planner, reference=reference,
                                       policy_path=policy_path, alpha=alpha, delta=delta,
                                       epsilon=epsilon, noise=noise)
    start = time.perf_counter()
    records = evaluate(scenarios, risks, episodes=episodes, seed=seed, workers=workers,
                       executor=executor, csv_path=output / "episodes.csv", progress=progress,
                       **spec_kwargs)
    rows = summarise(records)
    markdown = markdown_table(rows)
    files = {"episodes": output / "episodes.csv", "summary": output / "summary.md"}
    (output / "summary.md").write_text(
        f"# Evaluation summary\n\nplanner `{planner}` (reference `{reference}`), "
        f"alpha {alpha}, delta {delta}, epsilon {epsilon}, noise `{noise or 'scenario'}`, "
        f"{episodes} episodes per row, "
        f"seeds {seed}..{seed + episodes - 1}\n\n{markdown}"
    )
    if plots:
        files.update(make_figures(output / "figures", records, rows, scenarios, risks,
                                  seed=seed, spec_kwargs=spec_kwargs))
    return EvaluationOutputs(records, rows, markdown, time.perf_counter() - start, files)


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
    from agents import plots

    files: dict[str, Path] = {}
    # One rendered run (MultiObstacle if evaluated, DR-CVaR if evaluated) also gives the
    # safe-polytope figure and the animation; every other run only its trajectory.
    featured = ("SafeNav/MultiObstacle-v0" if "SafeNav/MultiObstacle-v0" in scenarios
                else scenarios[0], "dr_cvar" if "dr_cvar" in risks else risks[-1])
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
        scenario, risk = featured
        files["safe_polytopes"] = plots.plot_safe_polytopes(
            featured_trajectory, folder / "safe_polytopes.png",
            title=f"{short_name(scenario)}: {risk} safe polytopes")
        if featured_trajectory.frames:
            files["animation"] = plots.save_gif(
                featured_trajectory.frames, folder / "episode.gif",
                label=f"{plots.RISK_LABELS.get(risk, risk)}, {short_name(scenario)}, seed {seed}")
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
    alpha: float = 0.2,
    noise: str = "",
    executor: str = "process",
    progress: bool = True,
) -> EvaluationOutputs:
    """DR-CVaR over a grid of (epsilon, delta): collision rate against mean intervention.

    Writes ``sweep.csv`` (all episodes), ``sweep.md`` and ``figures/sweep.png``.
    """
    from agents import plots

    output = Path(output)
    output.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    all_records: list[EpisodeRecord] = []
    points = []
    for delta in deltas:
        for epsilon in epsilons:
            records = evaluate(scenarios, ["dr_cvar"], episodes=episodes, seed=seed,
                               workers=workers, executor=executor,
                               csv_path=output / "sweep.csv", progress=progress,
                               planner=planner, reference=reference, policy_path=policy_path,
                               alpha=alpha, delta=delta, epsilon=epsilon, noise=noise)
            ok = [r for r in records if not r.error]
            n = max(1, len(ok))
            points.append(dict(
                epsilon=epsilon, delta=delta, episodes=len(ok),
                collision_rate=sum(r.collision for r in ok) / n,
                goal_rate=sum(r.goal_reached for r in ok) / n,
                mean_intervention=sum(r.mean_intervention for r in ok) / n,
            ))
            all_records.extend(records)
    lines = ["| delta | epsilon | episodes | collision rate | goal rate | mean intervention |",
             "|---|---|---|---|---|---|"]
    lines += [f"| {p['delta']:g} | {p['epsilon']:g} | {p['episodes']} | "
              f"{p['collision_rate']:.1%} | {p['goal_rate']:.1%} | "
              f"{p['mean_intervention']:.3f} |" for p in points]
    markdown = "\n".join(lines) + "\n"
    (output / "sweep.md").write_text(f"# DR-CVaR epsilon/delta sweep\n\n{markdown}")
    files = {"episodes": output / "sweep.csv", "summary": output / "sweep.md",
             "sweep": plots.plot_sweep(points, output / "figures" / "sweep.png")}
    return EvaluationOutputs(all_records, summarise(all_records), markdown,
                             time.perf_counter() - start, files)


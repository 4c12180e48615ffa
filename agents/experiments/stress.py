"""The stress benchmark: ``safe-nav evaluate --suite stress``.

Every case of :data:`safe_nav_env.stress.STRESS_SUITE` (predictions that are wrong in
a known way) times every method of :data:`STRESS_METHODS`, on the same seeds (common
random numbers: episode ``i`` of every cell uses seed ``seed + i``). The planner is the
shipped PPO with the roll-out reference, as ``safe-nav evaluate``; the episodes run
through :func:`agents.evaluation.evaluate.evaluate`, so the CSV, run key, resume and
``--overwrite`` behave the same way.

Output folder::

    episodes.csv, episodes.run.json   one row per episode (column ``case``), the run key
    summary.md                        per case: collisions (continuous time, Wilson 95 %),
                                      sampled collisions, goal rate, time to goal,
                                      intervention, soft/recovery share; the guarantee
                                      audit; wall time per cell
    figures/pareto.png                collision rate against time to goal, a panel per case
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agents.evaluation.campaign import EvaluationOutputs, describe_run, output_folder
from agents.evaluation.evaluate import evaluate
from agents.evaluation.executors import Executor
from agents.evaluation.records import AUTO, EpisodeRecord, EpisodeSpec
from agents.evaluation.summary import (
    AUDIT_NOTE,
    SummaryRow,
    audit_rows,
    audit_table,
    summarise,
    time_to_goal_cell,
)
from filters.constants import ALPHA, DELTA, EPSILON
from filters.errors import InvalidParameterError
from safe_nav_env.scenarios import CUSTOM
from safe_nav_env.stress import STRESS_SUITE

__all__ = ["STRESS_METHODS", "StressMethod", "run_stress", "stress_specs"]


@dataclass(frozen=True)
class StressMethod:
    """One method of the benchmark: a risk setting and, for DR-CVaR, its radius.

    Attributes
    ----------
    name
        Its name on the command line (``--methods``).
    risk
        A risk of :data:`filters.wrapper.RISKS` (``"none"``: the unfiltered planner).
    auto_epsilon
        Use the wrapper's online Wasserstein radius (``epsilon="auto"``) instead of the
        run's fixed ``epsilon``.
    """

    name: str
    risk: str
    auto_epsilon: bool = False

    def label(self, epsilon: float) -> str:
        """The name in tables and plots, e.g. ``"dr_cvar (eps=auto)"``."""
        if self.risk == "none":
            return "none (unfiltered)"
        if self.risk == "dr_cvar":
            return f"dr_cvar (eps={'auto' if self.auto_epsilon else f'{epsilon:g}'})"
        return self.risk


STRESS_METHODS: dict[str, StressMethod] = {m.name: m for m in (
    StressMethod("none", "none"),
    StressMethod("mean", "mean"),
    StressMethod("cvar", "cvar"),
    StressMethod("dr_cvar", "dr_cvar"),
    StressMethod("dr_cvar_auto", "dr_cvar", auto_epsilon=True),
    StressMethod("gaussian_cc", "gaussian_cc"),
    StressMethod("moment_dr", "moment_dr"),
    StressMethod("conformal", "conformal"),
)}
"""The methods, by command-line name, in table order."""


def _methods(names: Sequence[str]) -> list[StressMethod]:
    unknown = [n for n in names if n not in STRESS_METHODS]
    if unknown or not names:
        raise InvalidParameterError(f"methods must be some of {list(STRESS_METHODS)}, got "
                                    f"{list(names)!r}")
    return [STRESS_METHODS[n] for n in dict.fromkeys(names)]


def _cases(names: Sequence[str]) -> list[str]:
    unknown = [n for n in names if n not in STRESS_SUITE]
    if unknown or not names:
        raise InvalidParameterError(f"cases must be some of {list(STRESS_SUITE)}, got "
                                    f"{list(names)!r}")
    return list(dict.fromkeys(names))


def stress_specs(
    cases: Sequence[str] = tuple(STRESS_SUITE),
    methods: Sequence[str] = tuple(STRESS_METHODS),
    *,
    episodes: int = 200,
    seed: int = 0,
    epsilon: float = EPSILON,
    **spec_kwargs: Any,
) -> list[EpisodeSpec]:
    """Every (case, method, episode); episode ``i`` uses seed ``seed + i`` in every cell.

    ``spec_kwargs`` are further :class:`~agents.evaluation.records.EpisodeSpec` fields (``planner``,
    ``alpha``, ``delta``, ``filter_options``, ...), shared by every episode.

    Raises
    ------
    InvalidParameterError
        For an unknown case or method, ``episodes < 1`` or a bad setting.
    """
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise InvalidParameterError(f"episodes must be an integer >= 1, got {episodes!r}")
    for name in ("scenario", "risk", "seed", "case", "noise"):
        if name in spec_kwargs:
            raise InvalidParameterError(f"the stress suite sets {name!r} itself")
    return [EpisodeSpec(CUSTOM, method.risk, seed + i,
                        epsilon=AUTO if method.auto_epsilon else epsilon, case=case,
                        **spec_kwargs)
            for case in _cases(cases) for method in _methods(methods)
            for i in range(episodes)]


def _label(record: EpisodeRecord | SummaryRow, epsilon: float) -> str:
    auto = (record.epsilon == AUTO if isinstance(record, EpisodeRecord)
            else record.method.endswith("(eps=auto)"))
    return StressMethod("", record.risk, auto_epsilon=auto).label(epsilon)


def stress_table(rows: Sequence[SummaryRow], *, epsilon: float) -> str:
    """Markdown tables of the suite, one per case, methods in :data:`STRESS_METHODS` order."""
    out = []
    by_case: dict[str, list[SummaryRow]] = defaultdict(list)
    for row in rows:
        by_case[row.scenario].append(row)
    for case in [c for c in STRESS_SUITE if c in by_case]:
        out.append(f"### {case}: {STRESS_SUITE[case].description}\n")
        out.append("| method | episodes | collision rate [95 % CI] | sampled collision rate | "
                   "goal rate | time to goal (s) | mean intervention (m/s²) | soft steps | "
                   "recovery steps |")
        out.append("|" + "---|" * 9)
        for r in by_case[case]:
            shares = dict(r.status_shares)
            filtered = r.risk != "none"
            failed = f" ({r.failed} failed)" if r.failed else ""
            filter_cells = (f"{r.mean_intervention:.3f} | {shares.get('soft', 0.0):.1%} | "
                            f"{shares.get('recovery', 0.0):.1%} |" if filtered
                            else "0.000 | - | - |")
            out.append(
                f"| {_label(r, epsilon)} | {r.episodes}{failed} | {r.collision_rate:.1%} "
                f"[{r.collision_low:.1%}, {r.collision_high:.1%}] | "
                f"{r.sampled_collision_rate:.1%} | {r.goal_rate:.1%} | {time_to_goal_cell(r)} | "
                + filter_cells)
        out.append("")
    return "\n".join(out)


def _pareto_panels(rows: Sequence[SummaryRow], *, epsilon: float) -> dict[str, list]:
    from agents.experiments.pareto import point_from_summary

    panels: dict[str, list] = defaultdict(list)
    for case in STRESS_SUITE:
        for r in (row for row in rows if row.scenario == case):
            point = point_from_summary(r, _label(r, epsilon))
            if point is not None:
                panels[case].append(point)
    return dict(panels)


def _timing_table(records: Sequence[EpisodeRecord], *, epsilon: float) -> str:
    cells: dict[tuple[str, str], list[float]] = defaultdict(list)
    for r in records:
        cells[(r.case, _label(r, epsilon))].append(r.wall_time)
    lines = ["| case | method | episodes | wall time per episode (s) | cell total (s) |",
             "|---|---|---|---|---|"]
    for (case, label), times in sorted(cells.items(), key=lambda item: (
            list(STRESS_SUITE).index(item[0][0]) if item[0][0] in STRESS_SUITE else 99,
            item[0][1])):
        lines.append(f"| {case} | {label} | {len(times)} | {sum(times) / len(times):.3f} | "
                     f"{sum(times):.1f} |")
    return "\n".join(lines) + "\n"


def run_stress(
    output: str | Path = "results/stress",
    cases: Sequence[str] = tuple(STRESS_SUITE),
    methods: Sequence[str] = tuple(STRESS_METHODS),
    *,
    episodes: int = 200,
    workers: int = 2,
    seed: int = 0,
    planner: str = "ppo",
    reference: str = "rollout",
    policy_path: str = "",
    alpha: float = ALPHA,
    delta: float = DELTA,
    epsilon: float = EPSILON,
    filter_options: dict[str, Any] | str | None = None,
    env_options: dict[str, Any] | str | None = None,
    executor: str | Executor = "process",
    plots: bool = True,
    progress: bool = True,
    overwrite: bool = False,
) -> EvaluationOutputs:
    """Run the stress benchmark and write its CSV, summary and Pareto figure to ``output``.

    Parameters
    ----------
    output
        Output folder (see the module docstring); an interrupted run resumes from it.
    cases
        Names in :data:`~safe_nav_env.stress.STRESS_SUITE`.
    methods
        Names in :data:`STRESS_METHODS`.
    episodes
        Episodes per (case, method).
    epsilon
        The fixed Wasserstein radius of ``dr_cvar``, in m (``dr_cvar_auto`` estimates it).
    workers, seed, planner, reference, policy_path, alpha, delta, filter_options, env_options,
    executor, progress, overwrite
        As for :func:`agents.evaluation.campaign.run_evaluation` (no noise preset: each case
        brings its own noise).
    plots
        Write ``figures/pareto.png``.

    Raises
    ------
    InvalidParameterError, PolicyFileError, RunMismatchError, ...
        As :func:`agents.evaluation.evaluate.evaluate`, before any episode runs.
    """
    output = output_folder(output)
    common: dict[str, Any] = dict(planner=planner, reference=reference,
                                  policy_path=policy_path, alpha=alpha, delta=delta,
                                  filter_options=filter_options or "",
                                  env_options=env_options or "")
    specs = stress_specs(cases, methods, episodes=episodes, seed=seed, epsilon=epsilon,
                         **common)
    start = time.perf_counter()
    records = evaluate(specs=specs, vary=("epsilon",), workers=workers, executor=executor,
                       csv_path=output / "episodes.csv", progress=progress,
                       overwrite=overwrite)
    wall = time.perf_counter() - start
    rows = summarise(records)
    markdown = stress_table(rows, epsilon=epsilon)
    settings = (f"alpha {alpha}, delta {delta} m, epsilon {epsilon} m (dr_cvar; "
                f"dr_cvar (eps=auto) estimates it online), {episodes} episodes per cell, "
                f"seeds {seed}..{seed + episodes - 1} in every cell")
    files = {"episodes": output / "episodes.csv", "run_key": output / "episodes.run.json",
             "summary": output / "summary.md"}
    n_cells = len({(r.case, _label(r, epsilon)) for r in records}) or 1
    (output / "summary.md").write_text(
        "# Stress benchmark\n\n"
        + describe_run(records, planner=planner, reference=reference, settings=settings)
        + f"- this call: {wall:.1f} s wall time on {workers} worker(s) for the "
        f"{len(records)} episodes it returned ({n_cells} cells; episodes resumed from the "
        "CSV cost nothing)\n"
        + "- time to goal: mean over the episodes that reached the goal\n\n"
        + "## Per case\n\n" + markdown
        + "\n## Guarantee audit (realised loss at the step-1 halfspaces)\n\n"
        + _relabel(audit_table(audit_rows(records)), epsilon) + "\n" + AUDIT_NOTE
        + "\n## Wall time per cell (sum of episode wall times, one worker each)\n\n"
        + _timing_table(records, epsilon=epsilon)
    )
    if plots and rows:
        from agents.experiments.pareto import plot_pareto

        files["pareto"] = plot_pareto(
            _pareto_panels(rows, epsilon=epsilon), output / "figures" / "pareto.png",
            title=f"Stress suite, {planner} planner: collision rate (continuous time) against "
            "time to goal, per filter risk")
    return EvaluationOutputs(records, rows, markdown, time.perf_counter() - start, files,
                             reused=records.reused)


def _relabel(table: str, epsilon: float) -> str:
    """The audit table with the fixed-radius DR-CVaR named as in the other tables."""
    return table.replace("| dr_cvar |", f"| dr_cvar (eps={epsilon:g}) |")

"""The stress benchmark by failure class: ``safe-nav evaluate --suite stress``.

Every case of :data:`safe_nav_env.stress.STRESS_SUITE` (a failure class: predictions
that are wrong in a known way, obstacles that turn, stop or crowd, ego actuation the
filter does not model, late predictions) times every reference planner of
``planners`` (the shipped PPO, :data:`DEFAULT_PLANNERS` adds the obstacle-blind
go-to-goal controller :class:`agents.policies.go_to_goal.GoToGoalPolicy`) times every
filter setting of :data:`STRESS_METHODS`, on the same seeds (common random numbers:
episode ``i`` of every cell uses seed ``seed + i``). The default settings are
:data:`DEFAULT_METHODS`: unfiltered, the wrapper's defaults (DR-CVaR, ε = 0.05 m, the
planner's action held as the reference), DR-CVaR with the roll-out reference, and the
two calibrated ones (``risk="conformal"``, ``epsilon="auto"``, roll-out). The episodes
run through :func:`agents.evaluation.evaluate.evaluate`, so the CSV, run key, resume
and ``--overwrite`` behave the same way.

The stress table: :func:`stress_cells` aggregates the records per (case, planner,
setting): continuous-time collisions with a Wilson 95 % interval, the goal rate and the
mean time to goal, and whether the cell meets the target of
:data:`TARGET_COLLISION_RATE` and :data:`TARGET_GOAL_RATE` (point estimates). For every
collided episode it keeps why (:func:`explain_collisions`): the first step whose hard
filter problem was infeasible (``first_infeasible_step``), the filter status before and
at the first collision, and the collision cause of
:class:`~agents.evaluation.records.EpisodeRecord`.

Output folder::

    episodes.csv, episodes.run.json   one row per episode (column ``case``), the run key
    stress_table.csv                  one row per cell (:func:`write_cells`)
    summary.md                        the overview (class x planner x setting, cells that miss
                                      <= 1 % collisions / >= 95 % goal marked), per class:
                                      collisions (continuous time, Wilson 95 %), goal rate,
                                      time to goal, target; the explained collisions (first
                                      infeasible step, status before and at the collision);
                                      the guarantee audit; wall time per cell
    figures/pareto.png                collision rate against time to goal, a panel per case
"""

from __future__ import annotations

import csv
import math
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, fields
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation.campaign import EvaluationOutputs, Report, run_campaign
from agents.evaluation.config import EvaluationConfig, split_options
from agents.evaluation.records import AUTO, PLANNERS, REFERENCES, EpisodeRecord, EpisodeSpec
from agents.evaluation.summary import audit_section, outcomes, table
from filters._validation import integer_at_least
from filters.constants import EPSILON
from filters.errors import InvalidParameterError
from safe_nav_env.scenarios import CUSTOM
from safe_nav_env.stress import STRESS_SUITE

__all__ = ["DEFAULT_CASES", "DEFAULT_METHODS", "DEFAULT_PLANNERS", "STRESS_METHODS",
           "TARGET_COLLISION_RATE", "TARGET_GOAL_RATE", "StressCell", "StressMethod",
           "cells_table", "explain_collisions", "overview_table", "run_stress", "stress_cells",
           "stress_specs", "write_cells"]


@dataclass(frozen=True)
class StressMethod:
    """One filter setting of the benchmark: a risk, its radius and the reference it tracks.

    Attributes
    ----------
    name
        Its name on the command line (``--methods``).
    risk
        A risk of :data:`filters.wrapper.RISKS` (``"none"``: the unfiltered planner).
    auto_epsilon
        Use the wrapper's online Wasserstein radius (``epsilon="auto"``) instead of the
        run's fixed ``epsilon``.
    reference
        ``"hold"`` or ``"rollout"`` (see :data:`~agents.evaluation.records.REFERENCES`),
        or ``None``: the run's ``reference``.
    """

    name: str
    risk: str
    auto_epsilon: bool = False
    reference: str | None = None

    def label(self, epsilon: float) -> str:
        """The name in tables and plots, e.g. ``"dr_cvar (eps=auto)"``."""
        if self.risk == "none":
            return "none (unfiltered)"
        if self.name == "default":
            return f"default wrapper (dr_cvar, eps={epsilon:g}, hold)"
        if self.risk == "dr_cvar":
            return f"dr_cvar (eps={'auto' if self.auto_epsilon else f'{epsilon:g}'})"
        return self.risk


STRESS_METHODS: dict[str, StressMethod] = {m.name: m for m in (
    StressMethod("none", "none"),
    StressMethod("default", "dr_cvar", reference="hold"),
    StressMethod("dr_cvar", "dr_cvar"),
    StressMethod("conformal", "conformal"),
    StressMethod("dr_cvar_auto", "dr_cvar", auto_epsilon=True),
    StressMethod("mean", "mean"),
    StressMethod("cvar", "cvar"),
    StressMethod("gaussian_cc", "gaussian_cc"),
    StressMethod("moment_dr", "moment_dr"),
)}
"""The filter settings, by command-line name, in table order. ``"default"`` is
:class:`filters.SafetyFilterWrapper` with its defaults (the planner's action held); the
others track the run's reference (the roll-out by default)."""

DEFAULT_METHODS: tuple[str, ...] = ("none", "default", "dr_cvar", "conformal", "dr_cvar_auto")
"""The settings the command runs unless told otherwise."""

DEFAULT_PLANNERS: tuple[str, ...] = ("ppo", "goal")
"""The reference planners the command runs unless told otherwise: the shipped PPO and the
obstacle-blind go-to-goal controller."""

DEFAULT_CASES: tuple[str, ...] = tuple(STRESS_SUITE)
"""The failure classes the command runs unless told otherwise: all of them."""


def _names(kind: str, names: Sequence[str], allowed: Sequence[str]) -> list[str]:
    unknown = [n for n in names if n not in allowed]
    if unknown or not names:
        raise InvalidParameterError(f"{kind} must be some of {list(allowed)}, got "
                                    f"{list(names)!r}")
    return list(dict.fromkeys(names))


def stress_specs(
    cases: Sequence[str] = DEFAULT_CASES,
    methods: Sequence[str] = DEFAULT_METHODS,
    planners: Sequence[str] = ("ppo",),
    *,
    episodes: int = 300,
    seed: int = 0,
    epsilon: float = EPSILON,
    reference: str = "rollout",
    **spec_kwargs: Any,
) -> list[EpisodeSpec]:
    """Every (case, planner, method, episode); episode ``i`` uses seed ``seed + i`` in every cell.

    ``reference`` is the reference of the methods that do not fix their own. ``spec_kwargs``
    are further :class:`~agents.evaluation.records.EpisodeSpec` fields (``alpha``,
    ``delta``, ``filter_options``, ...), shared by every episode; the MPC planner
    (``"mpc"``) always tracks its plan, so its ``default`` and ``dr_cvar`` cells coincide.

    Raises
    ------
    InvalidParameterError
        For an unknown case, method or planner, ``episodes < 1`` or a bad setting.
    """
    integer_at_least("episodes", episodes)
    for name in ("scenario", "risk", "seed", "case", "noise", "planner"):
        if name in spec_kwargs:
            raise InvalidParameterError(f"the stress suite sets {name!r} itself")
    cases = _names("cases", cases, list(STRESS_SUITE))
    chosen = [STRESS_METHODS[n] for n in _names("methods", methods, list(STRESS_METHODS))]
    planners = _names("planners", planners, PLANNERS)
    _names("reference", [reference], list(REFERENCES))  # also when every method fixes its own
    policy = spec_kwargs.pop("policy_path", "")
    return [EpisodeSpec(CUSTOM, method.risk, seed + i, planner=planner,
                        reference=method.reference or reference,
                        epsilon=AUTO if method.auto_epsilon else epsilon, case=case,
                        policy_path=policy if planner == "ppo" else "", **spec_kwargs)
            for case in cases for planner in planners for method in chosen
            for i in range(episodes)]


def _method_of(record: EpisodeRecord, reference: str, epsilon: float) -> tuple[str, str]:
    """The method (name, label) a record ran: its risk, radius and reference."""
    auto = record.epsilon == AUTO
    for method in STRESS_METHODS.values():
        if (method.risk == record.risk and method.auto_epsilon == auto
                and (record.risk == "none" or (method.reference or reference)
                     == record.reference)):
            return method.name, method.label(epsilon)
    return f"{record.risk}/{record.reference}", f"{record.risk} ({record.reference})"


def _order(key: tuple[str, str, str]) -> tuple:
    """Table order of a cell: case, planner and method as listed, unknown names last."""
    lists = [list(STRESS_SUITE), list(PLANNERS), list(STRESS_METHODS)]
    return (*(order.index(name) if name in order else len(order)
              for name, order in zip(key, lists, strict=True)), key[2])


# ---------------------------------------------------------------------------- the table
TARGET_COLLISION_RATE = 0.01
"""A cell meets the target with at most this share of collided episodes (continuous time)..."""

TARGET_GOAL_RATE = 0.95
"""... and at least this share reaching the goal."""

_Cell = tuple[str, str, str]
"""A stress cell's (case, planner, method name)."""

_MethodOf = Callable[[EpisodeRecord], tuple[str, str]]
"""``record -> (method name, label)``: :func:`_method_of` for the run's reference and radius."""


@dataclass(frozen=True)
class StressCell:
    """The episodes of one (case, planner, method) of the stress suite.

    Attributes
    ----------
    case, planner, method
        The failure class, the reference planner and the filter setting (their names).
    label
        The setting's name in tables.
    episodes, failed
        Episodes recorded and those that failed (an exception; left out of the rates).
    collisions, collision_rate, collision_low, collision_high
        Collided episodes (continuous time), their share and its Wilson 95 % interval.
    goal_rate, time_to_goal
        Share reaching the goal; mean time to goal in s over those (NaN if none).
    meets_target
        ``collision_rate <= 1 %`` and ``goal_rate >= 95 %``.
    fallback_collisions, inter_sample_collisions, noise_collisions
        Collided episodes by ``collision_cause``.
    infeasible_before
        Collided episodes whose first infeasible step came at or before the collision.
    """

    case: str
    planner: str
    method: str
    label: str
    episodes: int
    failed: int
    collisions: int
    collision_rate: float
    collision_low: float
    collision_high: float
    goal_rate: float
    time_to_goal: float
    meets_target: bool
    fallback_collisions: int = 0
    inter_sample_collisions: int = 0
    noise_collisions: int = 0
    infeasible_before: int = 0


def _infeasible_before(record: EpisodeRecord) -> bool:
    return 0 < record.first_infeasible_step <= record.first_collision_step


def by_cell(records: Iterable[EpisodeRecord],
             method_of: _MethodOf) -> dict[_Cell, list[EpisodeRecord]]:
    """The records by (case, planner, method name)."""
    groups: dict[_Cell, list[EpisodeRecord]] = {}
    for record in records:
        groups.setdefault((record.case, record.planner, method_of(record)[0]), []).append(record)
    return groups


def stress_cells(groups: dict[_Cell, list[EpisodeRecord]], method_of: _MethodOf
                 ) -> list[StressCell]:
    """One :class:`StressCell` per group of :func:`by_cell`, in table order (:func:`_order`);
    ``method_of``: ``record -> (method name, label)``."""
    cells = []
    for key in sorted(groups, key=_order):
        group = groups[key]
        stats = {k: v for k, v in outcomes(group).items() if k != "arrivals"}
        collided = [r for r in group if r.collision and not r.error]
        causes = Counter(r.collision_cause for r in collided)
        cells.append(StressCell(
            *key, label=method_of(group[-1])[1], collisions=len(collided), **stats,
            meets_target=bool(stats["episodes"] > stats["failed"]
                              and stats["collision_rate"] <= TARGET_COLLISION_RATE
                              and stats["goal_rate"] >= TARGET_GOAL_RATE),
            fallback_collisions=causes["fallback"],
            inter_sample_collisions=causes["inter_sample"], noise_collisions=causes["noise"],
            infeasible_before=sum(_infeasible_before(r) for r in collided)))
    return cells


def cells_table(cells: Sequence[StressCell], descriptions: dict[str, str]) -> str:
    """Per case, a Markdown table of its cells (collisions, goal, time to goal, target)."""
    columns = ("planner", "setting", "episodes", "collisions [95 % CI]", "goal rate",
               "time to goal (s)", "target")
    out = []
    for case in dict.fromkeys(c.case for c in cells):
        rows = [[c.planner, c.label,
                 f"{c.episodes}" + (f" ({c.failed} failed)" if c.failed else ""),
                 f"{c.collision_rate:.1%} [{c.collision_low:.1%}, {c.collision_high:.1%}]",
                 f"{c.goal_rate:.1%}",
                 "-" if math.isnan(c.time_to_goal) else f"{c.time_to_goal:.2f}",
                 "yes" if c.meets_target else "**MISS**"] for c in cells if c.case == case]
        out.append(f"### {case}: {descriptions.get(case, '')}\n\n" + table(columns, rows))
    return "\n".join(out)


def overview_table(cells: Sequence[StressCell]) -> str:
    """Classes as rows, (planner, setting) as columns: ``collisions / goal``, MISS marked."""
    columns = list(dict.fromkeys((c.planner, c.label) for c in cells))
    by_key = {(c.case, c.planner, c.label): c for c in cells}
    rows = []
    for case in dict.fromkeys(c.case for c in cells):
        entries = (by_key.get((case, *column)) for column in columns)
        rows.append([case, *("" if c is None else f"{c.collision_rate:.1%} / {c.goal_rate:.0%}"
                             + ("" if c.meets_target else " ✗") for c in entries)])
    return table(("class", *(f"{p}: {label}" for p, label in columns)), rows)


def explain_collisions(groups: dict[_Cell, list[EpisodeRecord]],
                       cells: Sequence[StressCell]) -> str:
    """Per case, the cells with collisions and why they happened (Markdown).

    For each such cell: collisions by cause (``fallback``: a non-optimal filter status
    within two steps before the collision; ``inter_sample``; ``noise``), how many had an
    infeasible hard problem at or before the collision and the median lead in steps
    from the first infeasible step to the collision, and the status transitions
    ``before -> at`` the collision with their counts.
    """
    columns = ("planner", "setting", "collisions", "fallback / inter-sample / noise",
               "infeasible before", "median lead (steps)", "status before → at")
    out = []
    for case in dict.fromkeys(c.case for c in cells):
        rows = []
        for c in (c for c in cells if c.case == case and c.collisions):
            group = [r for r in groups[(c.case, c.planner, c.method)]
                     if r.collision and not r.error]
            leads = [r.first_collision_step - r.first_infeasible_step for r in group
                     if _infeasible_before(r)]
            transitions = Counter(f"{r.status_before_collision or '(start)'} → "
                                  f"{r.status_at_collision}" for r in group)
            rows.append([c.planner, c.label, str(c.collisions),
                         f"{c.fallback_collisions} / {c.inter_sample_collisions} / "
                         f"{c.noise_collisions}", str(c.infeasible_before),
                         f"{float(np.median(leads)):.0f}" if leads else "-",
                         ", ".join(f"{t}: {n}" for t, n in transitions.most_common())])
        if rows:
            out.append(f"### {case}\n\n" + table(columns, rows))
    return "\n".join(out) if out else "No collisions.\n"


def write_cells(cells: Sequence[StressCell], path: str | Path) -> Path:
    """Write the cells as CSV (one row per cell, the fields of :class:`StressCell` in order);
    return the path."""
    path = Path(path)
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=[f.name for f in fields(StressCell)])
        writer.writeheader()
        writer.writerows(asdict(cell) for cell in cells)
    return path


def _timing_table(cells: Sequence[StressCell], groups: dict[_Cell, list[EpisodeRecord]]
                  ) -> str:
    rows = []
    for c in cells:
        t = [r.wall_time for r in groups[(c.case, c.planner, c.method)]]
        rows.append([c.case, c.planner, c.label, str(len(t)), f"{sum(t) / max(1, len(t)):.3f}",
                     f"{sum(t):.1f}"])
    return table(("case", "planner", "setting", "episodes", "wall time per episode (s)",
                  "cell total (s)"), rows)


def run_stress(output: str | Path | None = None, cases: Sequence[str] = DEFAULT_CASES,
               methods: Sequence[str] = DEFAULT_METHODS, *,
               planners: Sequence[str] = DEFAULT_PLANNERS, config: EvaluationConfig | None = None,
               episodes: int = 300, seed: int = 0, reference: str = "rollout",
               epsilon: float = EPSILON, **options: Any) -> EvaluationOutputs:
    """Run the stress benchmark; write its CSVs, summary and Pareto figure to ``output``.

    Parameters
    ----------
    output
        Output folder (see the module docstring; default ``results/stress``); an
        interrupted run resumes from it.
    cases
        Names in :data:`~safe_nav_env.stress.STRESS_SUITE`.
    methods
        Names in :data:`STRESS_METHODS`.
    planners
        Reference planners (:data:`~agents.evaluation.records.PLANNERS`).
    config
        How to run (:class:`~agents.evaluation.config.EvaluationConfig`); ``plots`` draws
        ``figures/pareto.png``.
    episodes
        Episodes per (case, planner, method), seeds ``seed .. seed + episodes - 1``.
    reference
        The reference of the methods that do not fix their own (all but ``default``).
    epsilon
        The fixed Wasserstein radius of ``dr_cvar`` and ``default``, in m
        (``dr_cvar_auto`` estimates it).
    options
        As for :func:`agents.evaluation.campaign.run_evaluation`, without ``noise`` and
        ``planner`` (each case brings its own noise; ``planners`` above);
        ``policy_path`` is the PPO planner's.

    Returns
    -------
    EvaluationOutputs
        Its ``rows`` are the :class:`StressCell` of the run.

    Raises
    ------
    InvalidParameterError, PolicyFileError, RunMismatchError, ...
        As :func:`agents.evaluation.campaign.run_campaign`, before any episode runs.
    """
    config, settings = split_options(config, output, options, default="results/stress")
    specs = stress_specs(cases, methods, planners, episodes=episodes, seed=seed,
                         epsilon=epsilon, reference=reference, **settings)

    method_of = partial(_method_of, reference=reference, epsilon=epsilon)

    def report(records: Sequence[EpisodeRecord]) -> Report:
        groups = by_cell(records, method_of)
        cells = stress_cells(groups, method_of)
        markdown = cells_table(cells, {n: case.description for n, case in STRESS_SUITE.items()})
        missed = sum(not c.meets_target for c in cells)
        body = (
            f"- methods: dr_cvar (eps=auto) estimates epsilon online; every method but the "
            f"default wrapper (`hold`) tracks the reference `{reference}`\n"
            + f"- target: at most {TARGET_COLLISION_RATE:.0%} collisions and at least "
            f"{TARGET_GOAL_RATE:.0%} goal (point estimates); {missed} of {len(cells)} cells "
            "miss it (marked ✗ / **MISS**)\n"
            + "- time to goal: mean over the episodes that reached the goal\n\n"
            + "## Overview: collisions (continuous time) / goal rate\n\n"
            + overview_table(cells)
            + "\n## Per class\n\n" + markdown
            + "\n## Explained collisions\n\n"
            "Per cell with collisions: the cause (fallback: a non-optimal filter status at "
            "the collision or the two steps before; inter-sample: overlap only between "
            "samples; noise: after nominal steps), how many had an infeasible hard problem "
            "(`first_infeasible_step`) at or before the collision and the median lead in "
            "steps from it to the collision, and the filter status at the step before and at "
            "the collision (`status_before_collision` → `status_at_collision`).\n\n"
            + explain_collisions(groups, cells) + audit_section(records)
            + "\n## Wall time per cell (sum of episode wall times, one worker each)\n\n"
            + _timing_table(cells, groups))
        return Report("Stress benchmark by failure class", body, cells, markdown,
                      files={"table": write_cells(cells, config.output / "stress_table.csv")},
                      figures=lambda folder: _pareto_figure(cells, folder))

    return run_campaign(specs, config, report,
                        vary=("epsilon", "planner", "reference", "policy_sha256"))


def _pareto_figure(cells: Sequence[StressCell], folder: Path) -> dict[str, Path]:
    """``pareto.png``: per case, a point per (planner, setting) that ran at least once."""
    from agents.experiments.pareto import ParetoPoint, plot_pareto

    panels: dict[str, list] = defaultdict(list)
    for c in cells:
        if c.episodes > c.failed:
            panels[c.case].append(ParetoPoint(f"{c.planner}: {c.label}", c.collisions,
                                              c.episodes - c.failed, c.time_to_goal))
    return {"pareto": plot_pareto(
        dict(panels), folder / "pareto.png",
        title="Stress suite: collision rate (continuous time) against time to goal, per "
        "planner and filter setting")} if cells else {}

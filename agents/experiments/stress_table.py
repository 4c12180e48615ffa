"""The stress table: one row per (failure class, reference planner, filter setting).

:func:`stress_cells` aggregates the records of ``safe-nav evaluate --suite stress``
(:mod:`agents.experiments.stress`) per cell: continuous-time collisions with a Wilson
95 % interval, the goal rate and the mean time to goal, and whether the cell meets the
target of :data:`TARGET_COLLISION_RATE` and :data:`TARGET_GOAL_RATE` (point estimates).
For every collided episode it keeps why (:func:`explain_collisions`): the first step
whose hard filter problem was infeasible (``first_infeasible_step``), the filter status
before and at the first collision, and the collision cause of
:class:`~agents.evaluation.records.EpisodeRecord`. The Markdown tables and the CSV
(:func:`write_cells`) are what ``summary.md`` and ``stress_table.csv`` hold.
"""

from __future__ import annotations

import csv
import math
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from agents.evaluation.records import EpisodeRecord
from agents.evaluation.summary import outcomes, table

__all__ = ["TARGET_COLLISION_RATE", "TARGET_GOAL_RATE", "StressCell", "cells_table",
           "explain_collisions", "overview_table", "stress_cells", "write_cells"]

TARGET_COLLISION_RATE = 0.01
"""A cell meets the target with at most this share of collided episodes (continuous time)..."""

TARGET_GOAL_RATE = 0.95
"""... and at least this share reaching the goal."""

_Cell = tuple[str, str, str]
"""A stress cell's (case, planner, method name)."""

_MethodOf = Callable[[EpisodeRecord], tuple[str, str]]
"""``record -> (method name, label)`` of the caller (:mod:`agents.experiments.stress`)."""


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


def stress_cells(
    records: Sequence[EpisodeRecord],
    method_of: _MethodOf,
    order: Callable[[_Cell], tuple],
) -> list[StressCell]:
    """One :class:`StressCell` per (case, planner, method), sorted by ``order``.

    Parameters
    ----------
    records
        The suite's records.
    method_of
        ``record -> (method name, label)``.
    order
        Sort key of a ``(case, planner, method)``.
    """
    groups = by_cell(records, method_of)
    cells = []
    for key in sorted(groups, key=order):
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


def explain_collisions(
    records: Sequence[EpisodeRecord],
    cells: Sequence[StressCell],
    method_of: _MethodOf,
) -> str:
    """Per case, the cells with collisions and why they happened (Markdown).

    For each such cell: collisions by cause (``fallback``: a non-optimal filter status
    within two steps before the collision; ``inter_sample``; ``noise``), how many had an
    infeasible hard problem at or before the collision and the median lead in steps
    from the first infeasible step to the collision, and the status transitions
    ``before -> at`` the collision with their counts.
    """
    collided = by_cell((r for r in records if r.collision and not r.error), method_of)
    columns = ("planner", "setting", "collisions", "fallback / inter-sample / noise",
               "infeasible before", "median lead (steps)", "status before → at")
    out = []
    for case in dict.fromkeys(c.case for c in cells):
        rows = []
        for c in (c for c in cells if c.case == case and c.collisions):
            group = collided.get((c.case, c.planner, c.method), [])
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

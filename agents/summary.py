"""Summary statistics of evaluation records: the table users read.

Per (scenario, planner, risk): the collision rate with a Wilson 95 % confidence
interval, the worst and the CVaR (lower 10 % tail mean) of the minimum distance to
collision, the goal rate and time to goal, the intervention size (how far the filter
moved the reference planner's action) and the filter's step time.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from agents.evaluation import EpisodeRecord

RISK_ORDER = {"none": 0, "mean": 1, "cvar": 2, "dr_cvar": 3}


def wilson_interval(successes: int, trials: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95 % by default).

    .. math::
        \\frac{\\hat p + z^2/2n \\pm z\\sqrt{\\hat p(1-\\hat p)/n + z^2/4n^2}}{1 + z^2/n}
    """
    if trials <= 0:
        return (math.nan, math.nan)
    p = successes / trials
    denominator = 1.0 + z * z / trials
    centre = (p + z * z / (2 * trials)) / denominator
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / denominator
    return (max(0.0, centre - half), min(1.0, centre + half))


def lower_tail_mean(values: np.ndarray, fraction: float = 0.1) -> float:
    """Mean of the lowest ``fraction`` of ``values`` (the CVaR of a distance, worst tail)."""
    values = np.sort(np.asarray(values, dtype=float)[np.isfinite(values)])
    if values.size == 0:
        return math.nan
    count = max(1, int(math.ceil(fraction * values.size)))
    return float(values[:count].mean())


@dataclass(frozen=True)
class SummaryRow:
    """Aggregate of the episodes of one (scenario, planner, risk)."""

    scenario: str
    planner: str
    risk: str
    episodes: int
    failed: int
    collision_rate: float
    collision_low: float
    collision_high: float
    worst_distance: float
    cvar_distance: float
    goal_rate: float
    time_to_goal: float
    mean_intervention: float
    fallback_share: float
    filter_time_ms: float


def summarise(records: Iterable[EpisodeRecord]) -> list[SummaryRow]:
    """One :class:`SummaryRow` per (scenario, planner, risk), in a stable order."""
    groups: dict[tuple[str, str, str], list[EpisodeRecord]] = defaultdict(list)
    for record in records:
        groups[(record.scenario, record.planner, record.risk)].append(record)
    rows = []
    for (scenario, planner, risk), group in sorted(
        groups.items(), key=lambda item: (item[0][0], item[0][1], RISK_ORDER.get(item[0][2], 9))
    ):
        ok = [r for r in group if not r.error]
        n = len(ok)
        collisions = sum(r.collision for r in ok)
        low, high = wilson_interval(collisions, n)
        distances = np.array([r.min_distance for r in ok], dtype=float)
        times = [r.time_to_goal for r in ok if r.goal_reached]
        steps = sum(r.steps for r in ok)
        rows.append(SummaryRow(
            scenario=scenario, planner=planner, risk=risk, episodes=len(group),
            failed=len(group) - n,
            collision_rate=collisions / n if n else math.nan,
            collision_low=low, collision_high=high,
            worst_distance=float(np.nanmin(distances)) if n else math.nan,
            cvar_distance=lower_tail_mean(distances),
            goal_rate=sum(r.goal_reached for r in ok) / n if n else math.nan,
            time_to_goal=float(np.mean(times)) if times else math.nan,
            mean_intervention=float(np.mean([r.mean_intervention for r in ok])) if n else math.nan,
            fallback_share=sum(r.fallback_steps for r in ok) / steps if steps else math.nan,
            filter_time_ms=1e3 * float(np.median([r.filter_time_median for r in ok]))
            if n else math.nan,
        ))
    return rows


def short_name(scenario: str) -> str:
    """``"SafeNav/HeadOn-v0"`` -> ``"HeadOn"``."""
    return scenario.split("/")[-1].rsplit("-v", 1)[0]


def markdown_table(rows: Sequence[SummaryRow]) -> str:
    """The summary as a Markdown table."""
    header = ("| scenario | planner | risk | episodes | collision rate [95 % CI] | "
              "worst distance (m) | CVaR10 distance (m) | goal rate | time to goal (s) | "
              "mean intervention (m/s²) | fallback steps | filter time (ms) |")
    lines = [header, "|" + "---|" * 12]
    for r in rows:
        failed = f" ({r.failed} failed)" if r.failed else ""
        lines.append(
            f"| {short_name(r.scenario)} | {r.planner} | {r.risk} | {r.episodes}{failed} | "
            f"{r.collision_rate:.1%} [{r.collision_low:.1%}, {r.collision_high:.1%}] | "
            f"{r.worst_distance:.3f} | {r.cvar_distance:.3f} | {r.goal_rate:.1%} | "
            f"{r.time_to_goal:.2f} | {r.mean_intervention:.3f} | {r.fallback_share:.1%} | "
            f"{r.filter_time_ms:.2f} |"
        )
    return "\n".join(lines) + "\n"

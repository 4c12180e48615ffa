"""Summary statistics of evaluation records: the tables users read.

Per (scenario, planner, risk): the collision rate in continuous time with a Wilson
95 % confidence interval and the sampled one (the paper's), the worst and the CVaR
(lower 10 % tail mean) of the minimum distance to collision, the goal rate and time
to goal, the intervention size (how far the filter moved the reference planner's
action), the filter's step time; then the share of steps with each filter status,
the collisions by cause and the first reason the filter braked on bad data.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from agents.evaluation.records import AUTO, FILTER_STATUSES, RISK_ORDER, EpisodeRecord
from agents.evaluation.statistics import wilson_interval
from filters.risk import empirical_cvar

COLLISION_CAUSES = ("fallback", "inter_sample", "noise")
"""Values of :attr:`EpisodeRecord.collision_cause` for a collided episode."""


def lower_tail_mean(values: np.ndarray, fraction: float = 0.1) -> float:
    r"""The CVaR of a distance's worst (lowest) tail over the finite ``values``, NaN if none.

    .. math:: -\mathrm{CVaR}_\alpha(-x), \qquad \alpha = \text{fraction},

    the mean of the lowest ``fraction`` of the values, fractional atom included
    (:func:`filters.risk.empirical_cvar`).
    """
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    return float(-empirical_cvar(-values, fraction)) if values.size else math.nan


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
    sampled_collision_rate: float = math.nan
    worst_swept_distance: float = math.nan
    status_shares: tuple[tuple[str, float], ...] = ()
    collision_causes: tuple[tuple[str, int], ...] = ()
    first_error: str = ""
    first_failure: str = ""
    method: str = ""
    arrivals: int = 0


def method_label(risk: str, epsilon: float | str) -> str:
    """The method's name in tables: the risk, ``"dr_cvar (eps=auto)"`` for the online radius."""
    return f"{risk} (eps=auto)" if epsilon == AUTO else risk


def _groups(records: Iterable[EpisodeRecord]) -> list[tuple[tuple[str, str, str, str],
                                                             list[EpisodeRecord]]]:
    """The records by (scenario or stress case, planner, risk, :func:`method_label`), in
    table order: scenario, planner, risk (:data:`RISK_ORDER`), the online radius last."""
    groups: dict[tuple[str, str, str, str], list[EpisodeRecord]] = defaultdict(list)
    for r in records:
        groups[(r.case or r.scenario, r.planner, r.risk, method_label(r.risk, r.epsilon))].append(r)
    return sorted(groups.items(), key=lambda item: (
        item[0][0], item[0][1], RISK_ORDER.get(item[0][2], len(RISK_ORDER)), item[0][3]))


def outcomes(group: Sequence[EpisodeRecord]) -> dict[str, Any]:
    """The outcome columns of a group of episodes (fields of :class:`SummaryRow`).

    ``episodes`` and ``failed`` (an exception; left out of the rates), the collision
    rate in continuous time with its Wilson 95 % interval (``collision_low``,
    ``collision_high``), the goal rate, the mean time to goal in s over the ``arrivals``
    (NaN if none); rates are NaN when no episode ran.
    """
    ok = [r for r in group if not r.error]
    n = len(ok)
    collisions = sum(r.collision for r in ok)
    times = [r.time_to_goal for r in ok if r.goal_reached]
    low, high = wilson_interval(collisions, n)
    return dict(episodes=len(group), failed=len(group) - n,
                collision_rate=collisions / n if n else math.nan, collision_low=low,
                collision_high=high, goal_rate=len(times) / n if n else math.nan,
                time_to_goal=float(np.mean(times)) if times else math.nan, arrivals=len(times))


def summarise(records: Iterable[EpisodeRecord]) -> list[SummaryRow]:
    """One :class:`SummaryRow` per (scenario, planner, risk), in a stable order.

    A stress-suite record counts under its case (``record.case``) as the scenario, and
    ``epsilon="auto"`` is a method of its own (``method`` ``"dr_cvar (eps=auto)"``).
    """
    rows = []
    for (scenario, planner, risk, method), group in _groups(records):
        ok = [r for r in group if not r.error]
        n = len(ok)
        distances = np.array([r.min_distance for r in ok], dtype=float)
        steps = sum(r.steps for r in ok)
        swept = np.array([r.min_swept_distance for r in ok], dtype=float)
        shares = tuple(
            (status, sum(getattr(r, f"share_{status}") * r.steps for r in ok) / steps)
            for status in FILTER_STATUSES) if steps else ()
        rows.append(SummaryRow(
            scenario=scenario, planner=planner, risk=risk, **outcomes(group),
            worst_distance=(float(np.nanmin(distances)) if n and not np.isnan(distances).all()
                            else math.nan),
            cvar_distance=lower_tail_mean(distances),
            mean_intervention=float(np.mean([r.mean_intervention for r in ok])) if n else math.nan,
            fallback_share=sum(r.fallback_steps for r in ok) / steps if steps else math.nan,
            filter_time_ms=1e3 * float(np.median([r.filter_time_median for r in ok]))
            if n else math.nan,
            sampled_collision_rate=sum(r.sampled_collision for r in ok) / n if n else math.nan,
            worst_swept_distance=(float(np.nanmin(swept)) if n and np.isfinite(swept).any()
                                  else math.nan),
            status_shares=shares, collision_causes=tuple(
                (cause, sum(r.collision_cause == cause for r in ok)) for cause in COLLISION_CAUSES),
            first_error=next((f"seed {r.seed}, {r.first_error}" for r in ok if r.first_error), ""),
            first_failure=next((f"seed {r.seed}: {r.error}" for r in group if r.error), "")[:200],
            method=method,
        ))
    return rows


def short_name(scenario: str) -> str:
    """``"SafeNav/HeadOn-v0"`` -> ``"HeadOn"``."""
    return scenario.split("/")[-1].rsplit("-v", 1)[0]


def table(columns: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    """A Markdown table of text cells: the header, its rule, one line per row."""
    return "\n".join(["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns),
                      *("| " + " | ".join(row) + " |" for row in rows)]) + "\n"


def markdown_table(rows: Sequence[SummaryRow]) -> str:
    """The summary as a Markdown table (collisions in continuous time unless "sampled")."""
    columns = ("scenario", "planner", "risk", "episodes", "collision rate [95 % CI]",
               "sampled collision rate", "worst distance (m)", "worst swept distance (m)",
               "CVaR10 distance (m)", "goal rate", "time to goal (s)",
               "mean intervention (m/s²)", "fallback steps", "filter time (ms)")
    return table(columns, ([
        short_name(r.scenario), r.planner, r.method or r.risk,
        f"{r.episodes}" + (f" ({r.failed} failed)" if r.failed else ""),
        f"{r.collision_rate:.1%} [{r.collision_low:.1%}, {r.collision_high:.1%}]",
        f"{r.sampled_collision_rate:.1%}", f"{r.worst_distance:.3f}",
        f"{r.worst_swept_distance:.3f}", f"{r.cvar_distance:.3f}", f"{r.goal_rate:.1%}",
        # the mean time to goal, or a dash and the count (the mean of nothing is no number)
        f"{r.time_to_goal:.2f}" if r.arrivals and math.isfinite(r.time_to_goal)
        else f"- ({r.arrivals} arrived)", f"{r.mean_intervention:.3f}", f"{r.fallback_share:.1%}",
        f"{r.filter_time_ms:.2f}"] for r in rows))


def status_table(rows: Sequence[SummaryRow]) -> str:
    """Share of steps per filter status, collisions by cause, first bad-data reason."""
    columns = ("scenario", "planner", "risk", *FILTER_STATUSES,
               "collisions by cause (" + " / ".join(COLLISION_CAUSES) + ")", "first error")
    return table(columns, ([
        short_name(r.scenario), r.planner, r.method or r.risk,
        *(f"{dict(r.status_shares)[s]:.1%}" if s in dict(r.status_shares) and r.risk != "none"
          else "-" for s in FILTER_STATUSES),  # "none": every step is a passthrough
        " / ".join(str(dict(r.collision_causes).get(c, 0)) for c in COLLISION_CAUSES),
        (r.first_error or r.first_failure or "").replace("|", "/")] for r in rows))


# ---------------------------------------------------------------------------- guarantee audit
@dataclass(frozen=True)
class AuditRow:
    """The guarantee audit of one (scenario or case, planner, method).

    See :mod:`agents.evaluation.audit`.

    Attributes
    ----------
    scenario, planner, risk, method
        As in :class:`SummaryRow`.
    promise
        ``"mean"``, ``"cvar"`` or ``"chance"`` (:data:`agents.evaluation.audit.PROMISES`).
    active
        :class:`agents.evaluation.audit.AuditResult` of the pooled losses of the *active*
        first-step halfspaces (the audit the issue asks for).
    all
        The same over every first-step halfspace, active or not (far more steps: the
        offset's promise is about the obstacle's law, whatever the ego does).
    """

    scenario: str
    planner: str
    risk: str
    method: str
    promise: str
    active: Any
    all: Any


def audit_rows(records: Iterable[EpisodeRecord]) -> list[AuditRow]:
    """Pool the records' audit losses per (scenario or case, planner, method).

    Unfiltered runs (``risk="none"``, no halfspaces) and failed episodes are left out.
    Each group's ``alpha`` and ``delta`` are its records' (a group mixing several
    raises :class:`~filters.errors.InvalidParameterError`).
    """
    from agents.evaluation.audit import PROMISES, audit_losses, decode_losses
    from filters.errors import InvalidParameterError

    rows = []
    for (scenario, planner, risk, method), group in _groups(
            r for r in records if r.risk != "none" and not r.error):
        settings = {(r.alpha, r.delta) for r in group}
        if len(settings) > 1:
            raise InvalidParameterError(
                f"the audit pools one (alpha, delta) per method; {scenario} {risk} has "
                f"{sorted(settings)}")
        alpha, delta = settings.pop()
        active, pooled = (audit_losses([], groups=[decode_losses(getattr(r, column))
                                                   for r in group], alpha=alpha, delta=delta)
                          for column in ("audit_losses", "audit_all_losses"))
        rows.append(AuditRow(scenario, planner, risk, method, PROMISES[risk], active, pooled))
    return rows


_PROMISE_TEXT = {"mean": "E ℓ ≤ δ", "cvar": "CVaR_α ℓ ≤ δ", "chance": "P(ℓ > δ) ≤ α"}


def _audit_cells(result: Any, promise: str) -> list[str]:
    """n, mean, CVaR, P(loss > delta) [CI], verdict; the promised quantity in bold."""
    if result.n == 0:
        return ["0", "-", "-", "-", "-"]

    cells = {kind: f"{value:.3f}" + ("" if math.isnan(low) else f" [{low:.3f}, {high:.3f}]")
             for kind, value, low, high in (
                 ("mean", result.mean_loss, result.mean_low, result.mean_high),
                 ("cvar", result.cvar_loss, result.cvar_low, result.cvar_high))}
    cells["chance"] = (f"{result.violation_rate:.1%} [{result.violation_low:.1%}, "
                       f"{result.violation_high:.1%}]")
    return [str(result.n), *(f"**{text}**" if kind == promise else text
                             for kind, text in cells.items()), result.verdict(promise)]


def audit_table(rows: Sequence[AuditRow]) -> str:
    """The guarantee audit as Markdown: each method's promise against the realised losses.

    Two pools side by side: the active first-step halfspaces, and all of them. The
    promised quantity is in bold; the verdict is
    :meth:`agents.evaluation.audit.AuditResult.verdict`.
    """
    pool = ["n", "mean ℓ (m)", "CVaR_α ℓ (m)", "P(ℓ > δ) [95 % CI]", "verdict"]
    columns = ["scenario", "planner", "method", "promise", "α", "δ (m)",
               *(f"active: {c}" for c in pool), *(f"all: {c}" for c in pool)]
    return table(columns, ([short_name(r.scenario), r.planner, r.method,
                            _PROMISE_TEXT[r.promise], f"{r.active.alpha:g}",
                            f"{r.active.delta:g}", *_audit_cells(r.active, r.promise),
                            *_audit_cells(r.all, r.promise)] for r in rows))


AUDIT_NOTE = (
    "Loss ℓ = b + r − h·p of each obstacle's step-1 halfspace h·y ≤ b (r = r_A + r_O), at "
    "the obstacle's realised position p one step later: the intrusion depth the risk bounds "
    "(docs/design.md). *active*: the steps where the applied plan's step-1 position lay "
    "within the inter-sample bow margin + 1 mm of the offset, or beyond it "
    "(agents/evaluation/audit.py); *all*: every step-1 halfspace, active or not. "
    "The promised quantity is in bold. Intervals (95 %): Wilson for P(ℓ > δ), which "
    "treats the steps as independent (successive steps of an episode are not, so it is "
    "optimistic); a cluster "
    "bootstrap over episodes (1000 replicates, seed 0) for the mean and the CVaR. Verdict: "
    "held if the point estimate meets the bound, violated if the whole interval lies "
    "beyond it, else within noise.\n")
"""Explanation printed under the audit table."""


def audit_section(records: Iterable[EpisodeRecord]) -> str:
    """The summary pages' guarantee-audit section: its heading, table and note."""
    return ("\n## Guarantee audit (realised loss at the step-1 halfspaces)\n\n"
            + audit_table(audit_rows(records)) + "\n" + AUDIT_NOTE)

"""Pareto plots: collision rate (continuous time) against mean time to goal, per method.

A small data-in API, so that any comparison can draw one: a :class:`ParetoPoint` per
method (a label, the collided episodes out of ``n``, the mean time to goal) and one
panel per case. The collision rate gets its Wilson 95 % interval as error bars. Lower
left is better on both axes: a method is *dominated* if another is at least as good on
both and better on one (by the point estimates; the intervals say how sure that is).
matplotlib is imported inside :func:`plot_pareto` only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from agents.evaluation.plots import pyplot, save_figure
from agents.evaluation.summary import wilson_interval
from filters._validation import finite_scalar, integer_at_least
from filters.errors import InvalidParameterError

__all__ = ["TIME_LABEL", "ParetoPoint", "dominated", "plot_pareto", "point_from_summary"]

TIME_LABEL = "mean time to goal (s), over the episodes that reached it"
"""Default x-axis label: the time to goal is averaged over the successful episodes only."""


@dataclass(frozen=True)
class ParetoPoint:
    """One method in one case.

    Attributes
    ----------
    label
        The method's name in the legend (e.g. ``"dr_cvar (eps=auto)"``).
    collisions, n
        Episodes with a collision (continuous time) and episodes run; ``0 <= collisions
        <= n``, ``n >= 1``.
    time_to_goal
        Mean time to goal in s over the episodes that reached it (NaN if none did:
        the point is then left out of the panel and named in its corner).
    """

    label: str
    collisions: int
    n: int
    time_to_goal: float

    def __post_init__(self) -> None:
        collisions = integer_at_least("collisions", self.collisions, low=0)
        if integer_at_least("n", self.n, low=0) < max(1, collisions):
            raise InvalidParameterError(f"need n >= 1 and 0 <= collisions <= n, got collisions "
                                        f"{self.collisions}, n {self.n} ({self.label!r})")
        if not (isinstance(self.time_to_goal, float) and math.isnan(self.time_to_goal)):
            finite_scalar(f"time_to_goal of {self.label!r} (s, or NaN)", self.time_to_goal, low=0)

    @property
    def rate(self) -> float:
        """Collision rate ``collisions / n``."""
        return self.collisions / self.n


def point_from_summary(row: object, label: str) -> ParetoPoint | None:
    """The point of a :class:`~agents.evaluation.summary.SummaryRow` (``None`` if no episode ran).

    The summary keeps the collision *rate* over the episodes that did not fail; the
    count is recovered as ``round(rate * n)`` with ``n = episodes - failed``.
    """
    n = row.episodes - row.failed
    if n < 1:
        return None
    return ParetoPoint(label, round(row.collision_rate * n), n, float(row.time_to_goal))


def dominated(points: Sequence[ParetoPoint]) -> list[bool]:
    """For each point, whether another is no worse on both axes and better on one.

    Points without a time to goal (NaN) are never dominated and dominate nothing.
    """
    return [not math.isnan(p.time_to_goal) and any(
        not math.isnan(q.time_to_goal) and q.rate <= p.rate and q.time_to_goal <= p.time_to_goal
        and (q.rate < p.rate or q.time_to_goal < p.time_to_goal) for q in points if q is not p)
        for p in points]


def plot_pareto(panels: Mapping[str, Sequence[ParetoPoint]], path: str | Path, *,
                title: str | None = None, columns: int = 2) -> Path:
    """One figure, one panel per case: collision rate against time to goal for every method.

    Parameters
    ----------
    panels
        ``{case name: points}``; the same label keeps its colour and marker across panels.
    path
        Where the PNG goes (folders are created).
    title
        Figure title (the axes: :data:`TIME_LABEL` and the collision rate).
    columns
        Panels per row (>= 1).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    InvalidParameterError
        If there are no panels, a panel has no points or ``columns < 1``.
    """
    empty = [name for name, points in panels.items() if not points]
    if not panels or empty:
        raise InvalidParameterError(f"plot_pareto needs at least one panel, each with points; "
                                    f"got {len(panels)} panels, with no points: {empty}")
    integer_at_least("columns", columns)
    plt = pyplot()
    labels = list(dict.fromkeys(p.label for points in panels.values() for p in points))
    colours = plt.get_cmap("tab10")
    markers = "osD^vP*Xhp<>"
    style = {label: (colours(i % 10), markers[i % len(markers)], None)  # colour, marker, face
             for i, label in enumerate(labels)}
    count = len(panels)
    cols = min(columns, count)
    rows = math.ceil(count / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 4.0 * rows), squeeze=False)
    for ax in axes.flat[count:]:
        ax.set_visible(False)
    for ax, (name, points) in zip(axes.flat, panels.items(), strict=False):
        flags = dominated(points)
        missing = []
        for point, flag in zip(points, flags, strict=True):
            if math.isnan(point.time_to_goal):
                missing.append(point.label)
                continue
            low, high = wilson_interval(point.collisions, point.n)
            colour, marker, _ = style[point.label]
            ax.errorbar(point.time_to_goal, point.rate,
                        yerr=[[max(0.0, point.rate - low)], [max(0.0, high - point.rate)]],
                        fmt=marker,
                        color=colour, mfc="white" if flag else colour, capsize=3,
                        label=point.label)
        if missing:
            ax.text(0.02, 0.98, "never reached the goal: " + ", ".join(missing),
                    transform=ax.transAxes, va="top", fontsize=7)
        n = sorted({p.n for p in points})
        ax.set_title(f"{name} ({'/'.join(map(str, n))} episodes per method)", fontsize=10)
        ax.set_xlabel(TIME_LABEL, fontsize=8)
        ax.set_ylabel("collision rate (continuous time), Wilson 95 % CI", fontsize=8)
        # Zoom on the rates that occur (small rates stay readable), never past [0, 1].
        highs = [wilson_interval(p.collisions, p.n)[1] for p in points]
        ax.set_ylim(-0.02, min(1.02, 1.25 * max(highs) + 0.03))
        ax.margins(x=0.12)
        times = [p.time_to_goal for p in points if not math.isnan(p.time_to_goal)]
        if times and max(times) - min(times) < 0.2:  # a few samples apart: widen to 0.2 s
            middle = 0.5 * (max(times) + min(times))
            ax.set_xlim(middle - 0.15, middle + 0.15)
        ax.grid(alpha=0.3)
    style["filled: Pareto-optimal (no other method safer and faster)"] = ("0.3", "o", None)
    style["hollow: dominated"] = ("0.3", "o", "white")
    labels = list(style)
    handles = [plt.Line2D([], [], color=c, marker=m, mfc=f, ls="") for c, m, f in style.values()]
    fig.legend(handles, labels, loc="lower center", ncol=min(4, len(labels)), fontsize=8,
               frameon=False, bbox_to_anchor=(0.5, -0.02 - 0.03 * math.ceil(len(labels) / 4)))
    fig.suptitle(title or "Collision rate against time to goal, per method", fontsize=11)
    fig.tight_layout()
    return save_figure(fig, path)

"""Statistics windows of the paper's Monte Carlo and their summary per scenario and risk.

The window of samples around the encounter on which the paper's box plots and worst
distances are computed (:data:`agents.experiments.paper_settings.PAPER_WINDOWS`, or
:func:`closest_approach_window` of the unfiltered run), the statistics of each
(preset, scenario, risk) on it (:class:`WindowRow`) and ``episodes.csv``.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from agents.evaluation.summary import SummaryRow, wilson_interval
from agents.experiments.paper_settings import PAPER_WINDOWS
from filters.errors import InvalidArrayError, InvalidParameterError

if TYPE_CHECKING:
    from agents.experiments.encounters import EncounterRecord

WINDOW_BEFORE, WINDOW_AFTER = 2, 1
"""Fallback window ``k* - 2 .. k* + 1`` (4 samples, like the authors' windows)."""


# ---------------------------------------------------------------------------- windows
def closest_approach_window(
    distances: np.ndarray, *, before: int = WINDOW_BEFORE, after: int = WINDOW_AFTER,
) -> tuple[int, int]:
    """Window ``(k* - before, k* + after)`` around the median step of closest approach.

    Parameters
    ----------
    distances
        Array (episodes, samples): the distance to collision of the unfiltered
        reference at each sample (minimum over the obstacles), in m; NaN after an
        episode's end.
    before, after
        Samples kept before and after ``k*``, ``>= 0``.

    Returns
    -------
    tuple of int
        ``(first, last)`` sample indices, both included, clipped to the series.
        ``k*`` is the median over the episodes of each episode's argmin (rounded
        down to a sample).

    Raises
    ------
    InvalidArrayError
        If ``distances`` is not 2-D with at least one finite entry per episode.
    InvalidParameterError
        If ``before`` or ``after`` is negative.
    """
    distances = np.asarray(distances, dtype=float)
    if distances.ndim != 2 or distances.size == 0:
        raise InvalidArrayError(
            f"distances must have shape (episodes, samples), got {distances.shape}")
    if not np.all(np.any(np.isfinite(distances), axis=1)):
        raise InvalidArrayError("every episode needs at least one finite distance")
    if before < 0 or after < 0:
        raise InvalidParameterError(f"before and after must be >= 0, got {before}, {after}")
    closest = np.nanargmin(np.where(np.isfinite(distances), distances, np.nan), axis=1)
    k = int(np.floor(np.median(closest)))
    return max(0, k - before), min(distances.shape[1] - 1, k + after)


def window_minimum(distances: np.ndarray, window: tuple[int, int]) -> np.ndarray:
    """Per episode, the minimum of ``distances`` over the samples ``first..last``.

    Parameters
    ----------
    distances
        Array (episodes, samples) in m (NaN where an episode has ended).
    window
        ``(first, last)`` sample indices, both included, ``0 <= first <= last``.

    Returns
    -------
    numpy.ndarray
        Shape (episodes,); NaN for an episode with no finite sample in the window.
    """
    distances = np.asarray(distances, dtype=float)
    if distances.ndim != 2:
        raise InvalidArrayError(
            f"distances must have shape (episodes, samples), got {distances.shape}")
    first, last = (int(w) for w in window)
    if not 0 <= first <= last:
        raise InvalidParameterError(f"window must be (first, last) with 0 <= first <= last, "
                                    f"got {window!r}")
    part = distances[:, first:last + 1]
    low = np.where(np.isfinite(part), part, np.inf).min(axis=1, initial=np.inf)
    return np.where(np.isfinite(low), low, np.nan)


# ---------------------------------------------------------------------------- statistics
def _series(records: Sequence[EncounterRecord], kind: str) -> np.ndarray:
    """(episodes, samples or steps) of the minimum over the obstacles, NaN-padded."""
    rows = [np.min(getattr(r, kind), axis=1) if getattr(r, kind).size else np.zeros(0)
            for r in records]
    width = max((row.size for row in rows), default=0)
    out = np.full((len(rows), width), np.nan)
    for i, row in enumerate(rows):
        out[i, :row.size] = row
    return out


@dataclass(frozen=True)
class WindowRow:
    """Statistics of one (preset, scenario, risk) on its window and on the whole episode.

    Collision counts are episodes with at least one collision. ``window`` are sample
    indices ``(first, last)``, both included (the paper's:
    :data:`~agents.experiments.paper_settings.PAPER_WINDOWS` when the scenario has
    one); the continuous-time window covers the steps between those
    samples. ``encounter_window`` is :func:`closest_approach_window` of the unfiltered
    run, the same statistic centred on this preset's own encounter. Distances in m,
    the filter time in ms.
    """

    preset: str
    scenario: str
    risk: str
    episodes: int
    failed: int
    window: tuple[int, int]
    collisions: int
    sampled_collisions: int
    window_sampled_collisions: int
    window_collisions: int
    window_worst: float
    window_worst_swept: float
    episode_worst: float
    encounter_window: tuple[int, int]
    encounter_sampled_collisions: int
    encounter_worst: float
    fallback_share: float
    fallback_episodes: int
    filter_time_ms: float

    @property
    def ok(self) -> int:
        """Episodes that ran to the end."""
        return self.episodes - self.failed


def resolve_windows(
    records: Sequence[EncounterRecord], *, mode: str = "paper",
) -> dict[str, tuple[tuple[int, int], str]]:
    """The window of every scenario in ``records`` and where it comes from.

    ``mode="paper"``: :data:`~agents.experiments.paper_settings.PAPER_WINDOWS` when the
    scenario has one, else as ``"encounter"``. ``mode="encounter"``:
    :func:`closest_approach_window` of the scenario's unfiltered (``risk="none"``)
    episodes (of all its episodes if none was unfiltered).
    """
    if mode not in ("paper", "encounter"):
        raise InvalidParameterError(f"mode must be 'paper' or 'encounter', got {mode!r}")
    windows = {}
    for scenario in dict.fromkeys(r.scenario for r in records):
        if mode == "paper" and scenario in PAPER_WINDOWS:
            windows[scenario] = (PAPER_WINDOWS[scenario], "authors' script")
            continue
        group = [r for r in records if r.scenario == scenario and not r.error]
        reference = [r for r in group if r.risk == "none"] or group
        windows[scenario] = ((0, 0), "no finished episode") if not reference else (
            closest_approach_window(_series(reference, "distances")),
            "closest approach of the unfiltered run" if reference[0].risk == "none"
            else "closest approach, all risks")
    return windows


def summarise_windows(records: Sequence[EncounterRecord]) -> list[WindowRow]:
    """One :class:`WindowRow` per (preset, scenario, risk), in the records' order."""
    windows = resolve_windows(records)
    encounters = resolve_windows(records, mode="encounter")
    groups: dict[tuple[str, str, str], list[EncounterRecord]] = {}
    for record in records:
        groups.setdefault((record.preset, record.scenario, record.risk), []).append(record)
    rows = []
    for (preset, scenario, risk), group in groups.items():
        ok = [r for r in group if not r.error]
        window, encounter = windows[scenario][0], encounters[scenario][0]
        sampled, swept = _series(ok, "distances"), _series(ok, "swept")
        in_window, in_encounter = (window_minimum(sampled, w) for w in (window, encounter))
        swept_window = window_minimum(swept, (window[0], max(window[0], window[1] - 1)))
        steps = sum(r.steps for r in ok)
        times = np.concatenate([r.filter_times for r in ok]) if ok else np.zeros(0)
        rows.append(WindowRow(
            preset=preset, scenario=scenario, risk=risk, episodes=len(group),
            failed=len(group) - len(ok), window=window,
            collisions=sum(r.collision for r in ok),
            sampled_collisions=sum(r.sampled_collision for r in ok),
            window_sampled_collisions=int(np.sum(in_window <= 0.0)),
            window_collisions=int(np.sum(swept_window <= 0.0)),
            window_worst=_nanmin(in_window), window_worst_swept=_nanmin(swept_window),
            episode_worst=_nanmin(sampled),
            encounter_window=encounter,
            encounter_sampled_collisions=int(np.sum(in_encounter <= 0.0)),
            encounter_worst=_nanmin(in_encounter),
            fallback_share=sum(r.fallback_steps for r in ok) / steps if steps else math.nan,
            fallback_episodes=sum(r.fallback_steps > 0 for r in ok),
            filter_time_ms=1e3 * float(np.median(times)) if times.size else math.nan,
        ))
    return rows


def _nanmin(values: np.ndarray) -> float:
    values = np.asarray(values, dtype=float)
    finite = values[np.isfinite(values)]
    return float(finite.min()) if finite.size else math.nan


def _summary_rows(rows: Sequence[WindowRow], *, sampled: bool) -> list[SummaryRow]:
    """Rows for :func:`agents.evaluation.plots.plot_collision_rates` (whole-episode counts)."""
    out = []
    for row in rows:
        count, n = (row.sampled_collisions if sampled else row.collisions), row.ok
        low, high = wilson_interval(count, n)
        out.append(SummaryRow(
            scenario=row.scenario, planner="mpc", risk=row.risk, episodes=row.episodes,
            failed=row.failed, collision_rate=count / n if n else math.nan,
            collision_low=low, collision_high=high, worst_distance=row.episode_worst,
            cvar_distance=math.nan, goal_rate=math.nan, time_to_goal=math.nan,
            mean_intervention=math.nan, fallback_share=row.fallback_share,
            filter_time_ms=row.filter_time_ms))
    return out


EPISODE_COLUMNS = ("preset", "scenario", "risk", "seed", "steps", "collision",
                   "sampled_collision", "window_first", "window_last", "window_min_distance",
                   "min_distance", "min_swept_distance", "fallback_steps",
                   "first_collision_step", "collision_cause", "wall_time", "error")
"""Columns of ``episodes.csv`` (distances in m: sampled, except ``min_swept_distance``)."""


def write_episodes_csv(records: Sequence[EncounterRecord], path: Path) -> Path:
    """One row per episode, with the window of its scenario."""
    windows = resolve_windows(records)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(EPISODE_COLUMNS)
        for r in records:
            window = windows[r.scenario][0]
            series = _series([r], "distances")
            writer.writerow([
                r.preset, r.scenario, r.risk, r.seed, r.steps, r.collision,
                r.sampled_collision, window[0], window[1],
                f"{window_minimum(series, window)[0]:.6g}", f"{_nanmin(r.distances):.6g}",
                f"{_nanmin(r.swept):.6g}", r.fallback_steps, r.first_collision_step,
                r.collision_cause, f"{r.wall_time:.4f}", r.error])
    return path

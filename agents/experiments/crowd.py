"""The interactive-crowd benchmark: ``safe-nav evaluate --suite crowd``.

CrowdNav's protocol (:mod:`safe_nav_env.crowd.env`): test case ``i`` is the episode of
seed ``seed + i`` of ``SafeNav/Crowd-v0``, the same cases for every setting and method.
Settings are the human model and whether the humans see the robot
(:data:`CROWD_SETTINGS`); methods are the filter's risks (``"none"``: the planner
alone). The episodes run through :func:`agents.evaluation.evaluate.evaluate`, so the
CSV, run key, resume and ``--overwrite`` behave as for ``safe-nav evaluate``.

Metrics, as CrowdNav reports them: success (goal reached), collision (continuous time,
the episode ends), timeout (neither within 25 s), time to goal (mean over the
successes, s) and discomfort frequency (the share of all steps whose clearance to some
human fell below 0.2 m), with Wilson 95 % intervals on the rates.

Output folder::

    episodes.csv, episodes.run.json   one row per episode, the run key
    summary.md                        the table per setting and method
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agents.evaluation.campaign import EvaluationOutputs
from agents.evaluation.config import EvaluationConfig
from agents.evaluation.records import EpisodeRecord
from agents.evaluation.summary import table, wilson_interval
from agents.experiments.scenes import run_scene_suite, scene_groups

__all__ = ["CROWD_SETTINGS", "CrowdRow", "crowd_rows", "crowd_table", "run_crowd"]

CROWD_SETTINGS: dict[str, dict[str, Any]] = {
    "orca_invisible": {"human_policy": "orca", "robot_visible": False},
    "orca_visible": {"human_policy": "orca", "robot_visible": True},
    "social_force_invisible": {"human_policy": "social_force", "robot_visible": False},
    "social_force_visible": {"human_policy": "social_force", "robot_visible": True},
}
"""Human model and robot visibility of each setting (``SafeNav/Crowd-v0`` options).
CrowdNav's main table is ``orca_invisible``."""

CROWD_RISKS = ("none", "mean", "cvar", "dr_cvar")
"""Methods run by default: the planner alone and the paper's three filters."""

CROWD_POLICY = "ppo_crowd.zip"
"""The shipped PPO planner trained on ``SafeNav/Crowd-v0`` (``agents/pretrained/``)."""


@dataclass(frozen=True)
class CrowdRow:
    """CrowdNav's metrics of one (setting, risk) over its test cases.

    Rates are shares of the cases; ``time_to_goal`` (s) is the mean over the successes;
    ``discomfort`` the share of all steps with a clearance below the discomfort
    distance; ``standing_collision`` the share of the cases whose collision came with
    the robot standing still (below 0.1 m/s: a human walked into it); ``*_low``,
    ``*_high`` the Wilson 95 % interval.
    """

    setting: str
    risk: str
    cases: int
    success: float
    success_low: float
    success_high: float
    collision: float
    collision_low: float
    collision_high: float
    standing_collision: float
    timeout: float
    time_to_goal: float
    discomfort: float
    failed: int


def crowd_rows(records: Sequence[EpisodeRecord]) -> list[CrowdRow]:
    """The table's rows, one per (setting, risk), in the order they first appear."""
    rows = []
    for setting, risk, group, ran in scene_groups(records, CROWD_SETTINGS):
        n = max(1, len(ran))
        successes = sum(r.goal_reached and not r.collision for r in ran)
        collisions = sum(r.collision for r in ran)
        times = [r.time_to_goal for r in ran if r.goal_reached and not r.collision]
        steps = sum(r.steps for r in ran)
        rows.append(CrowdRow(
            setting, risk, len(ran), successes / n, *wilson_interval(successes, len(ran)),
            collisions / n, *wilson_interval(collisions, len(ran)),
            standing_collision=sum(r.collision and r.standing_collision for r in ran) / n,
            timeout=(len(ran) - successes - collisions) / n,
            time_to_goal=sum(times) / len(times) if times else math.nan,
            discomfort=sum(r.discomfort_steps for r in ran) / steps if steps else math.nan,
            failed=len(group) - len(ran)))
    return rows


def crowd_table(rows: Sequence[CrowdRow]) -> str:
    """The rows as a Markdown table (CrowdNav's columns, with intervals)."""
    def pct(value: float, low: float | None = None, high: float | None = None) -> str:
        text = f"{100 * value:.1f}%"
        return text if low is None else f"{text} [{100 * low:.1f}, {100 * high:.1f}]"

    columns = ("setting", "method", "cases", "success [95 % CI]", "collision [95 % CI]",
               "of which standing", "timeout", "time to goal (s)", "discomfort frequency")
    return table(columns, ([
        row.setting, row.risk, str(row.cases),
        pct(row.success, row.success_low, row.success_high),
        pct(row.collision, row.collision_low, row.collision_high),
        pct(row.standing_collision), pct(row.timeout),
        "-" if math.isnan(row.time_to_goal) else f"{row.time_to_goal:.2f}",
        "-" if math.isnan(row.discomfort) else f"{row.discomfort:.3f}"] for row in rows))


def run_crowd(output: str | Path | None = None, settings: Sequence[str] = ("orca_invisible",),
              risks: Sequence[str] = CROWD_RISKS, *, config: EvaluationConfig | None = None,
              episodes: int = 500, seed: int = 0, **options: Any) -> EvaluationOutputs:
    """Run the crowd benchmark; write its CSV and summary to ``output``.

    Parameters
    ----------
    output
        Output folder (see the module docstring; default ``results/crowd``); an
        interrupted run resumes from it.
    settings
        Names in :data:`CROWD_SETTINGS`.
    risks
        Filter risks (``"none"``: the planner alone).
    config, options
        As for :func:`agents.evaluation.campaign.run_evaluation`. The PPO planner needs a
        policy trained on ``SafeNav/Crowd-v0`` (its observation has five human slots):
        no ``policy_path`` means the shipped crowd policy.
    episodes
        Test cases per (setting, risk): seeds ``seed .. seed + episodes - 1``.

    Raises
    ------
    InvalidParameterError, PolicyFileError, RunMismatchError, ...
        As :func:`agents.evaluation.campaign.run_campaign`, before any episode runs.
    """
    return run_scene_suite(
        output, "Crowd", CROWD_SETTINGS, settings, risks,
        table=lambda records: crowd_table(crowd_rows(records)),
        title="Interactive crowds (CrowdNav's circle crossing)", shipped_policy=CROWD_POLICY,
        config=config, episodes=episodes, seed=seed, **options)

"""The recorded-pedestrian benchmark: ``safe-nav evaluate --suite pedestrians``.

Every packaged ETH/UCY scene of ``SafeNav/Pedestrians-v0`` (ETH: Pellegrini et al.,
ICCV 2009; UCY: Lerner, Chrysanthou & Lischinski, Eurographics 2007) times every risk,
on the same seeds (episode ``i`` of every cell is seed ``seed + i``: its start time,
start and goal). Pedestrians follow their recordings and do not react to the robot; the
predictions see the past only (:mod:`safe_nav_env.pedestrians`). The episodes run
through :func:`agents.evaluation.evaluate.evaluate`.

Metrics per scene, in the style of ECP-MPC: collision rate (continuous time, Wilson 95
%) and the share of the episodes whose collision came with the ego standing still
(below 0.1 m/s over the colliding step: a pedestrian walked into a robot that was not
moving), success rate (goal reached without collision), time to goal (mean over the
successes, s), infeasible share (steps whose hard QP had no solution: a filter status
other than ``optimal``), miscoverage (the share of first-step halfspaces whose obstacle,
one step later, intruded deeper than the risk bound: realised loss ``> delta``) and the
smallest clearance over the continuous-time path (m; the median over episodes and the
worst).

Output folder::

    episodes.csv, episodes.run.json   one row per episode, the run key
    summary.md                        the table per scene and risk
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation.audit import decode_losses
from agents.evaluation.campaign import EvaluationOutputs
from agents.evaluation.config import EvaluationConfig
from agents.evaluation.records import EpisodeRecord
from agents.evaluation.summary import table, wilson_interval
from agents.experiments.scenes import run_scene_suite, scene_groups
from safe_nav_env.pedestrians.recording import SCENES

__all__ = ["PEDESTRIAN_SETTINGS", "PedestrianRow", "pedestrian_rows", "pedestrian_table",
           "run_pedestrians"]

PEDESTRIAN_SETTINGS: dict[str, dict[str, Any]] = {name: {"scene": name} for name in SCENES}
"""One setting per packaged scene (``SafeNav/Pedestrians-v0``'s ``scene`` option)."""

PEDESTRIAN_RISKS = ("none", "mean", "cvar", "dr_cvar", "conformal")
"""Methods run by default: the planner alone, the paper's filters and a calibrated one."""

PEDESTRIAN_POLICY = "ppo_pedestrians.zip"
"""The shipped PPO planner trained on ``SafeNav/Pedestrians-v0`` (scene ``zara2``; eight
obstacle slots), the suite's PPO planner when no policy is given."""


@dataclass(frozen=True)
class PedestrianRow:
    """The metrics of one (scene, risk); see the module docstring."""

    scene: str
    risk: str
    episodes: int
    collision: float
    collision_low: float
    collision_high: float
    standing_collision: float
    success: float
    time_to_goal: float
    infeasible: float
    miscoverage: float
    median_min_distance: float
    worst_min_distance: float
    failed: int


def pedestrian_rows(records: Sequence[EpisodeRecord]) -> list[PedestrianRow]:
    """The table's rows, one per (scene, risk), in the order they first appear."""
    rows = []
    for scene, risk, group, ran in scene_groups(records, PEDESTRIAN_SETTINGS):
        n = len(ran)
        collisions = sum(r.collision for r in ran)
        low, high = wilson_interval(collisions, n)
        successes = [r for r in ran if r.goal_reached and not r.collision]
        steps = sum(r.steps for r in ran)
        optimal = sum(r.share_optimal * r.steps for r in ran)
        # A step-1 halfspace misses when its obstacle, one step later, intrudes deeper
        # than the risk bound delta it was built for.
        misses = np.concatenate([decode_losses(r.audit_all_losses) > r.delta
                                 for r in ran] or [np.zeros(0, bool)])
        clearances = np.array([r.min_swept_distance for r in ran
                               if math.isfinite(r.min_swept_distance)], dtype=float)
        rows.append(PedestrianRow(
            scene=scene, risk=risk, episodes=n, collision=collisions / max(1, n),
            collision_low=low, collision_high=high,
            standing_collision=sum(r.collision and r.standing_collision for r in ran) / max(1, n),
            success=len(successes) / max(1, n),
            time_to_goal=(float(np.mean([r.time_to_goal for r in successes]))
                          if successes else math.nan),
            infeasible=1.0 - optimal / steps if risk != "none" and steps else math.nan,
            miscoverage=float(np.mean(misses)) if misses.size else math.nan,
            median_min_distance=float(np.median(clearances)) if clearances.size else math.nan,
            worst_min_distance=float(clearances.min()) if clearances.size else math.nan,
            failed=len(group) - n))
    return rows


def _cell(value: float, percent: bool = False) -> str:
    """``value`` as a table cell: a percentage (one decimal) or two decimals; NaN: ``-``."""
    if math.isnan(value):
        return "-"
    return f"{100 * value:.1f}%" if percent else f"{value:.2f}"


def pedestrian_table(rows: Sequence[PedestrianRow]) -> str:
    """The rows as a Markdown table."""
    columns = ("scene", "method", "episodes", "collision [95 % CI]", "of which standing",
               "success", "time to goal (s)", "infeasible steps", "miscoverage",
               "min distance, median / worst (m)")
    return table(columns, ([
        row.scene, row.risk, str(row.episodes),
        f"{_cell(row.collision, percent=True)} [{100 * row.collision_low:.1f}, "
        f"{100 * row.collision_high:.1f}]", _cell(row.standing_collision, percent=True),
        _cell(row.success, percent=True), _cell(row.time_to_goal),
        _cell(row.infeasible, percent=True), _cell(row.miscoverage, percent=True),
        f"{_cell(row.median_min_distance)} / {_cell(row.worst_min_distance)}"] for row in rows))


def run_pedestrians(output: str | Path | None = None,
                    scenes: Sequence[str] = tuple(PEDESTRIAN_SETTINGS),
                    risks: Sequence[str] = PEDESTRIAN_RISKS, *,
                    config: EvaluationConfig | None = None, episodes: int = 100, seed: int = 0,
                    planner: str = "mpc", **options: Any) -> EvaluationOutputs:
    """Run the pedestrian benchmark; write its CSV and summary to ``output``.

    Parameters
    ----------
    output
        Output folder (see the module docstring; default ``results/pedestrians``); an
        interrupted run resumes from it.
    scenes
        Packaged scene names (:data:`PEDESTRIAN_SETTINGS`).
    risks
        Filter risks (``"none"``: the planner alone).
    config, planner, options
        As for :func:`agents.evaluation.campaign.run_evaluation` (the planner is the MPC
        by default). The PPO planner needs a policy whose observation has the
        environment's slots (8 by default): no ``policy_path`` means the shipped one
        (:data:`PEDESTRIAN_POLICY`).
    episodes
        Episodes per (scene, risk).

    Raises
    ------
    InvalidParameterError, PolicyFileError, RunMismatchError, ...
        As :func:`agents.evaluation.campaign.run_campaign`, before any episode runs.
    """
    return run_scene_suite(
        output, "Pedestrians", PEDESTRIAN_SETTINGS, scenes, risks,
        table=lambda records: pedestrian_table(pedestrian_rows(records)),
        title="Recorded pedestrians (ETH: Pellegrini et al., ICCV 2009; UCY: Lerner, "
              "Chrysanthou & Lischinski, Eurographics 2007)",
        shipped_policy=PEDESTRIAN_POLICY, config=config, episodes=episodes, seed=seed,
        planner=planner, **options)

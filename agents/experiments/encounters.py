"""The paper's Monte Carlo episodes: one encounter per (preset, scenario, risk, seed).

An :class:`EncounterJob` runs on the evaluation runner
(:func:`agents.evaluation.runner.run_episode`) with the paper's filter, the preset's
planner and the paper's episode length, and gives an :class:`EncounterRecord`, its
trajectory step by step; :func:`paper_monte_carlo` runs all of them.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from agents.evaluation.records import EpisodeSpec
from agents.evaluation.runner import make_env, run_episode
from agents.evaluation.trajectory import Trajectory
from agents.experiments.paper_settings import (
    PAPER_SCENARIOS,
    PRESETS,
    ReproductionPreset,
    paper_duration,
)
from agents.planners import MPCReferencePlanner
from filters._validation import integer_at_least
from filters.errors import InvalidParameterError
from filters.risk import PAPER_RISKS
from safe_nav_env.scenarios import scenario_name


# ---------------------------------------------------------------------------- episodes
@dataclass(frozen=True)
class EncounterJob:
    """One paper-comparison episode: a preset, a scenario id, a risk and a seed.

    ``render``: the featured run of the figures, with its ``rgb_array`` frames and its
    halfspaces (the Monte Carlo's records keep neither).
    """

    preset: ReproductionPreset
    scenario: str
    risk: str
    seed: int
    render: bool = False


@dataclass(eq=False)
class EncounterRecord(Trajectory):
    """Everything one episode did, step by step: its :class:`Trajectory` and what it ran.

    Attributes
    ----------
    preset, scenario, risk, seed
        The episode (:class:`EncounterJob`).
    error
        Empty, or why the episode stopped early (its partial data are kept).
    wall_time
        Time the episode took, in s.
    collision, sampled_collision, first_collision_step, collision_cause, fallback_steps
        As in :class:`~agents.evaluation.records.EpisodeRecord` (the runner's values).
    """

    preset: str = ""
    scenario: str = ""
    risk: str = ""
    seed: int = 0
    error: str = ""
    wall_time: float = 0.0
    collision: bool = False
    sampled_collision: bool = False
    first_collision_step: int = 0
    collision_cause: str = ""
    fallback_steps: int = 0

    @property
    def ego_velocities(self) -> np.ndarray:
        """(S+1, 2) ego velocities, in m/s."""
        return self.ego_states[:, 2:]

    @property
    def steps(self) -> int:
        return int(self.inputs.shape[0])


class _ZeroInputReference(MPCReferencePlanner):
    """The MPC planner whose reference inputs for the filter are zero, so the wrapper's
    input cost ``(u - u_ref)' R (u - u_ref)`` is the paper's ``u' R u`` (Problem 2)."""

    def __call__(self, env: Any, action: np.ndarray, horizon: int):
        states, inputs = super().__call__(env, action, horizon)
        return states, np.zeros_like(inputs)


def _preset_planner(preset: ReproductionPreset):
    """A function ``env -> planner``: the preset's obstacle-agnostic MPC planner for ``env``,
    the agent and the filter's reference maker (zero reference inputs: Problem 2's ``u' R u``)."""
    Q, Q_terminal, R = preset.planner_weights
    return lambda env: _ZeroInputReference.from_env(
        env, horizon=preset.horizon, Q=Q, Q_terminal=Q_terminal, R=R,
        convention=preset.planner_convention)


def encounter_spec(job: EncounterJob) -> EpisodeSpec:
    """The evaluation pipeline's episode of ``job``: the MPC planner, the paper's filter.

    The paper's filter exactly: Problem 2 with its normals, no inter-sample rows and no
    terminal set (both are this project's additions, see :mod:`filters.intersample`),
    the preset's weights, fallback and input bound, and the paper's episode length.

    Raises
    ------
    InvalidParameterError
        If the scenario has no paper duration
        (:func:`~agents.experiments.paper_settings.paper_duration`), or a setting fails
        the :class:`~agents.evaluation.records.EpisodeSpec`'s checks (e.g. an unknown risk).
    """
    preset = job.preset
    q, q_terminal, r = preset.filter_weights  # times the identity; state 4, input 2
    filter_options = dict(
        horizon=preset.horizon, Q=(q * np.eye(4)).tolist(),
        Q_terminal=(q_terminal * np.eye(4)).tolist(), R=(r * np.eye(2)).tolist(),
        fallback=preset.fallback, objective="trajectory", normals="paper", intersample=False,
        terminal=False)
    env_options = dict(episode_length=paper_duration(job.scenario),
                       max_acceleration=preset.max_acceleration,
                       max_speed=None)  # the paper's ego has no speed limit
    return EpisodeSpec(scenario=scenario_name(job.scenario, warn=False), risk=job.risk,
                       seed=int(job.seed), planner="mpc", alpha=preset.alpha,
                       delta=preset.delta_for(job.risk), epsilon=preset.epsilon,
                       noise=preset.noise, filter_options=filter_options,
                       env_options=env_options)


def make_encounter_env(job: EncounterJob):
    """The filtered environment of ``job`` (paper episode length) and its planner."""
    return make_env(encounter_spec(job), policy=_preset_planner(job.preset),
                    render_mode="rgb_array" if job.render else None)


_FROM_RECORD = ("collision", "sampled_collision", "first_collision_step", "collision_cause",
                "fallback_steps")


def run_encounter(job: EncounterJob) -> EncounterRecord:
    """Run one episode of ``job`` on the evaluation runner; never raises for a failure.

    The episode runs in :func:`agents.evaluation.runner.run_episode` (the runner of
    ``safe-nav evaluate``) with its trajectory recorded; the record keeps its partial
    data if the episode failed.
    """
    start = time.perf_counter()
    try:
        record, trajectory = run_episode(encounter_spec(job), policy=_preset_planner(job.preset),
                                         record_trajectory=True, render=job.render)
        error = record.error if trajectory is None else record.error.split(" | ")[0]
        from_record = {name: getattr(record, name) for name in _FROM_RECORD}
    except Exception as exc:  # noqa: BLE001 — a bad job (e.g. no paper duration) is recorded
        trajectory, error, from_record = None, f"{type(exc).__name__}: {exc}", {}
    if trajectory is None:  # failed before its first state was recorded
        trajectory = Trajectory(
            ego=np.zeros((0, 2)), obstacles=np.zeros((0, 0, 2)), obstacle_radii=np.zeros(0),
            ego_radius=math.nan, goal=np.zeros(2), halfspaces=[], statuses=[], frames=[],
            dt=math.nan)
    elif not job.render:
        trajectory.halfspaces = []
    return EncounterRecord(**vars(trajectory), preset=job.preset.name, scenario=job.scenario,
                           risk=job.risk, seed=int(job.seed), error=error.replace("\n", " ")[:500],
                           wall_time=time.perf_counter() - start, **from_record)


# ---------------------------------------------------------------------------- Monte Carlo
RISKS = ("none", *PAPER_RISKS)
"""Risk settings of the paper's Monte Carlo, plus the unfiltered reference."""


def paper_monte_carlo(
    preset: str | ReproductionPreset = "paper",
    scenarios: Sequence[str] = PAPER_SCENARIOS,
    risks: Sequence[str] = RISKS,
    *,
    episodes: int = 300,
    seed: int = 0,
    workers: int = 1,
    progress: bool = False,
) -> list[EncounterRecord]:
    """The paper's Monte Carlo (Section IV-B) under ``preset``, paper episode lengths.

    Episode ``i`` of every (scenario, risk) uses seed ``seed + i``, so the risks are
    compared on common random numbers. The episodes run on the evaluation pipeline's
    executor (:func:`agents.evaluation.executors.make_executor` with ``workers`` local
    processes, which runs again the episodes of a worker that died), each through
    :func:`run_encounter`; the records come in job order (scenario, risk, seed).

    Raises
    ------
    InvalidParameterError
        For an unknown preset, scenario or risk, ``episodes < 1`` or ``workers < 1``.
    WorkersLostError
        If the worker processes keep dying.
    """
    from tqdm.auto import tqdm

    from agents.evaluation.executors import make_executor

    if isinstance(preset, str):
        if preset not in PRESETS:
            raise InvalidParameterError(f"preset must be one of {sorted(PRESETS)}, got "
                                        f"{preset!r}")
        preset = PRESETS[preset]
    integer_at_least("episodes", episodes)
    jobs = [EncounterJob(preset, scenario, risk, seed + i)
            for scenario in scenarios for risk in risks for i in range(episodes)]
    for job in jobs[::episodes]:  # each (scenario, risk) through the episode's own checks
        encounter_spec(job)
    order = {(job.scenario, job.risk, job.seed): k for k, job in enumerate(jobs)}
    with make_executor("process", workers) as executor:  # results in order of completion
        records = list(tqdm(executor.run(jobs, run_encounter), total=len(jobs),
                            desc="paper episodes", unit="ep", disable=not progress))
    return sorted(records, key=lambda r: order[(r.scenario, r.risk, r.seed)])

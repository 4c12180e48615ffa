"""One episode: build the filtered environment, run the planner through it, record it.

:func:`run_episode` never raises for a failure inside the episode: the record's
``error`` says what went wrong (like ``diffrax``'s ``throw=False``), so a Monte
Carlo run keeps going. :func:`check_policy` and :func:`load_policy` are the checks
an evaluation makes *before* anything runs.
"""

from __future__ import annotations

import dataclasses
import math
import time
import traceback
from collections import Counter, OrderedDict
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from agents.errors import PolicyFileError
from agents.evaluation.audit import encode_losses
from agents.evaluation.policy_files import check_policy, load_policy, policy_file
from agents.evaluation.records import (
    FILTER_STATUSES,
    KEY_FIELDS,
    EpisodeRecord,
    EpisodeSpec,
    package_version,
)
from agents.evaluation.trajectory import Trajectory, TrajectoryRecorder
from filters.errors import InvalidParameterError, InvalidTypeError
from filters.wrapper import FALLBACK_STATUSES, NOMINAL_STATUSES, SafetyFilterWrapper
from safe_nav_env.constants import DT

__all__ = ["EpisodeStats", "Trajectory", "TrajectoryRecorder", "check_policy",
           "clear_env_cache", "collision_cause", "load_policy", "make_env", "policy_file",
           "run_episode", "run_spec"]

FALLBACK_WINDOW = 2
"""A collision is blamed on a fallback if one ran this many steps before it, or at it."""

STANDING_SPEED = 0.1
"""Ego speed (m/s) below which a collision counts as one with the ego standing still
(``standing_collision``): someone walked into a robot that was not moving."""


def collision_cause(collisions: Sequence[bool], sampled_collisions: Sequence[bool],
                    statuses: Sequence[str]) -> str:
    """Why an episode's first continuous-time collision happened.

    Parameters
    ----------
    collisions, sampled_collisions, statuses
        Per step ``t = 1..S``: the continuous-time collision flag over the step, the
        collision flag at its end sample, and the filter's status at the step.

    Returns
    -------
    str
        ``""`` (no collision), ``"fallback"`` (a status that is not nominal, i.e. neither
        "optimal" nor the unfiltered pass-through, at the first colliding step or in the
        :data:`FALLBACK_WINDOW` steps before it),
        ``"inter_sample"`` (the ego overlaps an obstacle only between two samples) or
        ``"noise"`` (after nominal steps, at a sample: the realised motion went beyond
        the risk margin).
    """
    if not any(collisions):
        return ""
    first = list(collisions).index(True)
    window = statuses[max(0, first - FALLBACK_WINDOW):first + 1]
    if any(status not in NOMINAL_STATUSES for status in window):
        return "fallback"
    return "noise" if sampled_collisions[first] else "inter_sample"


# ---------------------------------------------------------------------------- environment
def make_env(spec: EpisodeSpec, *, render_mode: str | None = None, policy: Any = None,
             env_kwargs: dict[str, Any] | None = None) -> tuple[Any, Any]:
    """The filtered (or pass-through) environment of an episode and its planner.

    Parameters
    ----------
    spec
        The episode.
    render_mode
        Passed to ``gym.make``.
    policy
        A planner to use instead of the spec's (``predict(obs, deterministic=True)``),
        or a function ``env -> planner`` called with the new environment.
    env_kwargs
        Further ``gym.make`` keywords that are not recorded (e.g. ``scenario=`` of
        ``"Custom"``); the recorded ones are ``spec.env_options``.

    Raises
    ------
    InvalidParameterError, ScenarioError, ConfigError, PolicyFileError
        If a setting is invalid or the policy does not load.
    """
    import gymnasium as gym

    from safe_nav_env import env_id

    kwargs = {**spec.env_kwargs(), **(env_kwargs or {})}
    try:
        env = gym.make(env_id(spec.scenario), render_mode=render_mode, **kwargs)
    except TypeError as exc:
        if "unexpected keyword argument" in str(exc):
            raise InvalidParameterError(f"env_options: {exc}") from exc
        raise
    try:
        if policy is not None:
            planner = policy if hasattr(policy, "predict") else policy(env)
        elif spec.planner == "mpc":
            from agents.planners import MPCReferencePlanner

            planner = MPCReferencePlanner.from_env(env)
        elif spec.planner == "goal":
            from agents.policies.go_to_goal import GoToGoalPolicy

            planner = GoToGoalPolicy.from_env(env)
        else:
            planner, _ = load_policy(spec.policy_path, sha256=spec.policy_sha256)
        filter_kwargs = spec.filter_kwargs()
        # A PPO policy trained on the normalised view acts in [-1, 1]: it steps through
        # NormalisedActions (outside the filter) and the roll-out reference gets m/s².
        from agents.training.wrappers import NormalisedActions, in_physical_units

        actor = in_physical_units(planner, env.action_space) if spec.planner == "ppo" else planner
        if spec.planner == "mpc":
            filter_kwargs["reference"] = planner
        elif spec.reference == "rollout":
            filter_kwargs["policy"] = actor
        try:
            wrapped = SafetyFilterWrapper(env, **filter_kwargs)
        except InvalidTypeError as exc:  # e.g. an unknown key: a bad value of filter_options
            raise InvalidParameterError(f"filter_options: {exc}") from exc
        if actor is not planner:  # a normalised policy
            wrapped = NormalisedActions(wrapped)
    except BaseException:
        env.close()
        raise
    return wrapped, planner


# ---------------------------------------------------------------------------- reuse
ENV_CACHE_SIZE = 4
"""Filtered environments kept per process for :func:`run_episode` (one per setting)."""

_ENV_CACHE: OrderedDict[EpisodeSpec, tuple[Any, Any]] = OrderedDict()


def _reusable_env(spec: EpisodeSpec, sha: str) -> tuple[EpisodeSpec | None, Any, Any]:
    """The filtered environment and planner of ``spec``'s setting, built once per process.

    Building the environment and the MPC filter (``gym.make``, the QP's matrices, the
    solver workspaces) costs more than a short episode. Episodes that differ only in
    their seed share one environment: ``env.reset(seed=...)`` re-seeds and reloads the
    scenario, and the wrapper's ``reset`` forgets the filter's plan, normals and
    calibration, so the episode is the same as on a fresh environment (the test
    ``test_reused_environment_gives_the_same_records`` checks this record by record).
    ``sha`` is the policy file's SHA-256 now (part of the key: a changed file is
    loaded again, and refused if ``spec.policy_sha256`` says otherwise). Returns the
    cache key (``None`` if the environment is not reusable, see :func:`_resets_fully`),
    the environment and the planner.
    """
    if spec.planner == "ppo":
        load_policy(spec.policy_path, sha256=spec.policy_sha256)  # cached; raises if changed
    key = dataclasses.replace(spec, seed=0, policy_sha256=sha)
    if key in _ENV_CACHE:
        _ENV_CACHE.move_to_end(key)
        return (key, *_ENV_CACHE[key])
    env, planner = make_env(spec)
    if not _resets_fully(env):
        return None, env, planner  # used once and closed, like a fresh environment
    _ENV_CACHE[key] = (env, planner)
    while len(_ENV_CACHE) > ENV_CACHE_SIZE:
        _ENV_CACHE.popitem(last=False)[1][0].close()
    return key, env, planner


def _resets_fully(env: Any) -> bool:
    """Whether ``reset`` forgets everything an episode leaves in ``env``'s wrappers.

    Not so for a filter whose online calibration (``risk="conformal"``,
    ``epsilon="auto"``) carries over between episodes (``calibration_memory=
    "persistent"``): a reused environment would make an episode depend on the ones run
    before it in the process. With ``"episode"`` (the default) ``reset`` restores the
    held-out calibrated state, as a fresh wrapper starts from.
    """
    return not any(getattr(layer, "_calibration", None) is not None
                   and getattr(layer, "calibration_memory", "persistent") != "episode"
                   for layer in _wrappers(env))


def _wrappers(env: Any) -> Iterator[Any]:
    """The wrapper layers of ``env``, outermost first (not the base environment)."""
    while env is not None and env is not getattr(env, "unwrapped", None):
        yield env
        env = getattr(env, "env", None)


def clear_env_cache() -> None:
    """Close and forget the environments :func:`run_episode` keeps for reuse."""
    while _ENV_CACHE:
        _ENV_CACHE.popitem()[1][0].close()


# ---------------------------------------------------------------------------- one episode
def run_episode(
    spec: EpisodeSpec,
    *,
    policy: Any = None,
    record_trajectory: bool = False,
    render: bool = False,
    env_kwargs: dict[str, Any] | None = None,
    reuse_env: bool = True,
) -> tuple[EpisodeRecord, Trajectory | None]:
    """Run one episode and summarise it; never raises for a failure inside the episode.

    With ``reuse_env`` (and no ``policy``, ``env_kwargs`` or ``render``) the filtered
    environment of the spec's setting is built once per process and reset for each
    seed (see :func:`clear_env_cache`); the records are the same as with a fresh one.

    Returns
    -------
    record : EpisodeRecord
        ``error`` is non-empty if the episode failed (its partial statistics are kept).
    trajectory : Trajectory or None
        States, clearances and halfspaces, if ``record_trajectory`` (up to the failure,
        if the episode failed); with ``render`` also the ``rgb_array`` frames
        (halfspaces drawn by the wrapper's render hook).
    """
    start = time.perf_counter()
    stats = EpisodeStats()
    recorder = None
    sha = ""
    cache_key = None
    try:
        if policy is None and spec.planner == "ppo":
            sha = check_policy(spec.policy_path)
        if (reuse_env and policy is None and env_kwargs is None and not render
                and spec.planner in ("ppo", "goal")):  # stateless planners: reuse the env
            cache_key, env, planner = _reusable_env(spec, sha)
        else:
            env, planner = make_env(spec, policy=policy, env_kwargs=env_kwargs,
                                    render_mode="rgb_array" if render else None)
        try:
            obs, info = env.reset(seed=int(spec.seed))
            base = env.unwrapped
            stats.start(base, info, intersample=any(  # the filter adds inter-sample rows
                isinstance(layer, SafetyFilterWrapper) and layer.intersample
                for layer in _wrappers(env)))
            recorder = (TrajectoryRecorder(env, render, info, stats.per_step)
                        if record_trajectory else None)
            done = False
            while not done:
                action, _ = planner.predict(obs, deterministic=True)
                obs, reward, terminated, truncated, info = env.step(action)
                if not np.all(np.isfinite(obs)):
                    raise FloatingPointError(f"non-finite observation at step {stats.steps + 1}")
                stats.step(base, reward, info)
                if recorder is not None:
                    recorder.record(info)
                done = terminated or truncated
        except BaseException:
            _ENV_CACHE.pop(cache_key, None)  # a half-run episode: do not reuse that environment
            raise
        finally:
            if cache_key not in _ENV_CACHE:  # not cached, or dropped after a failure
                env.close()
        error = ""
    except Exception as exc:  # noqa: BLE001 — a Monte Carlo run records failures
        error = f"{type(exc).__name__}: {exc}".replace("\n", " ")[:500]
        if not isinstance(exc, FloatingPointError | InvalidParameterError | PolicyFileError):
            error += " | " + traceback.format_exc(limit=3).replace("\n", " ")[-300:]
    # also after a failure: the partial data are kept
    trajectory = recorder.trajectory() if recorder is not None else None
    record = EpisodeRecord(
        **{**{name: getattr(spec, name) for name in KEY_FIELDS},
           "policy_sha256": spec.policy_sha256 or sha},
        # The policy column: the file that ran (the shipped one resolved), else "".
        policy=("" if spec.planner != "ppo" else f"<{type(policy).__name__} object>"
                if policy is not None else str(policy_file(spec.policy_path))),
        version=package_version(), **stats.summary(),
        wall_time=time.perf_counter() - start, error=error)
    return record, trajectory


def _obstacle_ids(base: Any) -> np.ndarray | None:
    """The environment's obstacle identity per row (``obstacle_ids``), or ``None``."""
    ids = getattr(base, "obstacle_ids", None)
    return None if ids is None else np.array(ids, dtype=np.int64)


def run_spec(spec: EpisodeSpec) -> EpisodeRecord:
    """The record of one episode (what the executors run in their workers)."""
    return run_episode(spec)[0]


class EpisodeStats:
    """Accumulates the per-step quantities of an episode into the record's columns."""

    def __init__(self) -> None:
        self.steps = 0
        self.discomfort_steps = 0
        self.min_distance = math.inf
        self.min_swept_distance = math.inf
        self.goal_time = math.nan
        self.path_length = 0.0
        self.episode_return = 0.0
        self.standing_collision = False
        self.first_error = ""
        self.dt = DT
        self.intersample = False
        self.per_step: list[tuple[bool, bool, str, float, float]] = []
        """(collision, sampled collision, filter status, intervention, filter time) per step."""
        self.audit: list[float] = []
        self.audit_all: list[float] = []
        self._ego = np.zeros(4)
        self._ids: np.ndarray | None = None

    def start(self, base: Any, info: dict[str, Any], *, intersample: bool = False) -> None:
        self.dt = float(base.dt)
        self.intersample = intersample
        self._ego = np.asarray(base.ego_state, dtype=float).copy()
        self._ids = _obstacle_ids(base)
        self._distance(info)

    def _distance(self, info: dict[str, Any]) -> None:
        distances = np.asarray(info.get("distance_to_collision", []), dtype=float)
        self.min_distance = min(self.min_distance, float(distances.min(initial=math.inf)))
        self.min_swept_distance = float(np.fmin(  # fmin: a NaN (not reported) is skipped
            self.min_swept_distance, info.get("min_swept_distance_to_collision", math.nan)))

    def step(self, base: Any, reward: float, info: dict[str, Any]) -> None:
        self.steps += 1
        self.episode_return += float(reward)
        self._distance(info)
        collision = bool(info.get("collision", False))
        ego = np.asarray(base.ego_state, dtype=float).copy()
        # The ego's velocity is linear in time over a step (constant input), so its speed
        # stays below the larger of the two ends: standing throughout when both are.
        if collision and not any(step[0] for step in self.per_step):
            self.standing_collision = max(float(np.linalg.norm(self._ego[2:4])),
                                          float(np.linalg.norm(ego[2:4]))) < STANDING_SPEED
        self.path_length += float(np.linalg.norm(ego[:2] - self._ego[:2]))
        self._ego = ego
        self.discomfort_steps += bool(info.get("discomfort", False))
        if info.get("is_success", False) and math.isnan(self.goal_time):
            self.goal_time = self.steps * self.dt
        report = info["filter"]
        # Before the continuous-time environment, "collision" was the sampled flag.
        self.per_step.append((collision, bool(info.get("sampled_collision", collision)),
                              str(report["status"]), float(report["intervention"]),
                              float(report["filter_time"])))
        reason = str(report["error"]) if "error" in report.keys() else ""
        if reason and not self.first_error:
            self.first_error = f"step {self.steps}: {reason}".replace("\n", " ")[:300]
        ids, self._ids = self._ids, _obstacle_ids(base)
        self._audit(base, report, ids)

    def _audit(self, base: Any, report: Any, ids: np.ndarray | None = None) -> None:
        """The realised losses of the step's active first-step halfspaces.

        See :mod:`agents.evaluation.audit`.

        ``base`` has already stepped: its obstacle positions are the realised ones at the
        step the halfspaces' ``k = 1`` predicted. Steps without halfspaces or a plan
        (pass-through, status ``"error"``) are not audited, nor are steps with
        non-finite data (which the filter reports as ``"error"`` anyway). Where the
        environment names the obstacle in each row (``obstacle_ids``: the slots of
        ``SafeNav/Pedestrians-v0``), ``ids`` are those before the step: a row is audited
        only if it held the same obstacle before and after (not an empty slot, not one
        that passed to another pedestrian).
        """
        normals, offsets, plan = (report[name] if name in report.keys() else None
                                  for name in ("normals", "offsets", "planned_states"))
        if normals is None or offsets is None or plan is None or len(normals) == 0:
            return
        from agents.evaluation.audit import first_step_losses
        from filters.intersample import arc_margin

        h = np.asarray(normals, dtype=float)[:, 0]
        b = np.asarray(offsets, dtype=float)[:, 0]
        realised = np.asarray(base.obstacle_positions, dtype=float)[: len(h)]
        radii = float(base.ego_radius) + np.asarray(base.obstacle_radii, dtype=float)[: len(h)]
        y1 = np.asarray(base.dynamics[2], dtype=float) @ np.asarray(plan, dtype=float)[1]
        if not all(np.all(np.isfinite(x)) for x in (realised, y1, h, b)):
            return
        margins = arc_margin(h, base.input_bounds, float(base.dt)) if self.intersample else 0.0
        active, losses = first_step_losses(h, b, y1, realised, radii, margins=margins)
        if ids is not None and self._ids is not None:
            same = (ids[: len(h)] >= 0) & (ids[: len(h)] == self._ids[: len(h)])
            active, losses = active[same], losses[same]
        self.audit.extend(float(v) for v in losses[active])
        self.audit_all.extend(float(v) for v in losses)

    def summary(self) -> dict[str, Any]:
        """The record's columns that describe what happened (see :class:`EpisodeRecord`)."""
        collisions, sampled, statuses, interventions, times = (
            [list(column) for column in zip(*self.per_step, strict=True)] or [[]] * 5)
        counts = Counter(statuses)
        interventions = np.asarray(interventions or [0.0])
        times = np.asarray(times or [0.0])
        first = collisions.index(True) if any(collisions) else -1  # 0-based
        return dict(
            **{name: getattr(self, name) for name in (
                "steps", "standing_collision", "discomfort_steps", "path_length", "first_error",
                "episode_return")},
            **{name: value if math.isfinite(value := getattr(self, name)) else math.nan
               for name in ("min_distance", "min_swept_distance")},
            collision=first >= 0,
            collision_steps=sum(collisions),
            first_collision_step=first + 1,
            collision_cause=collision_cause(collisions, sampled, statuses),
            first_infeasible_step=next((i + 1 for i, status in enumerate(statuses)
                                        if status in FALLBACK_STATUSES), 0),
            status_before_collision=statuses[first - 1] if 0 < first <= len(statuses) else "",
            status_at_collision=statuses[first] if 0 <= first < len(statuses) else "",
            sampled_collision=any(sampled),
            sampled_collision_steps=sum(sampled),
            goal_reached=not math.isnan(self.goal_time),
            time_to_goal=self.goal_time,
            mean_intervention=float(interventions.mean()),
            max_intervention=float(interventions.max()),
            statuses=";".join(f"{s}:{c}" for s, c in sorted(counts.items())),
            **{f"share_{status}": counts[status] / max(1, self.steps)
               for status in FILTER_STATUSES},
            fallback_steps=int(sum(counts[status] for status in FALLBACK_STATUSES)),
            filter_time_median=float(np.median(times)),
            filter_time_max=float(times.max()),
            audit_steps=len(self.audit),
            audit_losses=encode_losses(self.audit),
            audit_all_steps=len(self.audit_all),
            audit_all_losses=encode_losses(self.audit_all),
        )

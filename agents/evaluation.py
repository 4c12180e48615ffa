"""Monte Carlo evaluation of filtered against unfiltered reference planners.

An *episode* is one scenario, one risk setting, one planner and one seed. Episodes
with the same seed see the same obstacle noise whatever the risk setting (the
environment draws the same random numbers each step whatever the action), so
risk settings are compared on common random numbers.

Every episode returns an :class:`EpisodeRecord`, a flat row of the CSV. A failing
episode (an exception, a NaN) is recorded with ``error`` set instead of stopping
the run, like ``diffrax``'s ``throw=False``.
"""

from __future__ import annotations

import csv
import math
import time
import traceback
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from filters.errors import InvalidParameterError
from filters.wrapper import RISKS

PAPER_SCENARIOS = (
    "SafeNav/HeadOn-v0",
    "SafeNav/Overtaking-v0",
    "SafeNav/Intersection-v0",
    "SafeNav/MultiObstacle-v0",
)
"""The paper's four scenarios."""

PLANNERS = ("ppo", "mpc")
"""Reference planners: the shipped PPO policy, or the paper's obstacle-agnostic MPC."""

REFERENCES = ("rollout", "hold")
"""How the filter makes a reference trajectory from a PPO proposal."""


@dataclass(frozen=True)
class EpisodeSpec:
    """One episode to run.

    Attributes
    ----------
    scenario
        Registered environment id, e.g. ``"SafeNav/HeadOn-v0"``.
    risk
        ``"none"``, ``"mean"``, ``"cvar"`` or ``"dr_cvar"``.
    seed
        Seed of ``env.reset``: the obstacles' noise and any random scenario data.
    planner
        ``"ppo"`` or ``"mpc"``.
    reference
        ``"rollout"`` (roll the policy out on the predicted mean motion) or
        ``"hold"`` (hold the proposed action); the MPC planner always uses its plan.
    alpha, delta, epsilon
        Risk parameters (tail mass, risk bound in m, Wasserstein radius in m).
    policy_path
        PPO policy file; empty for the shipped one.
    noise
        Noise preset of the environment (``safe_nav_env.NOISE_PRESETS``, e.g.
        ``"authors_code"``); empty for the scenario's own (the paper's text).
    """

    scenario: str
    risk: str
    seed: int
    planner: str = "ppo"
    reference: str = "rollout"
    alpha: float = 0.2
    delta: float = 0.1
    epsilon: float = 0.05
    policy_path: str = ""
    noise: str = ""

    def key(self) -> tuple:
        """Identity of the episode in a results file (used to resume)."""
        return (self.scenario, self.risk, int(self.seed), self.planner, self.reference,
                float(self.alpha), float(self.delta), float(self.epsilon), self.noise)


@dataclass(frozen=True)
class EpisodeRecord:
    """One row of the results: what happened in one episode.

    Distances are in m, times in s, interventions in m/s².
    """

    scenario: str
    risk: str
    seed: int
    planner: str
    reference: str
    alpha: float
    delta: float
    epsilon: float
    noise: str = ""
    steps: int = 0
    collision: bool = False
    collision_steps: int = 0
    min_distance: float = math.nan
    goal_reached: bool = False
    time_to_goal: float = math.nan
    path_length: float = 0.0
    mean_intervention: float = 0.0
    max_intervention: float = 0.0
    statuses: str = ""
    fallback_steps: int = 0
    filter_time_median: float = 0.0
    filter_time_max: float = 0.0
    episode_return: float = 0.0
    wall_time: float = 0.0
    error: str = ""

    def key(self) -> tuple:
        return (self.scenario, self.risk, int(self.seed), self.planner, self.reference,
                float(self.alpha), float(self.delta), float(self.epsilon), self.noise)


RECORD_FIELDS = tuple(f.name for f in fields(EpisodeRecord))
"""CSV columns, in order."""


@dataclass
class Trajectory:
    """Positions of one episode, for plots: ego (steps+1, 2), obstacles (steps+1, k, 2)."""

    ego: np.ndarray
    obstacles: np.ndarray
    obstacle_radii: np.ndarray
    ego_radius: float
    goal: np.ndarray
    halfspaces: list[tuple[np.ndarray, np.ndarray]]
    statuses: list[str]
    frames: list[np.ndarray]


# ---------------------------------------------------------------------------- policies
_POLICY_CACHE: dict[tuple[str, str], Any] = {}


def _load_planner(planner: str, policy_path: str, env: Any) -> Any:
    if planner == "mpc":
        from agents.planners import MPCReferencePlanner

        return MPCReferencePlanner.from_env(env)
    key = (planner, policy_path)
    if key not in _POLICY_CACHE:
        from agents.training import load_ppo, set_torch_threads

        set_torch_threads(1)
        _POLICY_CACHE[key] = load_ppo(policy_path or None)
    return _POLICY_CACHE[key]


def make_env(spec: EpisodeSpec, *, render_mode: str | None = None, policy: Any = None,
             env_kwargs: dict[str, Any] | None = None):
    """The filtered (or pass-through) environment of an episode and its planner."""
    import gymnasium as gym

    import safe_nav_env  # noqa: F401
    from filters import SafetyFilterWrapper

    kwargs = dict(env_kwargs or {})
    if spec.noise:
        kwargs.setdefault("noise", spec.noise)
    env = gym.make(spec.scenario, render_mode=render_mode, **kwargs)
    planner = policy if policy is not None else _load_planner(spec.planner, spec.policy_path, env)
    filter_kwargs: dict[str, Any] = dict(risk=spec.risk, alpha=spec.alpha, delta=spec.delta,
                                         epsilon=spec.epsilon)
    # A PPO policy trained on the normalised view acts in [-1, 1]: it steps through
    # NormalisedActions (outside the filter) and the roll-out reference gets m/s².
    from agents.wrappers import NormalisedActions, PhysicalUnitsPolicy, is_normalised_policy

    normalised = spec.planner != "mpc" and is_normalised_policy(planner, env.action_space)
    if spec.planner == "mpc":
        filter_kwargs["reference"] = planner
    elif spec.reference == "rollout":
        filter_kwargs["policy"] = (PhysicalUnitsPolicy(planner, env.action_space)
                                   if normalised else planner)
    filtered = SafetyFilterWrapper(env, **filter_kwargs)
    return (NormalisedActions(filtered) if normalised else filtered), planner


# ---------------------------------------------------------------------------- one episode
def run_episode(
    spec: EpisodeSpec,
    *,
    policy: Any = None,
    record_trajectory: bool = False,
    render: bool = False,
    env_kwargs: dict[str, Any] | None = None,
) -> tuple[EpisodeRecord, Trajectory | None]:
    """Run one episode and summarise it; never raises for a failure inside the episode.

    Returns
    -------
    record : EpisodeRecord
        ``error`` is non-empty if the episode failed (its partial statistics are kept).
    trajectory : Trajectory or None
        Positions and halfspaces, if ``record_trajectory``; with ``render`` also the
        ``rgb_array`` frames (halfspaces drawn by the wrapper's render hook).
    """
    base_fields = dict(scenario=spec.scenario, risk=spec.risk, seed=int(spec.seed),
                       planner=spec.planner, reference=spec.reference, alpha=spec.alpha,
                       delta=spec.delta, epsilon=spec.epsilon, noise=spec.noise)
    start = time.perf_counter()
    stats = _EpisodeStats()
    trajectory = None
    try:
        env, planner = make_env(spec, policy=policy, env_kwargs=env_kwargs,
                                render_mode="rgb_array" if render else None)
        try:
            obs, info = env.reset(seed=int(spec.seed))
            base = env.unwrapped
            stats.start(base, info)
            recorder = _TrajectoryRecorder(env, render) if record_trajectory else None
            done = False
            while not done:
                action, _ = planner.predict(obs, deterministic=True)
                obs, reward, terminated, truncated, info = env.step(action)
                if not np.all(np.isfinite(obs)):
                    raise FloatingPointError(f"non-finite observation at step {stats.steps + 1}")
                stats.step(base, reward, info)
                if recorder is not None:
                    recorder.record(info["filter"])
                done = terminated or truncated
            if recorder is not None:
                trajectory = recorder.trajectory()
        finally:
            env.close()
        error = ""
    except Exception as exc:  # noqa: BLE001 — a Monte Carlo run records failures
        error = f"{type(exc).__name__}: {exc}".replace("\n", " ")[:500]
        if not isinstance(exc, FloatingPointError):
            error += " | " + traceback.format_exc(limit=3).replace("\n", " ")[-300:]
    record = EpisodeRecord(**base_fields, **stats.summary(), wall_time=time.perf_counter() - start,
                           error=error)
    return record, trajectory


class _TrajectoryRecorder:
    """Collects an episode's positions, statuses, halfspaces and (optionally) frames."""

    def __init__(self, env: Any, render: bool) -> None:
        self._env, self._base, self._render = env, env.unwrapped, render
        self._ego: list[np.ndarray] = []
        self._obstacles: list[np.ndarray] = []
        self._statuses: list[str] = []
        self._halfspaces: list[tuple[np.ndarray, np.ndarray]] = []
        self._frames: list[np.ndarray] = []
        self._snapshot()

    def _snapshot(self) -> None:
        self._ego.append(np.asarray(self._base.ego_state[:2], dtype=float).copy())
        self._obstacles.append(np.asarray(self._base.obstacle_positions, dtype=float).copy())
        if self._render:
            self._frames.append(self._env.render())

    def record(self, report: Any) -> None:
        """After a step: the new positions and what the filter did."""
        self._snapshot()
        self._statuses.append(report["status"])
        if report["normals"] is not None:
            self._halfspaces.append((np.asarray(report["normals"]),
                                     np.asarray(report["offsets"])))

    def trajectory(self) -> Trajectory:
        base = self._base
        return Trajectory(
            ego=np.asarray(self._ego), obstacles=np.asarray(self._obstacles),
            obstacle_radii=np.asarray(base.obstacle_radii, dtype=float).copy(),
            ego_radius=float(base.ego_radius), goal=np.asarray(base.goal, dtype=float).copy(),
            halfspaces=self._halfspaces, statuses=self._statuses, frames=self._frames)


class _EpisodeStats:
    """Accumulates the per-step quantities of an episode."""

    def __init__(self) -> None:
        self.steps = 0
        self.collision_steps = 0
        self.min_distance = math.inf
        self.goal_time = math.nan
        self.path_length = 0.0
        self.interventions: list[float] = []
        self.filter_times: list[float] = []
        self.statuses: Counter[str] = Counter()
        self.episode_return = 0.0
        self.dt = 0.2
        self._position = np.zeros(2)

    def start(self, base: Any, info: dict[str, Any]) -> None:
        self.dt = float(base.dt)
        self._position = np.asarray(base.ego_state[:2], dtype=float).copy()
        self._distance(info)

    def _distance(self, info: dict[str, Any]) -> None:
        distances = np.asarray(info.get("distance_to_collision", []), dtype=float)
        if distances.size:
            self.min_distance = min(self.min_distance, float(distances.min()))

    def step(self, base: Any, reward: float, info: dict[str, Any]) -> None:
        self.steps += 1
        self.episode_return += float(reward)
        self._distance(info)
        self.collision_steps += int(bool(info.get("collision", False)))
        position = np.asarray(base.ego_state[:2], dtype=float)
        self.path_length += float(np.linalg.norm(position - self._position))
        self._position = position.copy()
        if info.get("is_success", False) and math.isnan(self.goal_time):
            self.goal_time = self.steps * self.dt
        report = info["filter"]
        self.statuses[report["status"]] += 1
        self.interventions.append(float(report["intervention"]))
        self.filter_times.append(float(report["filter_time"]))

    def summary(self) -> dict[str, Any]:
        fallback = sum(c for s, c in self.statuses.items() if s in ("shifted", "brake"))
        interventions = np.asarray(self.interventions or [0.0])
        times = np.asarray(self.filter_times or [0.0])
        return dict(
            steps=self.steps,
            collision=self.collision_steps > 0,
            collision_steps=self.collision_steps,
            min_distance=self.min_distance if math.isfinite(self.min_distance) else math.nan,
            goal_reached=not math.isnan(self.goal_time),
            time_to_goal=self.goal_time,
            path_length=self.path_length,
            mean_intervention=float(interventions.mean()),
            max_intervention=float(interventions.max()),
            statuses=";".join(f"{s}:{c}" for s, c in sorted(self.statuses.items())),
            fallback_steps=int(fallback),
            filter_time_median=float(np.median(times)),
            filter_time_max=float(times.max()),
            episode_return=self.episode_return,
        )


# ---------------------------------------------------------------------------- many episodes
def episode_specs(
    scenarios: Sequence[str],
    risks: Sequence[str],
    episodes: int,
    seed: int = 0,
    **spec_kwargs: Any,
) -> list[EpisodeSpec]:
    """Every (scenario, risk, episode) combination; episode ``i`` uses seed ``seed + i``."""
    for risk in risks:
        if risk not in RISKS:
            raise InvalidParameterError(f"risk must be one of {RISKS}, got {risk!r}")
    if episodes < 1:
        raise InvalidParameterError(f"episodes must be >= 1, got {episodes!r}")
    planner = spec_kwargs.get("planner", "ppo")
    if planner not in PLANNERS:
        raise InvalidParameterError(f"planner must be one of {PLANNERS}, got {planner!r}")
    reference = spec_kwargs.get("reference", "rollout")
    if reference not in REFERENCES:
        raise InvalidParameterError(f"reference must be one of {REFERENCES}, got {reference!r}")
    noise = spec_kwargs.get("noise", "")
    if noise:
        from safe_nav_env import NOISE_PRESETS

        if noise not in NOISE_PRESETS:
            raise InvalidParameterError(
                f"noise must be '' or one of {sorted(NOISE_PRESETS)}, got {noise!r}")
    return [EpisodeSpec(scenario=s, risk=r, seed=seed + i, **spec_kwargs)
            for s in scenarios for r in risks for i in range(episodes)]


def _run_spec(spec: EpisodeSpec) -> EpisodeRecord:
    return run_episode(spec)[0]


def _worker_init() -> None:
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:  # pragma: no cover - torch is optional for the MPC planner
        pass


def run_specs(
    specs: Sequence[EpisodeSpec],
    *,
    workers: int = 1,
    executor: str = "process",
    on_record: Callable[[EpisodeRecord], None] | None = None,
) -> Iterator[EpisodeRecord]:
    """Run episodes, yielding records as they finish (order of completion).

    ``executor="process"`` spreads them over ``workers`` local processes
    (``workers=1`` runs in this process); ``executor="ray"`` submits them as Ray tasks.
    """
    if workers < 1:
        raise InvalidParameterError(f"workers must be >= 1, got {workers!r}")
    if executor == "ray":
        from agents.ray_executor import run_on_ray

        iterator: Iterable[EpisodeRecord] = run_on_ray(specs)
    elif executor != "process":
        raise InvalidParameterError(f"executor must be 'process' or 'ray', got {executor!r}")
    elif workers == 1:
        iterator = (_run_spec(spec) for spec in specs)
    else:
        iterator = _run_in_pool(specs, workers)
    for record in iterator:
        if on_record is not None:
            on_record(record)
        yield record


def _run_in_pool(specs: Sequence[EpisodeSpec], workers: int) -> Iterator[EpisodeRecord]:
    import multiprocessing

    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=context,
                             initializer=_worker_init) as pool:
        chunk = max(1, min(16, len(specs) // (4 * workers) or 1))
        yield from pool.map(_run_spec, specs, chunksize=chunk)


# ---------------------------------------------------------------------------- CSV
def read_records(path: str | Path) -> list[EpisodeRecord]:
    """Records from a results CSV (written by :class:`RecordWriter`)."""
    types = {f.name: f.type for f in fields(EpisodeRecord)}
    records = []
    with open(path, newline="") as handle:
        for row in csv.DictReader(handle):
            values: dict[str, Any] = {}
            for name in RECORD_FIELDS:
                raw = row.get(name, "")
                kind = types[name]
                if kind in ("int", int):
                    values[name] = int(float(raw)) if raw else 0
                elif kind in ("float", float):
                    values[name] = float(raw) if raw else math.nan
                elif kind in ("bool", bool):
                    values[name] = raw == "True"
                else:
                    values[name] = raw
            records.append(EpisodeRecord(**values))
    return records


class RecordWriter:
    """Appends records to a CSV as they finish, so an interrupted run can resume."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        new = not self.path.exists() or self.path.stat().st_size == 0
        self._handle = open(self.path, "a", newline="")
        self._writer = csv.DictWriter(self._handle, fieldnames=RECORD_FIELDS)
        if new:
            self._writer.writeheader()
            self._handle.flush()

    def __call__(self, record: EpisodeRecord) -> None:
        self._writer.writerow(asdict(record))
        self._handle.flush()

    def close(self) -> None:
        self._handle.close()

    def __enter__(self) -> RecordWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def sort_records(records: Iterable[EpisodeRecord]) -> list[EpisodeRecord]:
    """Records in a canonical order (scenario, risk, seed, ...), independent of completion order."""
    return sorted(records, key=lambda r: tuple(str(k) for k in r.key()[:2]) + r.key()[2:])


# ---------------------------------------------------------------------------- the main job
def evaluate(
    scenarios: Sequence[str] = PAPER_SCENARIOS,
    risks: Sequence[str] = RISKS,
    *,
    episodes: int = 100,
    seed: int = 0,
    workers: int = 1,
    executor: str = "process",
    csv_path: str | Path | None = None,
    progress: bool = True,
    **spec_kwargs: Any,
) -> list[EpisodeRecord]:
    """Run the Monte Carlo comparison of risk settings and return every episode's record.

    Parameters
    ----------
    scenarios
        Environment ids.
    risks
        Risk settings, ``"none"`` being the unfiltered planner.
    episodes
        Episodes per (scenario, risk); episode ``i`` uses seed ``seed + i``.
    workers
        Local worker processes (``executor="process"``).
    executor
        ``"process"`` (default) or ``"ray"``.
    csv_path
        If given, records are appended there as they finish, and episodes already in
        the file are not run again (an interrupted run resumes).
    progress
        Show a progress bar.
    **spec_kwargs
        ``planner``, ``reference``, ``alpha``, ``delta``, ``epsilon``, ``policy_path``,
        ``noise`` (see :class:`EpisodeSpec`).

    Returns
    -------
    list of EpisodeRecord
        Sorted by scenario, risk and seed, whatever the order they finished in, so the
        result does not depend on the number of workers.
    """
    specs = episode_specs(scenarios, risks, episodes, seed, **spec_kwargs)
    done: list[EpisodeRecord] = []
    writer = None
    if csv_path is not None:
        path = Path(csv_path)
        if path.exists() and path.stat().st_size:
            wanted = {spec.key() for spec in specs}
            done = [r for r in read_records(path) if r.key() in wanted]
            finished = {r.key() for r in done}
            specs = [spec for spec in specs if spec.key() not in finished]
        writer = RecordWriter(path)
    records = list(done)
    try:
        iterator = run_specs(specs, workers=workers, executor=executor, on_record=writer)
        if progress and specs:
            from tqdm.auto import tqdm

            iterator = tqdm(iterator, total=len(specs), desc="episodes", unit="ep")
        records.extend(iterator)
    finally:
        if writer is not None:
            writer.close()
    return sort_records(records)

"""``safe-nav reproduce``: the paper's figures and tables, measured here, with a report.

What it produces in ``output``:

* ``figures/example1_halfspaces.png`` — Example 1 / Fig. 2: mean, CVaR and DR-CVaR
  halfspaces (epsilon 0.05, 0.1, 0.2) for 100 Gaussian samples;
* ``figures/halfspace_times.png`` and Table I — Fig. 3: CVXPY setup/solve/call time of
  the CVaR and DR-CVaR halfspace programs against N_s, next to our closed form, in the
  same run, with the paper's numbers alongside;
* the Monte Carlo of Section IV-B, like for like (see below), once per preset:
  ``monte_carlo/`` for the paper's text (:data:`PRESETS` ``"paper"``) and
  ``monte_carlo_authors_code/`` for the authors' code, each with ``episodes.csv``
  (one row per episode) and ``figures/`` (per-step box plots of the window,
  trajectories of the first seed with collisions and radii, collision counts in
  continuous time and sampled, the multi-obstacle safe polytopes, a GIF);
* ``report.md`` — every number above, stating where we match the paper and where not.

**Like for like.** The paper's Monte Carlo differs from ``safe-nav evaluate`` in
three ways, and this module follows the paper in each:

* *Episode length*: the scenarios' ``duration`` (3 s for HeadOn, Overtaking and
  Intersection, 5 s for MultiObstacle, i.e. 15 and 25 steps), passed to the
  environment as ``episode_length``; the environment's defaults (8-10 s) let the
  ego reach the goal, the paper's runs stop after the encounter.
* *Statistics window*: the paper's box plots (Fig. 4) and its worst distances
  (-0.45 m mean, -0.22 m CVaR) come from a few samples around the encounter. The
  authors' script (``multi_exp_sim.py``, ``plot_saved_dist_to_col(start, end)``,
  which slices the distance series ``[start - 1 : end]``) keeps samples 5-8
  (1.0-1.6 s) for HeadOn and Intersection and 2-5 (0.4-1.0 s) for Overtaking,
  sample 0 being the initial state; :data:`PAPER_WINDOWS` holds them. For a
  scenario without such a window (MultiObstacle, whose figure has no box plot, or a
  custom one) :func:`closest_approach_window` takes the 4 samples
  ``k* - 2 .. k* + 1`` around the median step of closest approach ``k*`` of the
  unfiltered reference. The worst distances, the window collision counts and the
  match/differ lines are computed on the window; whole-episode numbers, and the same
  statistic on that *encounter window* (which follows each preset's own encounter:
  the authors' windows fit their planner), are given too.
* *Settings*: :data:`PRESETS` ``"authors_code"`` is the authors' code (its noise,
  its planner weights in its own convention with the unpenalised first input, its
  input bound ``|u| <= 100``, its mean halfspace with δ = 0), next to ``"paper"``,
  the paper's text.

Collisions are given both ways: *continuous time* (the minimum clearance over each
step, ego on its constant-acceleration arc, obstacles on the chord between their
realised positions: ``info["swept_distance_to_collision"]`` of the environment) and
*sampled* (the clearance at the 0.2 s samples, ``info["distance_to_collision"]``),
which is what the paper's numbers count.
"""

from __future__ import annotations

import csv
import math
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation.records import PAPER_SCENARIOS as PAPER_SCENARIO_NAMES
from agents.evaluation.records import EpisodeSpec
from agents.evaluation.summary import SummaryRow, short_name, wilson_interval
from agents.experiments.table_one import EXAMPLE_ONE
from agents.planners import AUTHORS_CODE_PLANNER
from filters.constants import ALPHA, DELTA, EPSILON, HORIZON
from filters.errors import InvalidArrayError, InvalidParameterError
from filters.risk import PAPER_RISKS
from safe_nav_env.constants import DT
from safe_nav_env.scenarios import env_id, scenario_name

PAPER_SCENARIOS = tuple(env_id(name) for name in PAPER_SCENARIO_NAMES)
"""The paper's four scenarios by gym id (reproduce's encounters are keyed by gym id)."""

PAPER_WORST_DISTANCE = {"mean": -0.45, "cvar": -0.22}
"""Section IV-B: worst sampled distance to collision in the box plots (300 runs, the
three single-obstacle scenarios, on :data:`PAPER_WINDOWS`); DR-CVaR: no collision."""

PAPER_FILTER_TIME_MS = 7.0
"""Section IV-B: mean filter call time in the multi-obstacle run (CVXPY + ECOS)."""

PAPER_WINDOWS: dict[str, tuple[int, int]] = {
    "SafeNav/HeadOn-v0": (5, 8),
    "SafeNav/Overtaking-v0": (2, 5),
    "SafeNav/Intersection-v0": (5, 8),
}
"""The samples of the authors' box plots, ``(first, last)`` both included; sample 0 is
the initial state, sample k the state after k steps of 0.2 s. From the authors'
``multi_exp_sim.py``: ``start=6, end=9`` (HeadOn, Intersection) and ``start=3,
end=6`` (Overtaking), sliced as ``[start - 1 : end]``."""

WINDOW_BEFORE, WINDOW_AFTER = 2, 1
"""Fallback window ``k* - 2 .. k* + 1`` (4 samples, like the authors' windows)."""

INFEASIBLE_STATUSES = ("shifted", "brake", "soft", "recovery")
"""Filter statuses of a step whose hard QP failed (:class:`filters.mpc.FilterStatus`)."""

TOLERANCE_M = 0.1
"""A worst distance "matches" the paper's when within 0.1 m of it."""


# ---------------------------------------------------------------------------- presets
def authors_weights(Q: float, Q_terminal: float, R: float) -> tuple[float, float, float]:
    """Effective (``x' Q x``) weights of the authors' ``sum_squares((x - x_ref) Q)`` cost.

    ``sum_squares(e * q) = q² e' e``, so the effective weights are the squares.
    """
    return (float(Q) ** 2, float(Q_terminal) ** 2, float(R) ** 2)


@dataclass(frozen=True)
class ReproductionPreset:
    """Settings of one paper-comparison Monte Carlo.

    Attributes
    ----------
    name, description
        Identifier and one line for the report.
    noise
        Environment noise preset (:data:`safe_nav_env.NOISE_PRESETS`).
    planner_convention, planner_weights
        Convention (:data:`agents.planners.CONVENTIONS`) and ``(Q, Q_T, R)`` of the
        obstacle-agnostic reference planner, read in that convention.
    filter_weights
        ``(Q, Q_T, R)`` of the safety filter, effective (``x' Q x``), times identity.
    max_acceleration
        Input bound per axis of the environment, the planner and the filter, in m/s².
    alpha, delta, epsilon
        Tail mass, risk bound (m) and Wasserstein radius (m).
    mean_delta
        δ of the mean halfspace, in m (``None``: ``delta``).
    horizon
        Planner and filter horizon, in steps.
    filter_input_cost
        ``"absolute"``: the filter's input cost is ``u' R u`` (Problem 2 of the paper, and
        the authors' code); ``"deviation"``: ``(u - u_ref)' R (u - u_ref)`` with the
        planner's inputs (the package's default, a safe plan passes unchanged).
    fallback
        The filter's rule when its QP is infeasible (:data:`filters.mpc.filter.FALLBACKS`):
        ``"paper"`` shifts the last plan (the paper's Remark, the authors' code).
    """

    name: str
    description: str
    noise: str
    planner_convention: str
    planner_weights: tuple[float, float, float]
    filter_weights: tuple[float, float, float]
    max_acceleration: float
    alpha: float = ALPHA
    delta: float = DELTA
    epsilon: float = EPSILON
    mean_delta: float | None = None
    horizon: int = HORIZON
    filter_input_cost: str = "absolute"
    fallback: str = "paper"

    def delta_for(self, risk: str) -> float:
        """δ used with ``risk``, in m."""
        if risk == "mean" and self.mean_delta is not None:
            return float(self.mean_delta)
        return float(self.delta)


PRESETS: dict[str, ReproductionPreset] = {
    "paper": ReproductionPreset(
        name="paper",
        description="the paper's text: 100 samples of N(0, 0.01 I), Laplace reality with the "
                    "same covariance; our planner convention (x'Qx: Q 1, Q_T 3, R 1 on every "
                    "input, arena bound); filter 4 I, 25 I, I with the input cost u'Ru of "
                    "Problem 2 and the paper's fallback (shift the last plan); |u| <= 10 m/s²; "
                    "δ = 0.1 m for every metric",
        noise="paper", planner_convention="quadratic", planner_weights=(1.0, 3.0, 1.0),
        filter_weights=(4.0, 25.0, 1.0), max_acceleration=10.0,
    ),
    "authors_code": ReproductionPreset(
        name="authors_code",
        description="the authors' code: 20 samples of N(0, 0.1 I), Laplace reality of scale "
                    "0.1 m; their planner sum_squares((x-g) Q) with Q 1, Q_T 3, R 1 on "
                    "u_1..u_9 (effective 1, 9, 1; u_0 free; no arena bound); filter "
                    "sum_squares((x-x_ref) Q) + sum_squares(u R) with Q 2, Q_T 5, R 1 "
                    "(effective 4, 25, 1) and the shifted-plan fallback; |u| <= 100 m/s²; the "
                    "mean halfspace with δ = 0",
        noise="authors_code", planner_convention="authors_code",
        planner_weights=(AUTHORS_CODE_PLANNER["Q"], AUTHORS_CODE_PLANNER["Q_terminal"],
                         AUTHORS_CODE_PLANNER["R"]),
        filter_weights=authors_weights(2.0, 5.0, 1.0),
        max_acceleration=AUTHORS_CODE_PLANNER["max_acceleration"], mean_delta=0.0,
        horizon=int(AUTHORS_CODE_PLANNER["horizon"]),
    ),
}
"""The two settings :func:`reproduce` compares with the paper."""


def paper_duration(scenario: str) -> float:
    """The paper's episode length of a registered scenario id (its ``duration``), in s.

    Raises
    ------
    InvalidParameterError
        If ``scenario`` is not a registered id with a fixed scenario.
    """
    from safe_nav_env import ENV_IDS, SCENARIOS, Scenario

    name = ENV_IDS.get(scenario)
    value = SCENARIOS.get(name) if name is not None else None
    if not isinstance(value, Scenario):
        fixed = sorted(k for k, v in ENV_IDS.items() if isinstance(SCENARIOS.get(v), Scenario))
        raise InvalidParameterError(
            f"scenario must be a registered id with a fixed scenario {fixed}, got {scenario!r}")
    return float(value.duration)


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
    out = np.full(distances.shape[0], np.nan)
    finite = np.isfinite(part)
    rows = np.any(finite, axis=1)
    out[rows] = np.min(np.where(finite, part, np.inf)[rows], axis=1)
    return out


# ---------------------------------------------------------------------------- episodes
@dataclass(frozen=True)
class EncounterJob:
    """One paper-comparison episode: a preset, a scenario id, a risk and a seed."""

    preset: ReproductionPreset
    scenario: str
    risk: str
    seed: int
    render: bool = False
    record_halfspaces: bool = False


@dataclass(frozen=True, eq=False)
class EncounterRecord:
    """Everything one episode did, step by step (S steps, n obstacles).

    Attributes
    ----------
    ego_states
        (S+1, 4) ego states ``[p, v]`` at the samples (m, m/s).
    inputs
        (S, 2) applied accelerations, in m/s².
    obstacles
        (S+1, n, 2) realised obstacle positions, in m.
    distances
        (S+1, n) sampled distances to collision, in m (``info["distance_to_collision"]``).
    swept
        (S, n) minimum clearance over each step, in m (continuous time,
        ``info["swept_distance_to_collision"]``).
    statuses, filter_times
        The filter's status and its step time (s) at each step.
    halfspaces, frames
        Per step ``(normals, offsets)`` and rendered frames, if asked for.
    error
        Empty, or why the episode stopped early (its partial data are kept).
    """

    preset: str
    scenario: str
    risk: str
    seed: int
    dt: float
    ego_radius: float
    obstacle_radii: np.ndarray
    goal: np.ndarray
    ego_states: np.ndarray
    inputs: np.ndarray
    obstacles: np.ndarray
    distances: np.ndarray
    swept: np.ndarray
    statuses: tuple[str, ...]
    filter_times: np.ndarray
    halfspaces: list = field(default_factory=list)
    frames: list = field(default_factory=list)
    error: str = ""
    wall_time: float = 0.0

    @property
    def ego(self) -> np.ndarray:
        """(S+1, 2) ego positions, in m."""
        return self.ego_states[:, :2]

    @property
    def ego_velocities(self) -> np.ndarray:
        """(S+1, 2) ego velocities, in m/s."""
        return self.ego_states[:, 2:]

    @property
    def steps(self) -> int:
        return int(self.inputs.shape[0])

    @property
    def collision(self) -> bool:
        """Continuous-time collision in the episode (some step's clearance <= 0)."""
        return bool(self.swept.size and np.min(self.swept) <= 0.0)

    @property
    def sampled_collision(self) -> bool:
        """Collision at a sample instant (the paper's count)."""
        return bool(self.distances.size and np.min(self.distances) <= 0.0)

    @property
    def fallback_steps(self) -> int:
        """Steps where the filter's hard QP failed (:data:`INFEASIBLE_STATUSES`)."""
        return sum(s in INFEASIBLE_STATUSES for s in self.statuses)

    @property
    def step_collisions(self) -> tuple[list[bool], list[bool]]:
        """Per step ``1..S``: the continuous-time and the end-sample collision flags."""
        swept = [bool(np.min(row) <= 0.0) if row.size else False for row in self.swept]
        sampled = [bool(np.min(row) <= 0.0) if row.size else False
                   for row in self.distances[1:]]
        return swept, sampled

    @property
    def first_collision_step(self) -> int:
        """The first step with a continuous-time collision (1-based), 0 if none."""
        swept, _ = self.step_collisions
        return swept.index(True) + 1 if any(swept) else 0

    @property
    def collision_cause(self) -> str:
        """Why the first collision happened: ``""``, ``"fallback"``, ``"inter_sample"`` or
        ``"noise"`` (:func:`agents.evaluation.runner.collision_cause`, the evaluation's rule)."""
        from agents.evaluation.runner import collision_cause

        swept, sampled = self.step_collisions
        return collision_cause(swept, sampled, list(self.statuses))


class _PresetPlanner:
    """The preset's obstacle-agnostic planner: the agent and the filter's reference maker.

    With ``zero_inputs`` the reference inputs are zero, so the wrapper's input cost
    ``(u - u_ref)' R (u - u_ref)`` is the paper's ``u' R u`` (Problem 2).
    """

    def __init__(self, planner: Any, *, zero_inputs: bool) -> None:
        self.planner = planner
        self.zero_inputs = zero_inputs

    def predict(self, observation: np.ndarray, deterministic: bool = True) -> Any:
        return self.planner.predict(observation, deterministic=deterministic)

    def __call__(self, env: Any, action: np.ndarray, horizon: int):
        states, inputs = self.planner(env, action, horizon)
        return (states, np.zeros_like(inputs)) if self.zero_inputs else (states, inputs)


def _preset_planner(preset: ReproductionPreset):
    """A function ``env -> _PresetPlanner`` building the preset's planner for ``env``."""
    from agents.planners import MPCReferencePlanner

    Q, Q_terminal, R = preset.planner_weights

    def build(env: Any) -> _PresetPlanner:
        planner = MPCReferencePlanner.from_env(
            env, horizon=preset.horizon, Q=Q, Q_terminal=Q_terminal, R=R,
            convention=preset.planner_convention)
        return _PresetPlanner(planner, zero_inputs=preset.filter_input_cost != "deviation")

    return build


def encounter_spec(job: EncounterJob) -> EpisodeSpec:
    """The evaluation pipeline's episode of ``job``: the MPC planner, the paper's filter.

    The paper's filter exactly: Problem 2 with its normals, no inter-sample rows and no
    terminal set (both are this project's additions, see :mod:`filters.intersample`),
    the preset's weights, fallback and input bound, and the paper's episode length.

    Raises
    ------
    InvalidParameterError
        If the scenario has no paper duration (:func:`paper_duration`).
    """
    preset = job.preset
    q, q_terminal, r = preset.filter_weights
    states, inputs = 4, 2  # the double integrator's state and input sizes
    filter_options = dict(
        horizon=preset.horizon, Q=(q * np.eye(states)).tolist(),
        Q_terminal=(q_terminal * np.eye(states)).tolist(), R=(r * np.eye(inputs)).tolist(),
        fallback=preset.fallback, objective="trajectory", normals="paper", intersample=False,
        terminal=False)
    env_options = dict(episode_length=paper_duration(job.scenario),
                       max_acceleration=preset.max_acceleration)
    return EpisodeSpec(scenario=scenario_name(job.scenario, warn=False), risk=job.risk,
                       seed=int(job.seed), planner="mpc", alpha=preset.alpha,
                       delta=preset.delta_for(job.risk), epsilon=preset.epsilon,
                       noise=preset.noise, filter_options=filter_options,
                       env_options=env_options)


def make_encounter_env(job: EncounterJob):
    """The filtered environment of ``job`` (paper episode length) and its planner."""
    from agents.evaluation.runner import make_env

    env, adapter = make_env(encounter_spec(job), policy=_preset_planner(job.preset),
                            render_mode="rgb_array" if job.render else None)
    return env, adapter.planner


def run_encounter(job: EncounterJob) -> EncounterRecord:
    """Run one episode of ``job`` on the evaluation runner; never raises for a failure.

    The episode runs in :func:`agents.evaluation.runner.run_episode` (the runner of
    ``safe-nav evaluate``) with its trajectory recorded; the record keeps its partial
    data if the episode failed.
    """
    from agents.evaluation.runner import run_episode

    start = time.perf_counter()
    try:
        spec = encounter_spec(job)
    except Exception as exc:  # noqa: BLE001 — a Monte Carlo run records failures
        return _failed_encounter(job, f"{type(exc).__name__}: {exc}", start)
    record, trajectory = run_episode(spec, policy=_preset_planner(job.preset),
                                     record_trajectory=True, render=job.render,
                                     reuse_env=False)
    if trajectory is None:
        return _failed_encounter(job, record.error, start)
    return EncounterRecord(
        preset=job.preset.name, scenario=job.scenario, risk=job.risk, seed=int(job.seed),
        dt=trajectory.dt, ego_radius=trajectory.ego_radius,
        obstacle_radii=trajectory.obstacle_radii, goal=trajectory.goal,
        ego_states=trajectory.ego_states, inputs=trajectory.inputs,
        obstacles=trajectory.obstacles, distances=trajectory.distances,
        swept=trajectory.swept, statuses=tuple(trajectory.statuses),
        filter_times=trajectory.filter_times,
        halfspaces=trajectory.halfspaces if job.record_halfspaces else [],
        frames=trajectory.frames, error=record.error.split(" | ")[0],
        wall_time=time.perf_counter() - start)


def _failed_encounter(job: EncounterJob, error: str, start: float) -> EncounterRecord:
    """The record of an episode that failed before its first state was recorded."""
    return EncounterRecord(
        preset=job.preset.name, scenario=job.scenario, risk=job.risk, seed=int(job.seed),
        dt=math.nan, ego_radius=math.nan, obstacle_radii=np.zeros(0), goal=np.zeros(2),
        ego_states=np.zeros((0, 4)), inputs=np.zeros((0, 2)), obstacles=np.zeros((0, 0, 2)),
        distances=np.zeros((0, 0)), swept=np.zeros((0, 0)), statuses=(),
        filter_times=np.zeros(0), error=error.replace("\n", " ")[:500],
        wall_time=time.perf_counter() - start)


def _worker_init() -> None:
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")


def run_encounters(
    jobs: Sequence[EncounterJob], *, workers: int = 1, progress: bool = False,
) -> list[EncounterRecord]:
    """Run ``jobs`` (in ``workers`` processes) and return their records in job order."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise InvalidParameterError(f"workers must be an integer >= 1, got {workers!r}")
    iterator: Iterator[EncounterRecord]
    if workers == 1 or len(jobs) <= 1:
        iterator = map(run_encounter, jobs)
        return list(_progress(iterator, len(jobs), progress))
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=context,
                             initializer=_worker_init) as pool:
        chunk = max(1, min(16, len(jobs) // (4 * workers) or 1))
        return list(_progress(pool.map(run_encounter, jobs, chunksize=chunk), len(jobs),
                              progress))


def _progress(iterator: Iterable[EncounterRecord], total: int, show: bool):
    if not show:
        return iterator
    from tqdm.auto import tqdm

    return tqdm(iterator, total=total, desc="paper episodes", unit="ep")


# ---------------------------------------------------------------------------- Example 1, Table I


def example_one(seed: int = 0) -> dict:
    """Example 1: halfspaces of every metric for the paper's setup.

    Returns a dict with the samples, the normal and, per label, the offset ``b``
    and whether the ego reference lies on the safe side.
    """
    from filters import Disc, safe_halfspaces

    rng = np.random.default_rng(seed)
    e = EXAMPLE_ONE
    samples = rng.multivariate_normal(e["obstacle"], e["variance"] * np.eye(2), e["n_samples"])
    reference = np.asarray(e["reference"], dtype=float)[None, :]
    samples4 = samples[None, :, None, :]
    shapes = dict(ego_shape=Disc(e["radius"]), obstacle_shapes=[Disc(e["radius"])])
    cases = [("mean", "mean", 0.0), ("CVaR", "cvar", 0.0)] + [
        (f"DR-CVaR eps={eps:g}", "dr_cvar", eps) for eps in e["epsilons"]]
    result = {"samples": samples, "reference": reference[0], "halfspaces": {}}
    for label, risk, eps in cases:
        hs = safe_halfspaces(reference, samples4, risk=risk, alpha=e["alpha"], delta=e["delta"],
                             epsilon=eps, **shapes)
        normal, offset = hs.normals[0, 0], float(hs.offsets[0, 0])
        result["normal"] = normal
        result["halfspaces"][label] = {
            "offset": offset, "reference_safe": bool(normal @ reference[0] <= offset)}
    return result


def plot_example_one(example: dict, path: Path) -> Path:
    """Fig. 2: the samples, the reference and every halfspace boundary."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from filters.plotting import draw_halfspace

    fig, ax = plt.subplots(figsize=(8, 5))
    ax.set_xlim(-2, 1.5)
    ax.set_ylim(-1.8, 1.2)
    ax.set_aspect("equal")
    samples = example["samples"]
    ax.scatter(samples[:, 0], samples[:, 1], s=4, color="k", alpha=0.5,
               label="predicted obstacle positions (samples)")
    ax.add_patch(plt.Circle(EXAMPLE_ONE["obstacle"], EXAMPLE_ONE["radius"], color="k",
                            alpha=0.2, label=f"obstacle disc, r = {EXAMPLE_ONE['radius']:g} m"))
    ax.add_patch(plt.Circle(example["reference"], EXAMPLE_ONE["radius"], color="tab:blue",
                            alpha=0.3, label=f"ego disc, r = {EXAMPLE_ONE['radius']:g} m"))
    ax.plot(*example["reference"], "bo", label="ego reference position")
    ax.annotate("", xy=example["reference"] + 0.5 * example["normal"],
                xytext=example["reference"], arrowprops=dict(arrowstyle="->"))
    ax.plot([], [], color="k", marker=r"$\rightarrow$", ls="", ms=12,
            label="normal h (ego towards the sample mean)")
    colors = {"mean": "tab:red", "CVaR": "tab:blue"}
    greens = iter(["#66c266", "#2e9e2e", "#145214"])
    for label, data in example["halfspaces"].items():
        draw_halfspace(ax, example["normal"], data["offset"],
                       color=colors.get(label) or next(greens), alpha=0.9, label=label)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0),
              title="boundary h·y = b of each risk\n(safe side: below-left)", title_fontsize=7)
    ax.set_title("Example 1 (Fig. 2): safe halfspaces of mean, CVaR and DR-CVaR\n"
                 f"α = {EXAMPLE_ONE['alpha']:g}, δ = {EXAMPLE_ONE['delta']:g} m, "
                 f"{EXAMPLE_ONE['n_samples']} samples of N(p, {EXAMPLE_ONE['variance']:g} I)",
                 fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_halfspace_times(table: dict, path: Path) -> Path:
    """Fig. 3: CVXPY setup/solve/call and our time per halfspace against N_s (log scale)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    counts = sorted(table["cvxpy"]["dr_cvar"])
    for key, style in (("setup", ":"), ("solve", "--"), ("call", "-")):
        ax.plot(counts, [table["cvxpy"]["dr_cvar"][n][key] for n in counts], style + "o",
                color="tab:green", label=f"DR-CVaR CVXPY {key}")
    ax.plot(counts, [table["cvxpy"]["cvar"][n]["call"] for n in counts], "-s", color="tab:blue",
            label="CVaR CVXPY call")
    ax.plot(counts, [table["ours"][n] for n in counts], "-^", color="k",
            label="ours (closed form), per halfspace")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("number of samples N_s")
    ax.set_ylabel("time (ms)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path




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
    indices ``(first, last)``, both included (the paper's: :data:`PAPER_WINDOWS` when
    the scenario has one); the continuous-time window covers the steps between those
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
    window_source: str
    collisions: int
    sampled_collisions: int
    window_sampled_collisions: int
    window_collisions: int
    window_worst: float
    window_worst_swept: float
    episode_worst: float
    episode_worst_swept: float
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

    ``mode="paper"``: :data:`PAPER_WINDOWS` when the scenario has one, else as
    ``"encounter"``. ``mode="encounter"``: :func:`closest_approach_window` of the
    scenario's unfiltered (``risk="none"``) episodes (of all its episodes if none was
    unfiltered).
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
        source = ("closest approach of the unfiltered run" if reference and
                  reference[0].risk == "none" else "closest approach, all risks")
        if not reference:
            windows[scenario] = ((0, 0), "no finished episode")
            continue
        windows[scenario] = (closest_approach_window(_series(reference, "distances")), source)
    return windows


def closest_approach_sample(records: Sequence[EncounterRecord]) -> int | None:
    """Median sample of closest approach of the finished unfiltered episodes (or None)."""
    reference = [r for r in records if r.risk == "none" and not r.error]
    if not reference:
        return None
    series = _series(reference, "distances")
    return int(np.floor(np.median(np.nanargmin(series, axis=1))))


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
        window, source = windows[scenario]
        sampled, swept = _series(ok, "distances"), _series(ok, "swept")
        first, last = window
        in_window = window_minimum(sampled, window) if ok else np.zeros(0)
        encounter = encounters[scenario][0]
        in_encounter = window_minimum(sampled, encounter) if ok else np.zeros(0)
        swept_window = (window_minimum(swept, (first, max(first, last - 1)))
                        if ok and swept.shape[1] else np.full(len(ok), np.nan))
        steps = sum(r.steps for r in ok)
        times = np.concatenate([r.filter_times for r in ok]) if ok else np.zeros(0)
        rows.append(WindowRow(
            preset=preset, scenario=scenario, risk=risk, episodes=len(group),
            failed=len(group) - len(ok), window=window, window_source=source,
            collisions=sum(r.collision for r in ok),
            sampled_collisions=sum(r.sampled_collision for r in ok),
            window_sampled_collisions=int(np.sum(in_window <= 0.0)),
            window_collisions=int(np.sum(swept_window <= 0.0)),
            window_worst=_nanmin(in_window), window_worst_swept=_nanmin(swept_window),
            episode_worst=_nanmin(sampled), episode_worst_swept=_nanmin(swept),
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
        count = row.sampled_collisions if sampled else row.collisions
        n = row.ok
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
    compared on common random numbers.

    Raises
    ------
    InvalidParameterError
        For an unknown preset, scenario or risk, or ``episodes < 1``.
    """
    from filters.wrapper import RISKS as FILTER_RISKS

    if isinstance(preset, str):
        if preset not in PRESETS:
            raise InvalidParameterError(f"preset must be one of {sorted(PRESETS)}, got "
                                        f"{preset!r}")
        preset = PRESETS[preset]
    for risk in risks:
        if risk not in FILTER_RISKS:
            raise InvalidParameterError(f"risk must be one of {FILTER_RISKS}, got {risk!r}")
    for scenario in scenarios:
        paper_duration(scenario)
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise InvalidParameterError(f"episodes must be an integer >= 1, got {episodes!r}")
    jobs = [EncounterJob(preset, scenario, risk, seed + i)
            for scenario in scenarios for risk in risks for i in range(episodes)]
    return run_encounters(jobs, workers=workers, progress=progress)


def _window_table(rows: Sequence[WindowRow], dt: float) -> list[str]:
    lines = [
        "| scenario | risk | episodes | window (samples) | collisions, continuous time "
        "| collisions, sampled | sampled collisions in window | worst sampled distance in "
        "window (m) | worst continuous-time clearance in window (m) | worst sampled distance, "
        "whole episode (m) | encounter window: sampled collisions, worst sampled distance (m) "
        "| infeasible steps (episodes) | filter time (ms) |",
        "|" + "---|" * 13]
    for r in rows:
        failed = f" ({r.failed} failed)" if r.failed else ""
        first, last = r.window
        e_first, e_last = r.encounter_window
        lines.append(
            f"| {short_name(r.scenario)} | {r.risk} | {r.episodes}{failed} | {first}-{last} "
            f"({first * dt:.1f}-{last * dt:.1f} s) | {r.collisions}/{r.ok} | "
            f"{r.sampled_collisions}/{r.ok} | {r.window_sampled_collisions}/{r.ok} | "
            f"{r.window_worst:.3f} | {r.window_worst_swept:.3f} | {r.episode_worst:.3f} | "
            f"{e_first}-{e_last}: {r.encounter_sampled_collisions}/{r.ok}, "
            f"{r.encounter_worst:.3f} | {r.fallback_share:.1%} ({r.fallback_episodes}) | "
            f"{r.filter_time_ms:.2f} |")
    return lines


def _verdict(ok: bool) -> str:
    return "match" if ok else "differs"


def compare_with_paper(rows: Sequence[WindowRow]) -> list[str]:
    """The match/differ lines, computed on the paper's window (sampled, like the paper)."""
    lines = []
    single = [r for r in rows if r.scenario in PAPER_WINDOWS]
    for risk, paper in PAPER_WORST_DISTANCE.items():
        group = [r for r in single if r.risk == risk and math.isfinite(r.window_worst)]
        if group:
            ours = min(r.window_worst for r in group)
            each = ", ".join(f"{short_name(r.scenario)} {r.window_worst:.3f}" for r in group)
            whole = min(r.episode_worst for r in group)
            encounter = min(r.encounter_worst for r in group)
            verdict = _verdict(abs(ours - paper) <= TOLERANCE_M)
            lines.append(
                f"- Worst sampled distance in the window, {risk} halfspaces: paper about "
                f"{paper} m, here {ours:.3f} m ({each}): {verdict}"
                f" (tolerance {TOLERANCE_M} m). On this preset's encounter window "
                f"{encounter:.3f} m; whole episode {whole:.3f} m.")
    dr = [r for r in single if r.risk == "dr_cvar"]
    if dr:
        n = sum(r.ok for r in dr)
        window = sum(r.window_sampled_collisions for r in dr)
        lines.append(
            f"- DR-CVaR avoids every collision in the three scenarios: paper yes (sampled, in "
            f"the box plots); here {window} of {n} episodes collide at a sample in the window "
            f"({_verdict(window == 0)}); whole episode {sum(r.sampled_collisions for r in dr)} "
            f"sampled, {sum(r.collisions for r in dr)} in continuous time; worst sampled "
            f"distance in the window {min(r.window_worst for r in dr):.3f} m.")
    for scenario in dict.fromkeys(r.scenario for r in rows):
        by_risk = {r.risk: r for r in rows if r.scenario == scenario}
        if all(k in by_risk for k in PAPER_RISKS):
            m, c, d = (by_risk[k] for k in PAPER_RISKS)
            sampled_ok = (m.window_sampled_collisions >= c.window_sampled_collisions
                          >= d.window_sampled_collisions)
            swept_ok = m.collisions >= c.collisions >= d.collisions
            lines.append(
                f"- {short_name(scenario)}: collisions mean >= CVaR >= DR-CVaR, sampled in the "
                f"window {m.window_sampled_collisions} >= {c.window_sampled_collisions} >= "
                f"{d.window_sampled_collisions}: {_verdict(sampled_ok)}; continuous time, "
                f"whole episode {m.collisions} >= {c.collisions} >= {d.collisions}: "
                f"{_verdict(swept_ok)}.")
    multi = [r for r in rows if "MultiObstacle" in r.scenario and r.risk == "dr_cvar"]
    if multi:
        m = multi[0]
        lines.append(f"- Multi-obstacle filter time: paper {PAPER_FILTER_TIME_MS:g} ms mean "
                     f"(CVXPY + ECOS); here median {m.filter_time_ms:.2f} ms per step "
                     "(halfspaces + QP, no CVXPY; the default back end, DAQP at this size).")
        lines.append(f"- Multi-obstacle infeasible steps: paper one step in its one run; here "
                     f"{m.fallback_share:.2%} of the steps, in {m.fallback_episodes} of {m.ok} "
                     "episodes, were infeasible (the paper's fallback).")
    return lines


def _monte_carlo_section(
    preset: ReproductionPreset, records: Sequence[EncounterRecord], folder: Path, *,
    seed: int, episodes: int, wall_time: float, relative: str,
) -> list[str]:
    rows = summarise_windows(records)
    write_episodes_csv(records, folder / "episodes.csv")
    figures = _monte_carlo_figures(preset, records, rows, folder / "figures", seed=seed)
    scenarios = list(dict.fromkeys(r.scenario for r in records))
    dt = next((r.dt for r in records if math.isfinite(r.dt)), DT)
    windows = resolve_windows(records)
    encounters = resolve_windows(records, mode="encounter")
    lines = [f"### Preset `{preset.name}`", "", f"Settings: {preset.description}.", "",
             f"{episodes} runs per scenario and risk, seeds {seed}..{seed + episodes - 1}, "
             f"took {wall_time:.0f} s. Episode lengths (the scenarios' `duration`): "
             + ", ".join(f"{short_name(s)} {paper_duration(s):g} s" for s in scenarios) + ".",
             "", "Statistics windows (sample k is the state after k steps of "
             f"{dt:g} s):"]
    for scenario in scenarios:
        (first, last), source = windows[scenario]
        closest = closest_approach_sample([r for r in records if r.scenario == scenario])
        e_first, e_last = encounters[scenario][0]
        check = (f"; the unfiltered reference is closest to the obstacle at sample {closest} "
                 f"({closest * dt:.1f} s, median over the seeds), encounter window "
                 f"{e_first}-{e_last}" if closest is not None else "")
        lines.append(f"- {short_name(scenario)}: samples {first}-{last} "
                     f"({first * dt:.1f}-{last * dt:.1f} s), {source}{check}.")
    failed = [r for r in records if r.error]
    if failed:
        lines += ["", f"**{len(failed)} of {len(records)} episodes failed** (kept out of the "
                  f"statistics); the first: {short_name(failed[0].scenario)} {failed[0].risk} "
                  f"seed {failed[0].seed}: `{failed[0].error[:200]}`."]
    lines += ["", "Collision counts are episodes with at least one collision: in continuous "
              "time (the environment's swept clearance over each step) and sampled (at the "
              "0.2 s samples, the paper's count).", ""]
    lines += _window_table(rows, dt)
    lines += ["", "Causes of the filtered runs' collisions (continuous time, whole episode; "
              "`collision_cause` in `episodes.csv`: a fallback status at the colliding step "
              "or the two before it, an overlap only between two samples, or realised "
              "noise beyond the margin after nominal steps):", ""]
    lines += _cause_lines(records)
    lines += ["", f"![window box plots]({relative}/figures/distance_boxplots.png)", "",
              f"![collisions, continuous time]({relative}/figures/collision_rates.png)", "",
              f"![collisions, sampled]({relative}/figures/collision_rates_sampled.png)", ""]
    for name in figures:
        if name.startswith("trajectories_") or name in ("safe_polytopes", "animation"):
            lines.append(f"![{name}]({relative}/figures/{figures[name].name})")
    lines += ["", f"#### Against the paper, number by number (preset `{preset.name}`)", ""]
    lines += compare_with_paper(rows)
    lines.append("")
    return lines


def _cause_lines(records: Sequence[EncounterRecord]) -> list[str]:
    """One line per filtered scenario and risk with collisions: the counts per cause."""
    from agents.evaluation.summary import COLLISION_CAUSES

    lines = []
    for scenario in dict.fromkeys(r.scenario for r in records):
        for risk in dict.fromkeys(r.risk for r in records):
            if risk == "none":
                continue
            causes = [r.collision_cause for r in records
                      if r.scenario == scenario and r.risk == risk and not r.error]
            if any(causes):
                counts = ", ".join(f"{name} {causes.count(name)}" for name in COLLISION_CAUSES)
                lines.append(f"- {short_name(scenario)}, {risk}: {counts}")
    return lines or ["- none"]


def _monte_carlo_figures(
    preset: ReproductionPreset, records: Sequence[EncounterRecord], rows: Sequence[WindowRow],
    folder: Path, *, seed: int,
) -> dict[str, Path]:
    from agents.evaluation import plots

    files: dict[str, Path] = {}
    scenarios = list(dict.fromkeys(r.scenario for r in records))
    windows = {s: w for s, (w, _) in resolve_windows(records).items()}
    dt = next((r.dt for r in records if math.isfinite(r.dt)), DT)
    distances = {s: {risk: _series([r for r in records if r.scenario == s and r.risk == risk
                                     and not r.error], "distances")
                     for risk in dict.fromkeys(r.risk for r in records if r.scenario == s)}
                 for s in scenarios}
    files["distance_boxplots"] = plots.plot_window_boxplots(
        distances, windows, folder / "distance_boxplots.png", dt=dt,
        title=f"preset {preset.name}: sampled distance to collision in the statistics window")
    files["collision_rates"] = plots.plot_collision_rates(
        _summary_rows(rows, sampled=False), folder / "collision_rates.png",
        ylabel="collision rate (continuous time)\nshare of episodes",
        title=f"Preset {preset.name}: collision rate in continuous time, per scenario and "
              "risk (Wilson 95 %)")
    files["collision_rates_sampled"] = plots.plot_collision_rates(
        _summary_rows(rows, sampled=True), folder / "collision_rates_sampled.png",
        ylabel="collision rate (at the samples)\nshare of episodes",
        title=f"Preset {preset.name}: collision rate at the 0.2 s samples (the paper's "
              "count), per scenario and risk")
    for scenario in scenarios:
        first_seed = {r.risk: r for r in records
                      if r.scenario == scenario and r.seed == seed and not r.error}
        if first_seed:
            name = short_name(scenario)
            files[f"trajectories_{name}"] = plots.plot_trajectories(
                first_seed, folder / f"trajectories_{name}.png", every=3,
                title=f"{name}, seed {seed}, preset {preset.name}")
    risks = list(dict.fromkeys(r.risk for r in records))
    featured = ("SafeNav/MultiObstacle-v0" if "SafeNav/MultiObstacle-v0" in scenarios
                else scenarios[0], "dr_cvar" if "dr_cvar" in risks else risks[-1])
    if featured[1] != "none":
        record = run_encounter(EncounterJob(preset, featured[0], featured[1], seed, render=True,
                                            record_halfspaces=True))
        if not record.error:
            from agents.evaluation.plots import RISK_LABELS

            name = short_name(featured[0])
            files["safe_polytopes"] = plots.plot_safe_polytopes(
                record, folder / "safe_polytopes.png",
                title=f"{name}: {featured[1]} safe polytopes, seed {seed}")
            label = (f"{RISK_LABELS.get(featured[1], featured[1])} (alpha {preset.alpha:g}, "
                     f"delta {preset.delta_for(featured[1]):g} m, eps {preset.epsilon:g} m), "
                     f"{name}, seed {seed}, preset {preset.name}")
            files["animation"] = plots.save_gif(record.frames, folder / "episode.gif",
                                                label=label)
    return files


# ---------------------------------------------------------------------------- the report
def reproduce(
    output: str | Path = "results/reproduce",
    *,
    episodes: int = 300,
    workers: int = 2,
    seed: int = 0,
    timing_repeats: int = 100,
    sample_counts: tuple[int, ...] = (50, 100, 200, 500, 1000, 1500),
    presets: Sequence[str] = ("paper", "authors_code"),
    scenarios: Sequence[str] = PAPER_SCENARIOS,
    progress: bool = True,
    timing: bool = True,
) -> str:
    """Run every reproduction and write ``report.md``; returns the report text.

    Parameters
    ----------
    output
        Output folder.
    episodes
        Monte Carlo runs per (preset, scenario, risk); the paper has 300.
    workers
        Worker processes of the Monte Carlo.
    seed
        First seed.
    timing_repeats, sample_counts
        Table I / Fig. 3 timing: random sample sets per point and the N_s values.
    presets
        Names in :data:`PRESETS`; the first one's results go to ``monte_carlo/``,
        the others' to ``monte_carlo_<name>/``.
    scenarios
        Registered scenario ids.
    progress
        Show progress bars.
    timing
        Run the Table I timing (``False`` skips it, for quick runs).
    """
    from agents.experiments.table_one import PAPER_TABLE_ONE, halfspace_timing_table

    unknown = [p for p in presets if p not in PRESETS]
    if unknown or not presets:
        raise InvalidParameterError(f"presets must be a non-empty subset of {sorted(PRESETS)}, "
                                    f"got {list(presets)!r}")
    output = Path(output)
    figures = output / "figures"
    lines = ["# Reproduction of Safaoui & Summers (ICRA 2024), measured here", ""]

    example = example_one(seed)
    plot_example_one(example, figures / "example1_halfspaces.png")
    hs = example["halfspaces"]
    lines += ["## Example 1 (Fig. 2)", "", "![Example 1](figures/example1_halfspaces.png)", "",
              "| halfspace | offset b (m) | ego reference safe |", "|---|---|---|"]
    lines += [f"| {k} | {v['offset']:.4f} | {v['reference_safe']} |" for k, v in hs.items()]
    alpha = EXAMPLE_ONE["alpha"]
    gaps = [hs[f"DR-CVaR eps={eps:g}"]["offset"] - hs["CVaR"]["offset"] + eps / alpha
            for eps in EXAMPLE_ONE["epsilons"]]
    paper_claim = all(v["reference_safe"] for k, v in hs.items() if k != "DR-CVaR eps=0.2") and \
        not hs["DR-CVaR eps=0.2"]["reference_safe"]
    lines += ["", f"- b_DR-CVaR = b_CVaR - eps/alpha: largest gap {max(map(abs, gaps)):.2e} m "
              f"({_verdict(max(map(abs, gaps)) < 1e-9)}).",
              f"- Paper: the reference is safe for every halfspace except DR-CVaR at eps = 0.2; "
              f"here: {_verdict(paper_claim)} (seed {seed} samples).", ""]

    if timing:
        table = halfspace_timing_table(sample_counts=sample_counts, repeats=timing_repeats,
                                       seed=seed)
        plot_halfspace_times(table, figures / "halfspace_times.png")
        lines += ["## Halfspace compute time (Fig. 3, Table I)", "",
                  "![times](figures/halfspace_times.png)", "",
                  "Mean times in ms over "
                  f"{timing_repeats} random sample sets; CVXPY + Clarabel here (the vectorised "
                  "formulation of `filters.halfspace_cvxpy`; the per-sample one of the authors' "
                  "code is much slower to compile), CVXPY + ECOS in the paper. Ours: one "
                  "halfspace through `safe_halfspaces`.", "",
                  "| method | N_s | paper solve | paper call | CVXPY solve here | CVXPY call here "
                  "| ours here (closed form) |", "|---|---|---|---|---|---|---|"]
        for (risk, n), (p_solve, p_call) in PAPER_TABLE_ONE.items():
            here = table["cvxpy"][risk].get(n)
            if here is None:
                continue
            lines.append(f"| {risk} | {n} | {p_solve} | {p_call} | {here['solve']:.3f} | "
                         f"{here['call']:.2f} | {table['ours'][n]:.4f} |")
        lines.append("")

    lines += ["## Monte Carlo with the obstacle-agnostic MPC planner (Fig. 4, Fig. 5)", "",
              "Like for like with the paper: its episode lengths, its statistics window (the "
              "samples of the authors' box plots) and two settings, the paper's text and the "
              "authors' code. The paper's numbers are sampled (the clearance at the 0.2 s "
              "samples); collisions in continuous time are given next to them.", "",
              "Windows: the *window* is the authors' (the samples their box-plot script keeps: "
              "5-8 for HeadOn and Intersection, 2-5 for Overtaking; sample 0 is the initial "
              "state); MultiObstacle has no box plot in the paper, so its window is the "
              "encounter window. The *encounter window* is the 4 samples k*-2..k*+1 around the "
              "median sample k* of closest approach of the preset's own unfiltered run: the "
              "authors' windows fit their planner (its unpenalised first input reaches the "
              "obstacle early), so the encounter window shows the same statistic where this "
              "preset's encounter is. The match/differ lines use the window.", ""]
    for k, name in enumerate(presets):
        preset = PRESETS[name]
        folder_name = "monte_carlo" if k == 0 else f"monte_carlo_{name}"
        start = time.perf_counter()
        records = paper_monte_carlo(preset, scenarios, episodes=episodes, seed=seed,
                                    workers=workers, progress=progress)
        lines += _monte_carlo_section(preset, records, output / folder_name, seed=seed,
                                      episodes=episodes, wall_time=time.perf_counter() - start,
                                      relative=folder_name)
    report = "\n".join(lines) + "\n"
    output.mkdir(parents=True, exist_ok=True)
    (output / "report.md").write_text(report)
    return report

"""What an evaluation runs and what it records: :class:`EpisodeSpec`, :class:`EpisodeRecord`.

An *episode* is one scenario, one risk setting, one planner and one seed, with the
filter and environment settings of its :class:`EpisodeSpec`. It produces one
:class:`EpisodeRecord`, a flat row of the results CSV. The record keys
(:data:`KEY_FIELDS`) say which episode a row answers.

This module is the one source of truth for the planners and references, the record
columns and the record keys; the risk names are :data:`filters.wrapper.RISKS`. The CSV
is read and written by :mod:`agents.evaluation.record_csv`, the run key is
:mod:`agents.evaluation.run_keys`; :mod:`agents.evaluation.records` gathers them.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from filters.config import FilterConfig
from filters.constants import ALPHA, DELTA, EPSILON
from filters.errors import InvalidParameterError
from filters.mpc import FilterStatus
from safe_nav_env.scenarios import CUSTOM, scenario_name

__all__ = [
    "AUTO",
    "CYCLED_FIELDS",
    "FILTER_STATUSES",
    "KEY_FIELDS",
    "PLANNERS",
    "RECORD_FIELDS",
    "REFERENCES",
    "TIMING_FIELDS",
    "EpisodeRecord",
    "EpisodeSpec",
    "episode_key",
    "options_json",
]

PLANNERS = ("ppo", "mpc", "goal")
"""Reference planners: the shipped PPO policy, the paper's obstacle-agnostic MPC, or the
obstacle-blind go-to-goal controller (:class:`agents.policies.go_to_goal.GoToGoalPolicy`)."""

REFERENCES = ("rollout", "hold")
"""How the filter makes a reference trajectory from a PPO proposal."""

AUTO = "auto"
"""``epsilon`` value of the wrapper's online Wasserstein radius."""

FILTER_STATUSES = tuple(status.value for status in FilterStatus)
"""Filter statuses (:class:`filters.mpc.FilterStatus`: optimal, soft, recovery, shifted,
brake, error) whose share of the steps is a column ``share_<status>`` of a record."""



def options_json(options: Mapping[str, Any] | str | None, name: str = "options") -> str:
    """Settings as canonical JSON (sorted keys, no spaces): ``""`` for none.

    Numpy arrays and tuples become lists. Used for the option columns of the records
    and in the run key, so two spellings of the same settings compare equal.

    Raises
    ------
    InvalidParameterError
        If a key is not a string or a value is not a finite number, string, bool,
        ``None`` or a (nested) list or string-keyed mapping of them (e.g. the
        ``scenario`` of ``"Custom"``).
    """
    if options is None or options == "":
        return ""
    if isinstance(options, str):
        try:
            options = json.loads(options)
        except json.JSONDecodeError as exc:
            raise InvalidParameterError(f"{name} must be a JSON object, got {options!r}") from exc
    if not isinstance(options, Mapping):
        raise InvalidParameterError(f"{name} must be a mapping of settings, got {options!r}")
    if not options:
        return ""

    def plain(value: Any, path: str) -> Any:
        if isinstance(value, np.ndarray):
            value = value.tolist()
        if isinstance(value, tuple | list):
            return [plain(v, f"{path}[{i}]") for i, v in enumerate(value)]
        if isinstance(value, Mapping) and all(isinstance(key, str) for key in value):
            return {key: plain(v, f"{path}[{key!r}]") for key, v in value.items()}
        if isinstance(value, np.generic):
            value = value.item()
        if value is None or isinstance(value, bool | str):
            return value
        if isinstance(value, int | float):
            if not math.isfinite(value):
                raise InvalidParameterError(f"{path} must be finite, got {value!r}")
            return value
        raise InvalidParameterError(
            f"{path} must be a number, string, bool, None or a list or mapping of them "
            f"(recorded in the CSV), got {value!r}")

    for key in options:
        if not isinstance(key, str):
            raise InvalidParameterError(f"{name} keys must be strings, got {key!r}")
    plain_options = {key: plain(value, f"{name}[{key!r}]") for key, value in options.items()}
    return json.dumps(plain_options, sort_keys=True, separators=(",", ":"))


def _options_dict(text: str) -> dict[str, Any]:
    return json.loads(text) if text else {}


@dataclass(frozen=True)
class EpisodeSpec:
    """One episode to run.

    Attributes
    ----------
    scenario
        Canonical scenario name, e.g. ``"HeadOn"`` (``"head_on"`` and
        ``"SafeNav/HeadOn-v0"`` are accepted with a warning and stored as ``"HeadOn"``).
    risk
        One of :data:`filters.wrapper.RISKS`; ``"none"`` is the unfiltered planner.
    seed
        Seed of ``env.reset``: the obstacles' noise and any random scenario data.
    planner
        ``"ppo"``, ``"mpc"`` or ``"goal"`` (see :data:`PLANNERS`).
    reference
        ``"rollout"`` (roll the policy out on the predicted mean motion) or
        ``"hold"`` (hold the proposed action), for ``"ppo"`` and ``"goal"``; the MPC
        planner always uses its plan.
    alpha, delta, epsilon
        Risk parameters (tail mass, risk bound in m, Wasserstein radius in m);
        ``epsilon`` may be ``"auto"`` (the wrapper's radius estimated online).
    policy_path
        PPO policy file; empty for the shipped one.
    noise
        Noise preset of the environment (``safe_nav_env.NOISE_PRESETS``, e.g.
        ``"authors_code"``); empty for the scenario's own (the paper's text).
    filter_options
        Further keywords of :class:`filters.SafetyFilterWrapper` (``soft``,
        ``horizon``, ``objective``, ...), as a mapping or its JSON; stored as
        canonical JSON (:func:`options_json`).
    env_options
        Further keywords of ``gym.make`` (``n_samples``, ``episode_length``, ...),
        likewise.
    policy_sha256
        SHA-256 of the policy file's content, if known (set by
        :func:`agents.evaluation.evaluate.evaluate`); the runner refuses a file that differs.
    case
        A case of the stress suite (:data:`safe_nav_env.stress.STRESS_SUITE`, e.g.
        ``"heavy_tail"``), or ``""``. With a case the scenario is ``"Custom"`` and the
        environment gets the case's scenario, noise and predictor
        (:meth:`~safe_nav_env.stress.StressCase.env_kwargs`) under ``env_options``.
    """

    scenario: str
    risk: str
    seed: int
    planner: str = "ppo"
    reference: str = "rollout"
    alpha: float = ALPHA
    delta: float = DELTA
    epsilon: float | str = EPSILON
    policy_path: str = ""
    noise: str = ""
    filter_options: str = ""
    env_options: str = ""
    policy_sha256: str = ""
    case: str = ""

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "scenario", scenario_name(self.scenario))
        config = FilterConfig(risk=self.risk, alpha=self.alpha, delta=self.delta,
                              epsilon=self.epsilon)  # the filter's own checks
        if self.planner not in PLANNERS:
            raise InvalidParameterError(f"planner must be one of {PLANNERS}, got {self.planner!r}")
        if self.reference not in REFERENCES:
            raise InvalidParameterError(
                f"reference must be one of {REFERENCES}, got {self.reference!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int | np.integer):
            raise InvalidParameterError(f"seed must be an integer, got {self.seed!r}")
        set_(self, "seed", int(self.seed))
        for name in ("alpha", "delta", "epsilon"):
            set_(self, name, getattr(config, name))
        if self.case:
            from safe_nav_env.stress import STRESS_SUITE

            if self.case not in STRESS_SUITE:
                raise InvalidParameterError(
                    f"case must be '' or one of {sorted(STRESS_SUITE)}, got {self.case!r}")
            if self.noise:
                raise InvalidParameterError(
                    f"a stress case brings its own noise; got noise {self.noise!r} with case "
                    f"{self.case!r}")
            if self.scenario != CUSTOM:
                raise InvalidParameterError(
                    f"a stress case runs on the scenario {CUSTOM!r}, got scenario "
                    f"{self.scenario!r} with case {self.case!r}")
        if self.noise:
            from safe_nav_env import NOISE_PRESETS

            if self.noise not in NOISE_PRESETS:
                raise InvalidParameterError(
                    f"noise must be '' or one of {sorted(NOISE_PRESETS)}, got {self.noise!r}")
        set_(self, "policy_path", str(self.policy_path or ""))
        if self.planner != "ppo" and self.policy_path:  # it would be silently ignored
            raise InvalidParameterError(
                f"planner {self.planner!r} uses no policy file, got policy_path "
                f"{self.policy_path!r} (--policy): drop it, or use planner 'ppo'")
        set_(self, "filter_options", options_json(self.filter_options, "filter_options"))
        clash = sorted({"risk", "alpha", "delta", "epsilon"} & set(_options_dict(
            self.filter_options)))
        if clash:  # filter_kwargs() would silently replace them by the fields
            raise InvalidParameterError(
                f"filter_options must not set {clash} (fields of the episode), got "
                f"filter_options {self.filter_options}")
        set_(self, "env_options", options_json(self.env_options, "env_options"))
        if self.scenario != CUSTOM and "scenario" in _options_dict(self.env_options):
            raise InvalidParameterError(  # gym.make would silently replace the named one
                f"env_options 'scenario' is for the scenario {CUSTOM!r} only, got it with "
                f"scenario {self.scenario!r}")

    def filter_kwargs(self) -> dict[str, Any]:
        """Keywords of :class:`filters.SafetyFilterWrapper` (without the reference planner)."""
        return dict(_options_dict(self.filter_options), risk=self.risk, alpha=self.alpha,
                    delta=self.delta, epsilon=self.epsilon)

    def env_kwargs(self) -> dict[str, Any]:
        """Keywords of ``gym.make`` (the noise preset and the stress case included)."""
        kwargs = _options_dict(self.env_options)
        if self.case:
            from safe_nav_env.stress import STRESS_SUITE

            kwargs = {**STRESS_SUITE[self.case].env_kwargs(), **kwargs}
        if self.noise:
            kwargs.setdefault("noise", self.noise)
        return kwargs

    def key(self) -> tuple:
        """Identity of the episode in a results file (:data:`KEY_FIELDS`)."""
        return episode_key(self)


@dataclass(frozen=True, eq=False)
class EpisodeRecord:
    """One row of the results: what happened in one episode.

    Distances are in m, times in s, interventions in m/s². Collisions are in
    continuous time (``info["collision"]``: the exact clearance over each step);
    the ``sampled_*`` columns count them at the sample instants only, as the paper does.

    Attributes
    ----------
    scenario, risk, seed, planner, reference, alpha, delta, epsilon, noise, case
        The episode's :class:`EpisodeSpec`.
    filter_options, env_options
        Further filter and environment settings, as canonical JSON.
    policy, policy_sha256
        The PPO policy file that ran and the SHA-256 of its content (empty for the MPC).
    version
        Version of the safe-nav package that ran the episode.
    steps
        Environment steps.
    collision, collision_steps, first_collision_step
        Whether, how many steps and at which step (1-based, 0: none) the ego collided
        in continuous time.
    collision_cause
        For a collided episode: ``"fallback"`` if a step within the two steps before
        the first collision (or that step itself) had a filter status other than
        ``"optimal"``/``"passthrough"``; else ``"inter_sample"`` if that first collision
        is between samples only (no sampled collision at that step); else ``"noise"``
        (the obstacles' noise went beyond the filter's margin). Empty otherwise.
    first_infeasible_step
        The first step (1-based) whose hard filter problem had no solution, i.e. whose
        status is a fallback (``soft``, ``recovery``, ``shifted``, ``brake``, ``error``);
        0 if none.
    status_before_collision, status_at_collision
        For a collided episode, the filter status at the step before the first
        collision (empty if the collision is in step 1) and at that step; else empty.
    standing_collision
        Whether the first collision happened with the ego standing still (speed below
        0.1 m/s over the whole step): on recorded data, someone walked into it.
    sampled_collision, sampled_collision_steps
        The same at the sample instants only.
    min_distance, min_swept_distance
        Smallest clearance to any obstacle at the sample instants, and over the
        whole continuous-time path (NaN if the environment does not report it).
    discomfort_steps
        Steps whose sampled clearance to some obstacle was below the environment's
        discomfort distance (``info["discomfort"]``: 0.2 m in ``SafeNav/Crowd-v0``;
        always 0 where the environment does not report it).
    goal_reached, time_to_goal, path_length, episode_return
        Goal reached, when (s), the ego's path length (m) and the summed reward.
    mean_intervention, max_intervention
        :math:`\\|u_{applied} - u_{proposed}\\|` over the steps, in m/s².
    statuses
        Filter status counts, e.g. ``"optimal:38;soft:2"``.
    share_optimal, share_soft, share_recovery, share_shifted, share_brake, share_error
        Share of the steps with each filter status.
    fallback_steps
        Steps with the paper's fallbacks ``"shifted"`` or ``"brake"``.
    first_error
        The first step's reason for braking on bad data (``"step 3: NaN action"``).
    filter_time_median, filter_time_max, wall_time
        Filter step times and the episode's wall time, in s.
    audit_steps, audit_losses
        The guarantee audit (:mod:`agents.evaluation.audit`): the number of active first-step
        halfspaces (obstacle-steps) and their realised losses, in m, as
        ``";"``-separated numbers rounded to 0.1 mm (pooling over episodes needs every
        loss, since a CVaR is not a sum). Empty when no filter ran.
    audit_all_steps, audit_all_losses
        The same over *every* first-step halfspace, active or not.
    error
        Why the episode failed (an exception), else ``""``.
    """

    scenario: str
    risk: str
    seed: int
    planner: str
    reference: str
    alpha: float
    delta: float
    epsilon: float | str
    noise: str = ""
    case: str = ""
    filter_options: str = ""
    env_options: str = ""
    policy: str = ""
    policy_sha256: str = ""
    version: str = ""
    steps: int = 0
    collision: bool = False
    collision_steps: int = 0
    first_collision_step: int = 0
    collision_cause: str = ""
    first_infeasible_step: int = 0
    status_before_collision: str = ""
    status_at_collision: str = ""
    standing_collision: bool = False
    sampled_collision: bool = False
    sampled_collision_steps: int = 0
    min_distance: float = math.nan
    min_swept_distance: float = math.nan
    discomfort_steps: int = 0
    goal_reached: bool = False
    time_to_goal: float = math.nan
    path_length: float = 0.0
    mean_intervention: float = 0.0
    max_intervention: float = 0.0
    statuses: str = ""
    share_optimal: float = 0.0
    share_soft: float = 0.0
    share_recovery: float = 0.0
    share_shifted: float = 0.0
    share_brake: float = 0.0
    share_error: float = 0.0
    fallback_steps: int = 0
    first_error: str = ""
    filter_time_median: float = 0.0
    filter_time_max: float = 0.0
    episode_return: float = 0.0
    audit_steps: int = 0
    audit_losses: str = ""
    audit_all_steps: int = 0
    audit_all_losses: str = ""
    wall_time: float = 0.0
    error: str = ""

    def key(self) -> tuple:
        """Identity of the episode (:data:`KEY_FIELDS`), as for its :class:`EpisodeSpec`."""
        return episode_key(self)

    def __eq__(self, other: object) -> bool:
        """Field by field, NaN equal to NaN (a CSV round trip keeps a record equal)."""
        if not isinstance(other, EpisodeRecord):
            return NotImplemented
        return all(_same(getattr(self, name), getattr(other, name)) for name in RECORD_FIELDS)

    def __hash__(self) -> int:
        return hash(self.key())


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


RECORD_FIELDS = tuple(f.name for f in fields(EpisodeRecord))
"""CSV columns, in order."""

TIMING_FIELDS = ("wall_time", "filter_time_median", "filter_time_max")
"""Columns measured in seconds of this machine's time: the only ones that differ between two
runs of the same seeds and code (on 1 or 2 workers, locally or on Ray)."""

KEY_FIELDS = ("scenario", "risk", "seed", "planner", "reference", "alpha", "delta", "epsilon",
              "noise", "filter_options", "env_options", "policy_sha256", "case")
"""Fields that identify an episode; both :class:`EpisodeSpec` and :class:`EpisodeRecord`
have them, and :func:`episode_key` is the one key function for both."""

CYCLED_FIELDS = ("scenario", "risk", "seed", "case")
"""Key fields that vary within one run by design (the run key covers the others)."""

_KINDS = {f.name: f.type for f in fields(EpisodeRecord)}


def episode_key(item: EpisodeSpec | EpisodeRecord) -> tuple:
    """The tuple of :data:`KEY_FIELDS` of a spec or a record (floats as floats)."""
    return tuple(float(v) if _KINDS[name] in ("float", float) or (name == "epsilon" and v != AUTO)
                 else v for name, v in ((name, getattr(item, name)) for name in KEY_FIELDS))

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
from collections.abc import Mapping, Sequence
from dataclasses import MISSING, dataclass, field, fields
from typing import Any

import numpy as np

from filters._validation import integer_at_least
from filters.config import FilterConfig
from filters.constants import ALPHA, DELTA, EPSILON
from filters.errors import InvalidParameterError
from filters.mpc import FilterStatus
from safe_nav_env import NOISE_PRESETS, STRESS_SUITE
from safe_nav_env.scenarios import CUSTOM, scenario_name

__all__ = ["AUTO", "COLUMN_DOCS", "CYCLED_FIELDS", "FILTER_STATUSES", "KEY_FIELDS", "PLANNERS",
           "RECORD_FIELDS", "REFERENCES", "TIMING_FIELDS", "EpisodeRecord", "EpisodeSpec",
           "episode_key", "options_json"]

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
    if isinstance(options, str) and options:
        try:
            options = json.loads(options)
        except json.JSONDecodeError as exc:
            raise InvalidParameterError(f"{name} must be a JSON object, got {options!r}") from exc
    if options is None or options == "":
        return ""
    if not isinstance(options, Mapping):
        raise InvalidParameterError(f"{name} must be a mapping of settings, got {options!r}")

    def plain(value: Any, path: str) -> Any:
        if isinstance(value, np.ndarray | np.generic):
            value = value.tolist()
        if isinstance(value, tuple | list):
            return [plain(v, f"{path}[{i}]") for i, v in enumerate(value)]
        if isinstance(value, Mapping):
            if bad := [key for key in value if not isinstance(key, str)]:
                raise InvalidParameterError(f"{path} keys must be strings, got {bad[0]!r}")
            return {key: plain(v, f"{path}[{key!r}]") for key, v in value.items()}
        if isinstance(value, float) and not math.isfinite(value):
            raise InvalidParameterError(f"{path} must be finite, got {value!r}")
        if value is None or isinstance(value, bool | str | int | float):
            return value
        raise InvalidParameterError(
            f"{path} must be a number, string, bool, None or a list or mapping of them "
            f"(recorded in the CSV), got {value!r}")

    plain_options = plain(options, name)
    return json.dumps(plain_options, sort_keys=True, separators=(",", ":")) if plain_options else ""


def _options_dict(text: str) -> dict[str, Any]:
    return json.loads(text) if text else {}


def _check_choice(name: str, value: Any, choices: Sequence[str], blank: bool = False) -> None:
    """Raise unless ``value`` is one of ``choices`` (or ``""`` when ``blank``)."""
    if value not in choices and not (blank and value == ""):
        either = "'' or one of" if blank else "one of"
        raise InvalidParameterError(f"{name} must be {either} {choices}, got {value!r}")


def _column(unit: str, meaning: str, default: Any = MISSING) -> Any:
    """A record field and its CSV column's unit and meaning (:data:`COLUMN_DOCS`)."""
    return field(default=default, metadata={"unit": unit, "meaning": meaning})


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
        for name in ("alpha", "delta", "epsilon"):
            set_(self, name, getattr(config, name))
        _check_choice("planner", self.planner, PLANNERS)
        _check_choice("reference", self.reference, REFERENCES)
        set_(self, "seed", integer_at_least("seed", self.seed, low=0))  # as env.reset wants
        _check_choice("case", self.case, sorted(STRESS_SUITE), blank=True)
        if self.case and (self.noise or self.scenario != CUSTOM):
            raise InvalidParameterError(
                f"a stress case runs on the scenario {CUSTOM!r} and brings its own noise, got "
                f"scenario {self.scenario!r} and noise {self.noise!r} with case {self.case!r}")
        _check_choice("noise", self.noise, sorted(NOISE_PRESETS), blank=True)
        set_(self, "policy_path", str(self.policy_path or ""))
        if self.planner != "ppo" and self.policy_path:  # it would be silently ignored
            raise InvalidParameterError(
                f"planner {self.planner!r} uses no policy file, got policy_path "
                f"{self.policy_path!r} (--policy): drop it, or use planner 'ppo'")
        set_(self, "filter_options", options_json(self.filter_options, "filter_options"))
        if clash := sorted({"risk", "alpha", "delta", "epsilon"} & set(_options_dict(
                self.filter_options))):  # filter_kwargs() would silently replace them
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
        kwargs = {**(STRESS_SUITE[self.case].env_kwargs() if self.case else {}),
                  **_options_dict(self.env_options)}
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
    Each field is a CSV column, in order; its unit and meaning are in the field's
    metadata (:data:`COLUMN_DOCS`, the docs' glossary). Further notes:

    collision_cause
        ``"fallback"`` if a step within the two steps before the first collision (or
        that step itself) had a filter status other than ``"optimal"``/``"passthrough"``;
        else ``"inter_sample"`` if that first collision is between samples only; else
        ``"noise"`` (the obstacles' noise went beyond the filter's margin).
    standing_collision
        On recorded data: someone walked into the standing ego.
    audit_steps, audit_losses, audit_all_steps, audit_all_losses
        The guarantee audit (:mod:`agents.evaluation.audit`); pooling over episodes
        needs every loss, since a CVaR is not a sum. Empty when no filter ran.
    """

    scenario: str = _column("", "Canonical scenario name (HeadOn for SafeNav/HeadOn-v0); Custom "
                                "for a stress case")
    risk: str = _column("", "Risk metric of the safe halfspaces; none is the unfiltered planner")
    seed: int = _column("", "Seed of env.reset: the obstacles' noise and any random scenario data")
    planner: str = _column("", "Reference planner: ppo (the policy), mpc (the paper's "
                               "obstacle-agnostic MPC) or goal (the obstacle-blind go-to-goal "
                               "controller)")
    reference: str = _column("", "How a PPO proposal becomes a reference: rollout (the policy "
                                 "rolled out on the predicted mean motion) or hold (the action "
                                 "held)")
    alpha: float = _column("1", "Tail mass α of CVaR and DR-CVaR (α = 1 gives the mean)")
    delta: float = _column("m", "Risk bound δ on the intrusion depth")
    epsilon: float | str = _column("m", "Wasserstein radius ε of DR-CVaR, or auto (estimated "
                                        "online)")
    noise: str = _column("", "Noise preset of the environment (e.g. authors_code); empty for the "
                             "scenario's own", "")
    case: str = _column("", "Stress-suite case (e.g. heavy_tail); empty outside the stress "
                            "suite", "")
    filter_options: str = _column("", "Further SafetyFilterWrapper keywords, as canonical JSON", "")
    env_options: str = _column("", "Further gym.make keywords, as canonical JSON", "")
    policy: str = _column("", "PPO policy file that ran; empty for the shipped one or the MPC "
                              "planner", "")
    policy_sha256: str = _column("", "SHA-256 of the policy file's content", "")
    version: str = _column("", "Version of the safe-nav package that ran the episode", "")
    steps: int = _column("steps", "Environment steps of the episode (0.2 s each by default)", 0)
    collision: bool = _column("bool", "Whether the ego collided, in continuous time (exact "
                                      "clearance over each step)", False)
    collision_steps: int = _column("steps", "Steps with a continuous-time collision", 0)
    first_collision_step: int = _column("step", "First step with a continuous-time collision "
                                                "(1-based; 0: none)", 0)
    collision_cause: str = _column("", "For a collided episode: fallback (a non-optimal filter "
                                       "status at the colliding step or the two before), "
                                       "inter_sample (overlap only between samples) or noise "
                                       "(noise beyond the margin); else empty", "")
    first_infeasible_step: int = _column("step", "First step whose hard filter problem had no "
                                                 "solution (status soft, recovery, shifted, brake "
                                                 "or error; 1-based; 0: none)", 0)
    status_before_collision: str = _column("", "Filter status at the step before the first "
                                               "collision (empty without a collision or if it is "
                                               "in step 1)", "")
    status_at_collision: str = _column("", "Filter status at the first colliding step (empty "
                                           "without a collision)", "")
    standing_collision: bool = _column("bool", "Whether the first collision happened with the ego "
                                               "standing still (speed below 0.1 m/s over the whole "
                                               "step)", False)
    sampled_collision: bool = _column("bool", "Whether the ego collided at the sample instants "
                                              "(the paper's statistic)", False)
    sampled_collision_steps: int = _column("steps", "Steps with a collision at the sample "
                                                    "instants", 0)
    min_distance: float = _column("m", "Smallest clearance to any obstacle at the sample instants "
                                       "(negative: overlap)", math.nan)
    min_swept_distance: float = _column("m", "Smallest clearance over the continuous-time path "
                                             "(negative: overlap; NaN if not reported)", math.nan)
    discomfort_steps: int = _column("steps", "Steps whose sampled clearance to some obstacle was "
                                             "below the environment's discomfort distance (0.2 m "
                                             "in SafeNav/Crowd-v0; 0 where not reported)", 0)
    goal_reached: bool = _column("bool", "Whether the ego reached its goal", False)
    time_to_goal: float = _column("s", "Time at which the goal was reached (NaN if not "
                                       "reached)", math.nan)
    path_length: float = _column("m", "Length of the ego's path", 0.0)
    mean_intervention: float = _column("m/s²", "Mean of ||u_applied - u_proposed|| over the "
                                               "steps", 0.0)
    max_intervention: float = _column("m/s²", "Largest ||u_applied - u_proposed|| over the "
                                              "steps", 0.0)
    statuses: str = _column("", "Filter status counts, e.g. optimal:38;soft:2", "")
    share_optimal: float = _column("1", "Share of the steps whose QP was solved as posed", 0.0)
    share_soft: float = _column("1", "Share of the steps answered by the exact-penalty QP with "
                                     "halfspace slack", 0.0)
    share_recovery: float = _column("1", "Share of the steps answered by the recovery QP with "
                                         "arena slack", 0.0)
    share_shifted: float = _column("1", "Share of the steps that applied the last optimal plan, "
                                        "shifted (the paper's fallback)", 0.0)
    share_brake: float = _column("1", "Share of the steps that braked (last resort)", 0.0)
    share_error: float = _column("1", "Share of the steps that braked on bad data (NaN action or "
                                      "predictions)", 0.0)
    fallback_steps: int = _column("steps", "Steps on a fallback (status soft, recovery, "
                                           "shifted, brake or error)", 0)
    first_error: str = _column("", "The first step's reason for braking on bad data, e.g. step 3: "
                                   "NaN action", "")
    filter_time_median: float = _column("s", "Median time of one filter step (halfspaces + "
                                             "QP)", 0.0)
    filter_time_max: float = _column("s", "Largest time of one filter step", 0.0)
    episode_return: float = _column("1", "Sum of the environment's rewards over the episode", 0.0)
    audit_steps: int = _column("count", "Active first-step halfspaces (obstacle-steps) in the "
                                        "guarantee audit", 0)
    audit_losses: str = _column("m", "Their realised losses, ';'-separated, rounded to 0.1 mm", "")
    audit_all_steps: int = _column("count", "Every first-step halfspace in the audit, active or "
                                            "not", 0)
    audit_all_losses: str = _column("m", "Their realised losses, ';'-separated, rounded to 0.1 "
                                         "mm", "")
    wall_time: float = _column("s", "Wall-clock time of the episode", 0.0)
    error: str = _column("", "Why the episode failed (an exception); empty if it ran", "")

    def key(self) -> tuple:
        """Identity of the episode (:data:`KEY_FIELDS`), as for its :class:`EpisodeSpec`."""
        return episode_key(self)

    def __eq__(self, other: object) -> bool:
        """Field by field, NaN equal to NaN (a CSV round trip keeps a record equal)."""
        if not isinstance(other, EpisodeRecord):
            return NotImplemented
        pairs = ((getattr(self, name), getattr(other, name)) for name in RECORD_FIELDS)
        return all(a == b or (a != a and b != b) for a, b in pairs)  # x != x: x is NaN

    def __hash__(self) -> int:
        return hash(self.key())


RECORD_FIELDS = tuple(f.name for f in fields(EpisodeRecord))
"""CSV columns, in order."""

COLUMN_DOCS: dict[str, tuple[str, str]] = {
    f.name: (f.metadata["unit"], f.metadata["meaning"]) for f in fields(EpisodeRecord)}
"""Unit and meaning of every CSV column (:data:`RECORD_FIELDS`), for the docs' glossary.
Units: ``""`` for labels and text, ``"1"`` for dimensionless numbers and shares."""

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

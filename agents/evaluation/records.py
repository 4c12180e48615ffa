"""What an evaluation runs and what it records: episode specs, records, CSV, run keys.

An *episode* is one scenario, one risk setting, one planner and one seed, with the
filter and environment settings of its :class:`EpisodeSpec`. It produces one
:class:`EpisodeRecord`, a flat row of the results CSV. The record keys
(:data:`KEY_FIELDS`) say which episode a row answers; the *run key* (:func:`run_key`,
stored next to the CSV) covers every setting shared by the rows of a run -- planner,
policy file (by the SHA-256 of its content), filter and environment settings, noise
and the package version -- so that a resumed run never reuses the rows of another.

This module is the one source of truth for the scenario list of the paper, the
planners and references, the record columns and the record keys; the risk names are
:data:`filters.wrapper.RISKS` and the scenario names :data:`safe_nav_env.SCENARIO_NAMES`.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from agents.errors import RecordsFileError, RunMismatchError
from filters.constants import ALPHA, DELTA, EPSILON
from filters.errors import InvalidParameterError
from filters.mpc import FilterStatus
from filters.wrapper import RISKS, calibration_settings
from safe_nav_env.constants import PAPER_SCENARIOS
from safe_nav_env.scenarios import CUSTOM, SCENARIO_NAMES, scenario_name

__all__ = [
    "FILTER_STATUSES",
    "KEY_FIELDS",
    "PAPER_SCENARIOS",
    "PLANNERS",
    "RECORD_FIELDS",
    "REFERENCES",
    "RISKS",
    "SCENARIO_NAMES",
    "TIMING_FIELDS",
    "EpisodeRecord",
    "EpisodeSpec",
    "RecordWriter",
    "episode_key",
    "file_sha256",
    "options_json",
    "package_version",
    "read_records",
    "run_key",
    "sort_records",
    "write_records",
]

PLANNERS = ("ppo", "mpc")
"""Reference planners: the shipped PPO policy, or the paper's obstacle-agnostic MPC."""

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
        ``"ppo"`` or ``"mpc"``.
    reference
        ``"rollout"`` (roll the policy out on the predicted mean motion) or
        ``"hold"`` (hold the proposed action); the MPC planner always uses its plan.
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
        if self.risk not in RISKS:
            raise InvalidParameterError(f"risk must be one of {RISKS}, got {self.risk!r}")
        if self.planner not in PLANNERS:
            raise InvalidParameterError(f"planner must be one of {PLANNERS}, got {self.planner!r}")
        if self.reference not in REFERENCES:
            raise InvalidParameterError(
                f"reference must be one of {REFERENCES}, got {self.reference!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int | np.integer):
            raise InvalidParameterError(f"seed must be an integer, got {self.seed!r}")
        set_(self, "seed", int(self.seed))
        for name in ("alpha", "delta", "epsilon"):
            value = getattr(self, name)
            if name == "epsilon" and value == AUTO:
                continue
            if isinstance(value, bool) or not isinstance(value, int | float | np.number):
                extra = ' or "auto"' if name == "epsilon" else ""
                raise InvalidParameterError(f"{name} must be a number{extra}, got {value!r}")
            set_(self, name, float(value))
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
        if self.planner == "mpc" and self.policy_path:  # it would be silently ignored
            raise InvalidParameterError(
                f"planner 'mpc' (the obstacle-agnostic MPC) uses no policy file, got policy_path "
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


COLUMN_DOCS: dict[str, tuple[str, str]] = {
    "scenario": ("", "Canonical scenario name (HeadOn for SafeNav/HeadOn-v0); Custom for a "
                     "stress case"),
    "risk": ("", "Risk metric of the safe halfspaces; none is the unfiltered planner"),
    "seed": ("", "Seed of env.reset: the obstacles' noise and any random scenario data"),
    "planner": ("", "Reference planner: ppo (the policy) or mpc (the paper's obstacle-agnostic "
                    "MPC)"),
    "reference": ("", "How a PPO proposal becomes a reference: rollout (the policy rolled out "
                      "on the predicted mean motion) or hold (the action held)"),
    "alpha": ("1", "Tail mass α of CVaR and DR-CVaR (α = 1 gives the mean)"),
    "delta": ("m", "Risk bound δ on the intrusion depth"),
    "epsilon": ("m", "Wasserstein radius ε of DR-CVaR, or auto (estimated online)"),
    "noise": ("", "Noise preset of the environment (e.g. authors_code); empty for the "
                  "scenario's own"),
    "case": ("", "Stress-suite case (e.g. heavy_tail); empty outside the stress suite"),
    "filter_options": ("", "Further SafetyFilterWrapper keywords, as canonical JSON"),
    "env_options": ("", "Further gym.make keywords, as canonical JSON"),
    "policy": ("", "PPO policy file that ran; empty for the shipped one or the MPC planner"),
    "policy_sha256": ("", "SHA-256 of the policy file's content"),
    "version": ("", "Version of the safe-nav package that ran the episode"),
    "steps": ("steps", "Environment steps of the episode (0.2 s each by default)"),
    "collision": ("bool", "Whether the ego collided, in continuous time (exact clearance over "
                          "each step)"),
    "collision_steps": ("steps", "Steps with a continuous-time collision"),
    "first_collision_step": ("step", "First step with a continuous-time collision (1-based; "
                                     "0: none)"),
    "collision_cause": ("", "For a collided episode: fallback (a non-optimal filter status at "
                            "the colliding step or the two before), inter_sample (overlap only "
                            "between samples) or noise (noise beyond the margin); else empty"),
    "sampled_collision": ("bool", "Whether the ego collided at the sample instants (the "
                                  "paper's statistic)"),
    "sampled_collision_steps": ("steps", "Steps with a collision at the sample instants"),
    "min_distance": ("m", "Smallest clearance to any obstacle at the sample instants "
                          "(negative: overlap)"),
    "min_swept_distance": ("m", "Smallest clearance over the continuous-time path (negative: "
                                "overlap; NaN if not reported)"),
    "discomfort_steps": ("steps", "Steps whose sampled clearance to some obstacle was below "
                                  "the environment's discomfort distance (0.2 m in "
                                  "SafeNav/Crowd-v0; 0 where not reported)"),
    "goal_reached": ("bool", "Whether the ego reached its goal"),
    "time_to_goal": ("s", "Time at which the goal was reached (NaN if not reached)"),
    "path_length": ("m", "Length of the ego's path"),
    "mean_intervention": ("m/s²", "Mean of ||u_applied - u_proposed|| over the steps"),
    "max_intervention": ("m/s²", "Largest ||u_applied - u_proposed|| over the steps"),
    "statuses": ("", "Filter status counts, e.g. optimal:38;soft:2"),
    "share_optimal": ("1", "Share of the steps whose QP was solved as posed"),
    "share_soft": ("1", "Share of the steps answered by the exact-penalty QP with halfspace "
                        "slack"),
    "share_recovery": ("1", "Share of the steps answered by the recovery QP with arena slack"),
    "share_shifted": ("1", "Share of the steps that applied the last optimal plan, shifted "
                           "(the paper's fallback)"),
    "share_brake": ("1", "Share of the steps that braked (last resort)"),
    "share_error": ("1", "Share of the steps that braked on bad data (NaN action or "
                         "predictions)"),
    "fallback_steps": ("steps", "Steps with the paper's fallbacks shifted or brake"),
    "first_error": ("", "The first step's reason for braking on bad data, e.g. step 3: NaN "
                        "action"),
    "filter_time_median": ("s", "Median time of one filter step (halfspaces + QP)"),
    "filter_time_max": ("s", "Largest time of one filter step"),
    "episode_return": ("1", "Sum of the environment's rewards over the episode"),
    "audit_steps": ("count", "Active first-step halfspaces (obstacle-steps) in the guarantee "
                             "audit"),
    "audit_losses": ("m", "Their realised losses, ';'-separated, rounded to 0.1 mm"),
    "audit_all_steps": ("count", "Every first-step halfspace in the audit, active or not"),
    "audit_all_losses": ("m", "Their realised losses, ';'-separated, rounded to 0.1 mm"),
    "wall_time": ("s", "Wall-clock time of the episode"),
    "error": ("", "Why the episode failed (an exception); empty if it ran"),
}
"""Unit and meaning of every CSV column (:data:`RECORD_FIELDS`), for the docs' glossary.
Units: ``""`` for labels and text, ``"1"`` for dimensionless numbers and shares."""


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


def sort_records(records: Iterable[EpisodeRecord]) -> list[EpisodeRecord]:
    """Records in a canonical order (scenario, risk, seed, ...), independent of completion order."""
    risk_order = {risk: i for i, risk in enumerate(RISKS)}
    epsilon = KEY_FIELDS.index("epsilon")

    def order(record: EpisodeRecord) -> tuple:
        key = list(record.key())
        value = key[epsilon]  # a fixed radius sorts before "auto" (str and float do not compare)
        key[epsilon] = (1, 0.0) if value == AUTO else (0, value)
        return (record.case, record.scenario, risk_order.get(record.risk, len(RISKS)), *key[2:])

    return sorted(records, key=order)


# ---------------------------------------------------------------------------- CSV
def _parse(name: str, raw: str, path: Path, line: int) -> Any:
    kind = _KINDS[name]
    if name == "epsilon" and raw == AUTO:
        return raw
    if name == "epsilon":
        kind = "float"
    try:
        if kind in ("int", int):
            return int(float(raw)) if raw else 0
        if kind in ("float", float):
            return float(raw) if raw else math.nan
        if kind in ("bool", bool):
            if raw not in ("True", "False", ""):
                raise ValueError(raw)
            return raw == "True"
    except ValueError:
        raise RecordsFileError(f"{path}, line {line}: column {name!r} must be {kind}, "
                               f"got {raw!r}") from None
    return raw


def read_records(path: str | Path) -> list[EpisodeRecord]:
    """Records from a results CSV (written by :class:`RecordWriter`).

    Raises
    ------
    RecordsFileError
        If the header is not :data:`RECORD_FIELDS` (a CSV of another version) or a
        value does not parse.
    """
    path = Path(path)
    records = []
    with open(path, newline="") as handle:
        reader = csv.DictReader(handle)
        header = tuple(reader.fieldnames or ())
        if header != RECORD_FIELDS:
            missing = [c for c in RECORD_FIELDS if c not in header]
            extra = [c for c in header if c not in RECORD_FIELDS]
            raise RecordsFileError(
                f"{path} was not written by this version of safe-nav (columns missing: "
                f"{missing or 'none'}, unknown: {extra or 'none'})")
        for row in reader:
            if None in row or any(row[name] is None for name in RECORD_FIELDS):
                raise RecordsFileError(f"{path}, line {reader.line_num}: wrong number of columns")
            records.append(EpisodeRecord(**{name: _parse(name, row[name], path, reader.line_num)
                                            for name in RECORD_FIELDS}))
    return records


class RecordWriter:
    """Appends records to a CSV as they finish, so an interrupted run can resume.

    Raises
    ------
    RecordsFileError
        If ``path`` exists with another header.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        new = not self.path.exists() or self.path.stat().st_size == 0
        if not new:
            with open(self.path, newline="") as handle:
                header = tuple(next(csv.reader(handle), ()))
            if header != RECORD_FIELDS:
                raise RecordsFileError(
                    f"{self.path} has other columns than this version of safe-nav writes")
        self._handle = open(self.path, "a", newline="")
        self._writer = csv.DictWriter(self._handle, fieldnames=RECORD_FIELDS)
        self.written = 0
        if new:
            self._writer.writeheader()
            self._handle.flush()

    def __call__(self, record: EpisodeRecord) -> None:
        self._writer.writerow(asdict(record))
        self._handle.flush()
        self.written += 1

    def close(self) -> None:
        self._handle.close()

    def __enter__(self) -> RecordWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_records(path: str | Path, records: Iterable[EpisodeRecord]) -> None:
    """Replace ``path`` by a CSV of ``records`` (atomically: a temporary file, then a rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.name + ".tmp")
    with open(temporary, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=RECORD_FIELDS)
        writer.writeheader()
        for record in records:
            writer.writerow(asdict(record))
    os.replace(temporary, path)


# ---------------------------------------------------------------------------- run keys
def package_version() -> str:
    """Version of the installed safe-nav package (``"unknown"`` if it is not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("safe-nav")
    except PackageNotFoundError:  # pragma: no cover - running from a bare checkout
        return "unknown"


def file_sha256(path: str | Path) -> str:
    """SHA-256 (hex) of a file's content."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def run_key(specs: Sequence[EpisodeSpec], *, vary: Sequence[str] = ()) -> dict[str, Any]:
    """Every setting the episodes of a run share, plus the package version.

    Parameters
    ----------
    specs
        The run's episodes.
    vary
        Key fields that vary within the run by design besides :data:`CYCLED_FIELDS`
        (a sweep's ``("epsilon", "delta")``); they are left out of the run key.

    Returns
    -------
    dict
        ``{field: value}`` for every other field of :data:`KEY_FIELDS` and
        ``"version"``; JSON-serialisable. The policy counts by its content
        (``policy_sha256``), not by its path.

    Raises
    ------
    InvalidParameterError
        If such a field differs between the specs.
    """
    varying = set(CYCLED_FIELDS) | set(vary)
    names = [name for name in KEY_FIELDS if name not in varying]
    key: dict[str, Any] = {}
    for name in names:
        values = {getattr(spec, name) for spec in specs}
        if len(values) > 1:
            raise InvalidParameterError(
                f"the episodes of one run must share {name!r}, got {sorted(values, key=str)}")
        key[name] = values.pop() if values else None
    # The held-out calibration of conformal / epsilon="auto" (its defaults included).
    calibrations = {json.dumps(settings, sort_keys=True) for spec in specs
                    if (settings := calibration_settings(**spec.filter_kwargs())) is not None}
    if calibrations:
        key["calibration"] = [json.loads(text) for text in sorted(calibrations)]
    key["version"] = package_version()
    return key


def run_key_path(csv_path: str | Path) -> Path:
    """Where the run key of a results CSV is kept: ``episodes.csv`` -> ``episodes.run.json``."""
    csv_path = Path(csv_path)
    return csv_path.with_name(csv_path.stem + ".run.json")


def check_run_key(csv_path: str | Path, key: Mapping[str, Any]) -> None:
    """Refuse to add to ``csv_path`` unless its stored run key equals ``key``.

    Writes the key if the CSV holds no rows yet.

    Raises
    ------
    RunMismatchError
        If the stored key differs (the message names every differing setting), or the
        CSV has rows but no key.
    """
    csv_path = Path(csv_path)
    key_path = run_key_path(csv_path)
    has_rows = csv_path.exists() and csv_path.stat().st_size > 0
    hint = "choose another output folder (--output), or discard it (--overwrite)"
    if not key_path.exists():
        if has_rows:
            raise RunMismatchError(f"{csv_path} holds results but no run key {key_path.name} "
                                   f"(an older safe-nav wrote it?), so they cannot be reused; "
                                   f"{hint}")
        key_path.parent.mkdir(parents=True, exist_ok=True)
        key_path.write_text(json.dumps(dict(key), indent=2, sort_keys=True) + "\n")
        return
    try:
        stored = json.loads(key_path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise RunMismatchError(f"{key_path} is not a readable run key ({exc}); {hint}") from None
    wanted = json.loads(json.dumps(dict(key)))
    names = sorted(set(stored) | set(wanted))
    differ = [f"{name} {stored.get(name)!r} != {wanted.get(name)!r}" for name in names
              if stored.get(name) != wanted.get(name)]
    if differ:
        raise RunMismatchError(f"{csv_path.parent} holds a run with other settings "
                               f"({'; '.join(differ)} now); {hint}")

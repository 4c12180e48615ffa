"""Records and specs: CSV round trip, record keys, run keys, collision causes, statuses."""

from __future__ import annotations

import csv
import json
import math
import warnings

import numpy as np
import pytest

from agents.errors import RecordsFileError, RunMismatchError
from agents.evaluation.records import (
    FILTER_STATUSES,
    KEY_FIELDS,
    RECORD_FIELDS,
    EpisodeRecord,
    EpisodeSpec,
    RecordWriter,
    check_run_key,
    options_json,
    read_records,
    run_key,
    run_key_path,
    write_records,
)
from agents.evaluation.runner import EpisodeStats
from filters.errors import InvalidParameterError
from safe_nav_env import ScenarioNameWarning


def _record(seed: int, **changes) -> EpisodeRecord:
    values = dict(scenario="HeadOn", risk="dr_cvar", seed=seed, planner="ppo",
                  reference="rollout", alpha=0.2, delta=0.1, epsilon=0.05,
                  filter_options='{"soft":true}', policy="p.zip", policy_sha256="ab" * 32,
                  version="0.1.0", steps=40, collision=seed % 2 == 1, collision_steps=seed % 2,
                  first_collision_step=3 * (seed % 2), collision_cause="noise" if seed % 2 else "",
                  min_distance=-0.01 * seed, min_swept_distance=math.nan, goal_reached=True,
                  time_to_goal=4.2, statuses="optimal:39;soft:1", share_optimal=39 / 40,
                  share_soft=1 / 40, first_error="step 3: NaN action, with, commas",
                  error="" if seed < 2 else 'RuntimeError: "quoted" | line\tbreak')
    values.update(changes)
    return EpisodeRecord(**values)


def test_records_round_trip_through_csv_with_every_type(tmp_path):
    path = tmp_path / "episodes.csv"
    records = [_record(seed) for seed in range(4)]
    with RecordWriter(path) as writer:
        for record in records:
            writer(record)
    assert tuple(next(csv.reader(path.open()))) == RECORD_FIELDS
    back = read_records(path)
    assert back == records  # NaN equals NaN, strings with commas and quotes survive
    assert math.isnan(back[0].min_swept_distance) and back[1].collision is True
    assert back[1] != _record(1, min_distance=0.5)
    write_records(path, back[:2])
    assert read_records(path) == records[:2]


def test_a_csv_of_another_version_is_refused(tmp_path):
    path = tmp_path / "old.csv"
    path.write_text("scenario,risk,seed\nSafeNav/HeadOn-v0,none,0\n")
    with pytest.raises(RecordsFileError, match="columns missing"):
        read_records(path)
    with pytest.raises(RecordsFileError, match="other columns"):
        RecordWriter(path)
    good = tmp_path / "bad_value.csv"
    write_records(good, [_record(0)])
    text = good.read_text().replace(",40,", ",forty,", 1)
    good.write_text(text)
    with pytest.raises(RecordsFileError, match="steps"):
        read_records(good)


def test_spec_and_record_share_one_key():
    spec = EpisodeSpec("HeadOn", "dr_cvar", 0, filter_options={"soft": True},
                       policy_sha256="ab" * 32)
    assert spec.key() == _record(0).key()
    assert len(spec.key()) == len(KEY_FIELDS)
    # Same settings in another order or type: same key.
    other = EpisodeSpec("HeadOn", "dr_cvar", np.int64(0), alpha=np.float64(0.2),
                        filter_options='{"soft": true}', policy_sha256="ab" * 32)
    assert other.key() == spec.key()
    assert EpisodeSpec("HeadOn", "dr_cvar", 0, epsilon=0.1).key() != spec.key()


def test_spec_validates_its_settings():
    with pytest.raises(InvalidParameterError, match="risk"):
        EpisodeSpec("HeadOn", "maximal", 0)
    with pytest.raises(InvalidParameterError, match="planner"):
        EpisodeSpec("HeadOn", "none", 0, planner="rrt")
    with pytest.raises(InvalidParameterError, match="noise"):
        EpisodeSpec("HeadOn", "none", 0, noise="pink")
    with pytest.raises(InvalidParameterError, match="seed"):
        EpisodeSpec("HeadOn", "none", 0.5)
    with pytest.raises(InvalidParameterError, match="finite"):
        EpisodeSpec("HeadOn", "none", 0, filter_options={"alpha_scale": math.nan})
    with pytest.raises(InvalidParameterError, match="number, string"):
        EpisodeSpec("HeadOn", "none", 0, env_options={"scenario": object()})
    with pytest.raises(ValueError, match="unknown scenario 'Roundabout'"):
        EpisodeSpec("Roundabout", "none", 0)


def test_options_become_canonical_json():
    assert options_json({"b": (1, 2), "a": np.float32(0.5)}) == '{"a":0.5,"b":[1,2]}'
    assert options_json({}) == options_json(None) == options_json("") == ""
    assert options_json('{"b": 1, "a": true}') == '{"a":true,"b":1}'
    assert json.loads(options_json({"Q": np.eye(2)})) == {"Q": [[1.0, 0.0], [0.0, 1.0]]}
    assert (options_json({"scenario": {"name": "a", "goal": (4, 0)}})  # Custom's scenario
            == '{"scenario":{"goal":[4,0],"name":"a"}}')


def test_settings_that_would_be_silently_ignored_are_refused():
    with pytest.raises(InvalidParameterError, match="'Custom' only"):  # would replace HeadOn
        EpisodeSpec("HeadOn", "none", 0, env_options={"scenario": "Overtaking"})
    assert EpisodeSpec("Custom", "none", 0, env_options={"scenario": "Overtaking"})
    for planner in ("mpc", "goal"):
        with pytest.raises(InvalidParameterError, match=f"planner '{planner}'.*uses no policy"):
            EpisodeSpec("HeadOn", "none", 0, planner=planner, policy_path="policy.zip")


def test_scenario_spellings_become_the_canonical_name():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert EpisodeSpec("HeadOn", "none", 0).scenario == "HeadOn"
    for spelling in ("head_on", "SafeNav/HeadOn-v0"):
        with pytest.warns(ScenarioNameWarning, match="'HeadOn'"):
            assert EpisodeSpec(spelling, "none", 0).scenario == "HeadOn"


def test_run_key_covers_the_shared_settings_and_refuses_a_mismatch(tmp_path):
    specs = [EpisodeSpec(s, r, i, policy_sha256="cd" * 32) for s in ("HeadOn", "Overtaking")
             for r in ("none", "cvar") for i in range(2)]
    key = run_key(specs)
    assert {"planner", "reference", "alpha", "delta", "epsilon", "noise", "filter_options",
            "env_options", "policy_sha256", "version"} <= set(key)
    assert not {"scenario", "risk", "seed"} & set(key)
    with pytest.raises(InvalidParameterError, match="share 'alpha'"):
        run_key([*specs, EpisodeSpec("HeadOn", "none", 0, alpha=0.3, policy_sha256="cd" * 32)])
    assert "epsilon" not in run_key(specs, vary=("epsilon",))

    path = tmp_path / "episodes.csv"
    check_run_key(path, key)  # first run: stores the key
    assert json.loads(run_key_path(path).read_text()) == key
    check_run_key(path, key)  # same run: fine
    other = dict(key, policy_sha256="ef" * 32, alpha=0.3)
    with pytest.raises(RunMismatchError, match="alpha 0.2 != 0.3.*policy_sha256"):
        check_run_key(path, other)
    # Rows without a key (an older version) are never reused.
    orphan = tmp_path / "orphan" / "episodes.csv"
    write_records(orphan, [_record(0)])
    with pytest.raises(RunMismatchError, match="no run key"):
        check_run_key(orphan, key)


class _Base:
    dt = 0.2
    ego_state = np.zeros(4)


def _info(status: str, collision: bool, sampled: bool, error: str = "") -> dict:
    return {"collision": collision, "sampled_collision": sampled,
            "distance_to_collision": np.array([0.5]), "min_swept_distance_to_collision": 0.4,
            "filter": {"status": status, "intervention": 0.0, "filter_time": 0.0,
                       "error": error}}


def _stats(steps: list[tuple]) -> EpisodeStats:
    stats = EpisodeStats()
    stats.start(_Base(), {})
    for step in steps:
        stats.step(_Base(), 0.0, _info(*step))
    return stats


@pytest.mark.parametrize(("steps", "cause"), [
    ([("optimal", False, False)] * 3, ""),
    ([("optimal", False, False)] * 4 + [("optimal", True, True)], "noise"),
    ([("optimal", False, False)] * 4 + [("optimal", True, False)], "inter_sample"),
    # A fallback two steps before the first collision, or at it: blamed on the fallback.
    ([("optimal", False, False)] * 2 + [("shifted", False, False), ("optimal", False, False),
                                        ("optimal", True, False)], "fallback"),
    ([("optimal", False, False)] * 4 + [("brake", True, True)], "fallback"),
    # Three steps before is outside the window.
    ([("soft", False, False)] + [("optimal", False, False)] * 3 + [("optimal", True, True)],
     "noise"),
    # Only the first collision counts.
    ([("optimal", True, True), ("brake", False, False), ("brake", True, False)], "noise"),
    ([("passthrough", False, False), ("passthrough", True, False)], "inter_sample"),
])
def test_collision_cause(steps, cause):
    summary = _stats(steps).summary()
    assert summary["collision_cause"] == cause
    assert summary["collision"] == any(s[1] for s in steps)
    assert summary["sampled_collision"] == any(s[2] for s in steps)
    first = next((i + 1 for i, s in enumerate(steps) if s[1]), 0)
    assert summary["first_collision_step"] == first


@pytest.mark.parametrize(("steps", "explained"), [
    ([("optimal", False, False)] * 3, (0, "", "")),
    # Infeasible at step 3 (soft), collision at step 5: the statuses before and at it.
    ([("optimal", False, False)] * 2 + [("soft", False, False), ("recovery", False, False),
                                        ("soft", True, True)], (3, "recovery", "soft")),
    # A collision in step 1 has no status before it.
    ([("optimal", True, True), ("brake", False, False)], (2, "", "optimal")),
    ([("passthrough", False, False), ("passthrough", True, False)],
     (0, "passthrough", "passthrough")),
])
def test_first_infeasible_step_and_statuses_around_the_collision(steps, explained):
    summary = _stats(steps).summary()
    assert (summary["first_infeasible_step"], summary["status_before_collision"],
            summary["status_at_collision"]) == explained


def test_status_shares_and_the_first_error_reason():
    steps = ([("optimal", False, False)] * 5 + [("soft", False, False)] * 2
             + [("error", False, False, "NaN action")]
             + [("brake", False, False, "NaN predictions")]
             + [("recovery", False, False)])
    summary = _stats(steps).summary()
    shares = {s: summary[f"share_{s}"] for s in FILTER_STATUSES}
    assert shares == pytest.approx({"optimal": 0.5, "soft": 0.2, "recovery": 0.1,
                                    "shifted": 0.0, "brake": 0.1, "error": 0.1})
    assert summary["first_error"] == "step 8: NaN action"
    assert summary["fallback_steps"] == 5  # every step whose constraints did not all hold
    assert summary["min_swept_distance"] == pytest.approx(0.4)


@pytest.mark.parametrize(("speeds", "standing"), [
    # Speed at the start of each step, then at its end: the collision is in the last step.
    ([0.0, 0.0, 0.05], True),    # below 0.1 m/s at both ends of the colliding step
    ([0.0, 0.5, 0.0], False),    # braked to rest during the colliding step: it moved
    ([0.0, 0.0, 0.1], False),    # 0.1 m/s is moving
    ([0.3, 0.0, 0.0], True),     # stopped before the colliding step
])
def test_standing_collision_flags_a_collision_with_the_ego_at_rest(speeds, standing):
    class Base(_Base):
        ego_state = np.array([0.0, 0.0, speeds[0], 0.0])

    base = Base()
    stats = EpisodeStats()
    stats.start(base, {})
    for i, speed in enumerate(speeds[1:]):
        base.ego_state = np.array([0.0, 0.0, 0.0, speed])
        stats.step(base, 0.0, _info("optimal", i == len(speeds) - 2, False))
    assert stats.summary()["standing_collision"] is standing
    # No collision: never standing_collision.
    assert _stats([("optimal", False, False)] * 2).summary()["standing_collision"] is False

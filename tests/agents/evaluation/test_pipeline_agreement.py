"""Episode-level equivalence: the evaluation pipeline (the numpy actor, DAQP) and a
reference pipeline (SB3's own ``predict`` for the planner, the QP in Clarabel) give
collision and goal rates that agree within their Wilson 95 % intervals on 200 episodes
each (the equivalence rule of the docs' design page). The cell is the mean filter with
the held action on Intersection, which lets collisions through (a rate to compare)."""

from __future__ import annotations

import functools

import pytest

import filters.wrapper
from agents.evaluation.records import EpisodeSpec
from agents.evaluation.runner import run_episode
from agents.evaluation.statistics import wilson_interval
from agents.policies.loading import load_ppo

EPISODES = 200


def _rates(records):
    collisions = sum(r.collision for r in records)
    goals = sum(r.goal_reached for r in records)
    return {"collision": (collisions, wilson_interval(collisions, len(records))),
            "goal": (goals, wilson_interval(goals, len(records)))}


@pytest.mark.slow
def test_fast_and_reference_pipelines_agree_within_their_intervals(monkeypatch):
    specs = [EpisodeSpec("Intersection", "mean", seed, reference="hold")
             for seed in range(EPISODES)]
    fast = [run_episode(spec)[0] for spec in specs]
    model = load_ppo()  # the shipped policy, answered by SB3 itself
    monkeypatch.setattr(filters.wrapper, "MPCSafetyFilter",
                        functools.partial(filters.wrapper.MPCSafetyFilter, backend="clarabel"))
    reference = [run_episode(spec, policy=model)[0] for spec in specs]
    assert not any(r.error for r in fast + reference)
    ours, theirs = _rates(fast), _rates(reference)
    assert ours["collision"][0] > 0  # the mean filter lets some through: a rate to compare
    for name in ("collision", "goal"):
        (k_ours, (low_ours, high_ours)), (k_ref, (low_ref, high_ref)) = ours[name], theirs[name]
        tolerance = 1e-12  # the interval's ends are computed in floating point
        assert low_ref - tolerance <= k_ours / EPISODES <= high_ref + tolerance, (ours, theirs)
        assert low_ours - tolerance <= k_ref / EPISODES <= high_ours + tolerance, (ours, theirs)

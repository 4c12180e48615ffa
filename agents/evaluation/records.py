"""What an evaluation runs and what it records: episode specs, records, CSV, run keys.

One import for the evaluation's data: the episode specs and records with their columns
and keys (:mod:`agents.evaluation.episodes`), the results CSV
(:mod:`agents.evaluation.record_csv`) and the run keys (:mod:`agents.evaluation.run_keys`)
are importable from here. This module defines :data:`COLUMN_DOCS`, the unit and meaning
of every column, from which the docs' CSV glossary is built. The scenario list of the
paper is :data:`safe_nav_env.constants.PAPER_SCENARIOS`, the risk names
:data:`filters.wrapper.RISKS` and the scenario names :data:`safe_nav_env.SCENARIO_NAMES`.
"""

from __future__ import annotations

from agents.evaluation.episodes import (
    AUTO,
    CYCLED_FIELDS,
    FILTER_STATUSES,
    KEY_FIELDS,
    PLANNERS,
    RECORD_FIELDS,
    REFERENCES,
    TIMING_FIELDS,
    EpisodeRecord,
    EpisodeSpec,
    episode_key,
    options_json,
)
from agents.evaluation.record_csv import RecordWriter, read_records, sort_records, write_records
from agents.evaluation.run_keys import (
    check_run_key,
    file_sha256,
    package_version,
    run_key,
    run_key_path,
)
from filters.wrapper import RISKS
from safe_nav_env.constants import PAPER_SCENARIOS
from safe_nav_env.scenarios import SCENARIO_NAMES

__all__ = [
    "AUTO",
    "COLUMN_DOCS",
    "CYCLED_FIELDS",
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
    "check_run_key",
    "episode_key",
    "file_sha256",
    "options_json",
    "package_version",
    "read_records",
    "run_key",
    "run_key_path",
    "sort_records",
    "write_records",
]

COLUMN_DOCS: dict[str, tuple[str, str]] = {
    "scenario": ("", "Canonical scenario name (HeadOn for SafeNav/HeadOn-v0); Custom for a "
                     "stress case"),
    "risk": ("", "Risk metric of the safe halfspaces; none is the unfiltered planner"),
    "seed": ("", "Seed of env.reset: the obstacles' noise and any random scenario data"),
    "planner": ("", "Reference planner: ppo (the policy), mpc (the paper's obstacle-agnostic "
                    "MPC) or goal (the obstacle-blind go-to-goal controller)"),
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
    "first_infeasible_step": ("step", "First step whose hard filter problem had no solution "
                                      "(status soft, recovery, shifted, brake or error; "
                                      "1-based; 0: none)"),
    "status_before_collision": ("", "Filter status at the step before the first collision "
                                    "(empty without a collision or if it is in step 1)"),
    "status_at_collision": ("", "Filter status at the first colliding step (empty without "
                                "a collision)"),
    "standing_collision": ("bool", "Whether the first collision happened with the ego standing "
                                   "still (speed below 0.1 m/s over the whole step)"),
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

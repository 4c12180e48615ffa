"""Benchmarks over a scene environment's settings: the specs and the setting of a record.

A *scene suite* runs one scene environment (``SafeNav/Crowd-v0``,
``SafeNav/Pedestrians-v0``) under several named settings (environment options) and
risks, on the same seeds in every cell (common random numbers: test case ``i`` is seed
``seed + i``), through the evaluation pipeline.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from agents.evaluation.campaign import EvaluationOutputs, Report, run_campaign
from agents.evaluation.config import EvaluationConfig, split_options
from agents.evaluation.records import EpisodeRecord, EpisodeSpec
from agents.evaluation.summary import summarise
from agents.policies.loading import pretrained_policy_path
from filters._validation import integer_at_least
from filters.errors import InvalidParameterError

__all__ = ["run_scene_suite", "scene_groups", "scene_setting", "scene_specs"]


def scene_specs(scenario: str, catalogue: Mapping[str, Mapping[str, Any]],
                settings: Sequence[str], risks: Sequence[str], *, episodes: int, seed: int,
                **common: Any) -> list[EpisodeSpec]:
    """One spec per (setting, risk, test case).

    Parameters
    ----------
    scenario
        The scene environment's scenario name (``"Crowd"``, ``"Pedestrians"``).
    catalogue
        Setting name -> its environment options.
    settings
        The names to run, in ``catalogue``.
    risks
        Filter risks (``"none"``: the planner alone).
    episodes, seed
        Test cases per cell, seeds ``seed .. seed + episodes - 1``.
    common
        Further :class:`~agents.evaluation.records.EpisodeSpec` fields; ``env_options``
        are merged under each setting's options.

    Raises
    ------
    InvalidParameterError
        For an unknown setting or a non-positive episode count.
    """
    unknown = [s for s in settings if s not in catalogue]
    if unknown:
        raise InvalidParameterError(f"unknown {scenario} settings {unknown}; choose from "
                                    f"{list(catalogue)}")
    integer_at_least("episodes", episodes)
    env_options = common.pop("env_options", "") or {}
    if isinstance(env_options, str):
        env_options = json.loads(env_options)
    return [EpisodeSpec(scenario=scenario, risk=risk, seed=seed + i,
                        env_options={**env_options, **catalogue[setting]}, **common)
            for setting in settings for risk in risks for i in range(episodes)]


def scene_setting(record: EpisodeRecord, catalogue: Mapping[str, Mapping[str, Any]]) -> str:
    """The name in ``catalogue`` whose options the record's environment options contain
    (the options themselves if none does)."""
    options = json.loads(record.env_options) if record.env_options else {}
    for name, setting in catalogue.items():
        if all(options.get(key) == value for key, value in setting.items()):
            return name
    return record.env_options


def scene_groups(records: Sequence[EpisodeRecord], catalogue: Mapping[str, Mapping[str, Any]],
                 ) -> list[tuple[str, str, list[EpisodeRecord], list[EpisodeRecord]]]:
    """Per (setting, risk), in the order they first appear: the records, and those that ran."""
    groups: dict[tuple[str, str], list[EpisodeRecord]] = {}
    for record in records:
        groups.setdefault((scene_setting(record, catalogue), record.risk), []).append(record)
    return [(*key, group, [r for r in group if not r.error]) for key, group in groups.items()]


def run_scene_suite(output: str | Path | None, scenario: str,
                    catalogue: Mapping[str, Mapping[str, Any]], settings: Sequence[str],
                    risks: Sequence[str], *, table: Callable[[Sequence[EpisodeRecord]], str],
                    title: str, shipped_policy: str, config: EvaluationConfig | None,
                    episodes: int, seed: int, **options: Any) -> EvaluationOutputs:
    """Run a scene suite as a campaign; write ``episodes.csv`` and ``summary.md`` (``title``,
    the run's description and ``table(records)``) to ``output`` (default
    ``results/<scenario in lower case>``).

    ``shipped_policy`` is the PPO file in ``agents/pretrained/`` used when the planner is
    PPO and ``policy_path`` is empty; ``config`` and ``options`` as for
    :func:`agents.evaluation.campaign.run_evaluation`. Raises what :func:`scene_specs` and
    :func:`~agents.evaluation.campaign.run_campaign` raise, before any episode runs.
    """
    config, common = split_options(config, output, options,
                                   default=f"results/{scenario.lower()}")
    if common.get("planner", "ppo") == "ppo" and not common.get("policy_path"):
        common["policy_path"] = str(pretrained_policy_path(shipped_policy))
    specs = scene_specs(scenario, catalogue, settings, risks, episodes=episodes, seed=seed,
                        **common)

    def report(records: Sequence[EpisodeRecord]) -> Report:
        markdown = table(records)
        return Report(title, f"\n{markdown}", summarise(records), markdown)

    return run_campaign(specs, config, report, vary=("env_options",))

"""Benchmarks over a scene environment's settings: the specs and the setting of a record.

A *scene suite* runs one scene environment (``SafeNav/Crowd-v0``,
``SafeNav/Pedestrians-v0``) under several named settings (environment options) and
risks, on the same seeds in every cell (common random numbers: test case ``i`` is seed
``seed + i``), through the evaluation pipeline.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from agents.evaluation.campaign import EvaluationOutputs, describe_run, output_folder
from agents.evaluation.evaluate import evaluate
from agents.evaluation.records import EpisodeRecord, EpisodeSpec
from agents.evaluation.summary import summarise
from agents.policies.loading import pretrained_policy_path
from filters._validation import integer_at_least
from filters.errors import InvalidParameterError

__all__ = ["run_scene_suite", "scene_setting", "scene_specs"]


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


def run_scene_suite(output: str | Path, scenario: str, catalogue: Mapping[str, Mapping[str, Any]],
                    settings: Sequence[str], risks: Sequence[str], *,
                    table: Callable[[Sequence[EpisodeRecord]], str], title: str,
                    shipped_policy: str, episodes: int, seed: int, workers: int, planner: str,
                    reference: str, policy_path: str, alpha: float, delta: float, epsilon: float,
                    **options: Any) -> EvaluationOutputs:
    """Run a scene suite through the evaluation pipeline; write ``episodes.csv`` and
    ``summary.md`` (``title``, the run's description and ``table(records)``) to ``output``.

    ``shipped_policy`` is the PPO file in ``agents/pretrained/`` used when the planner is
    PPO and ``policy_path`` is empty; ``options`` are ``filter_options``, ``env_options``,
    ``executor``, ``progress`` and ``overwrite`` as for
    :func:`agents.evaluation.evaluate.evaluate`. Raises what :func:`scene_specs` and
    :func:`~agents.evaluation.evaluate.evaluate` raise, before any episode runs.
    """
    output = output_folder(output)
    if planner == "ppo" and not policy_path:
        policy_path = str(pretrained_policy_path(shipped_policy))
    specs = scene_specs(scenario, catalogue, settings, risks, episodes=episodes, seed=seed,
                        planner=planner, reference=reference, policy_path=policy_path,
                        alpha=alpha, delta=delta, epsilon=epsilon,
                        filter_options=options.pop("filter_options", None) or "",
                        env_options=options.pop("env_options", None) or "")
    start = time.perf_counter()
    records = evaluate(specs=specs, vary=("env_options",), workers=workers,
                       csv_path=output / "episodes.csv", **options)
    wall = time.perf_counter() - start
    markdown = table(records)
    run_settings = (f"alpha {alpha}, delta {delta} m, epsilon {epsilon} m, {episodes} "
                    f"episodes per cell (seeds {seed}..{seed + episodes - 1})")
    (output / "summary.md").write_text(
        f"# {title}\n\n"
        + describe_run(records, planner=planner, reference=reference, settings=run_settings)
        + f"- this call: {wall:.1f} s wall time on {workers} worker(s)\n\n" + markdown)
    files = {"episodes": output / "episodes.csv", "run_key": output / "episodes.run.json",
             "summary": output / "summary.md"}
    return EvaluationOutputs(records, summarise(records), markdown,
                             time.perf_counter() - start, files, reused=records.reused)

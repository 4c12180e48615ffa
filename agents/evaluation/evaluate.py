"""Monte Carlo evaluation of filtered against unfiltered reference planners.

An *episode* is one scenario, one risk setting, one planner and one seed. Episodes
with the same seed see the same obstacle noise whatever the risk setting (the
environment draws the same random numbers each step whatever the action), so
risk settings are compared on common random numbers.

:func:`evaluate` is the orchestration: it checks every setting and the policy file
*before* anything runs (:func:`check_specs`), resumes from the results CSV of the
same run (its run key must match: :func:`agents.evaluation.records.check_run_key`; failed rows
are run again), runs the rest on an executor and writes each record as it finishes.
Every episode returns an :class:`~agents.evaluation.records.EpisodeRecord`; a failing episode
(an exception, a NaN) is recorded with ``error`` set instead of stopping the run.

The parts live in :mod:`agents.evaluation.records` (specs, records, CSV, run keys),
:mod:`agents.evaluation.runner` (one episode) and
:mod:`agents.evaluation.executors` (process pool, Ray); import their names from there.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import fields
from pathlib import Path
from typing import Any

from agents.errors import OutputPathError, RecordsFileError
from agents.evaluation.executors import Executor, make_executor
from agents.evaluation.records import (
    KEY_FIELDS,
    PAPER_SCENARIOS,
    RISKS,
    EpisodeRecord,
    EpisodeSpec,
    RecordWriter,
    check_run_key,
    read_records,
    run_key,
    run_key_path,
    sort_records,
    write_records,
)
from agents.evaluation.runner import load_policy, make_env
from filters._validation import integer_at_least
from filters.errors import InvalidParameterError

__all__ = ["SPEC_OPTIONS", "EvaluationInterrupted", "EvaluationRecords", "check_specs",
           "episode_specs", "evaluate", "output_folder"]

SPEC_OPTIONS = tuple(f.name for f in fields(EpisodeSpec)
                     if f.name not in ("scenario", "risk", "seed", "policy_sha256"))
"""Keywords of :func:`evaluate` that become fields of every :class:`EpisodeSpec`."""


class EvaluationInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`evaluate`; the finished episodes are saved.

    Attributes
    ----------
    finished, total
        Episodes finished (and saved, if there is a CSV) and asked for.
    csv_path
        The results CSV, or ``None``.
    reused
        Of the finished episodes, those read back from the CSV (run before this call).
    """

    def __init__(self, finished: int, total: int, csv_path: Path | None,
                 reused: int = 0) -> None:
        super().__init__(f"interrupted after {finished} of {total} episodes")
        self.finished, self.total, self.csv_path, self.reused = finished, total, csv_path, reused


class EvaluationRecords(list):
    """The records :func:`evaluate` returns: a list, and how many of them were reused.

    Attributes
    ----------
    reused
        Records of finished episodes read back from the results CSV (an earlier,
        interrupted or shorter run of the same settings), not run again by this call.
    """

    reused: int = 0


def episode_specs(
    scenarios: Sequence[str],
    risks: Sequence[str],
    episodes: int,
    seed: int = 0,
    **spec_kwargs: Any,
) -> list[EpisodeSpec]:
    """Every (scenario, risk, episode) combination; episode ``i`` uses seed ``seed + i``.

    Raises
    ------
    InvalidParameterError
        For an unknown risk, planner, reference, noise preset or keyword, or
        ``episodes < 1``.
    ScenarioError
        For an unknown scenario.
    """
    if unknown := sorted(set(spec_kwargs) - set(SPEC_OPTIONS)):
        raise InvalidParameterError(f"unknown episode setting(s) {unknown}; expected some of "
                                    f"{list(SPEC_OPTIONS)}")
    integer_at_least("episodes", episodes)
    return [EpisodeSpec(scenario=s, risk=r, seed=seed + i, **spec_kwargs)
            for s in scenarios for r in risks for i in range(episodes)]


def check_specs(specs: Sequence[EpisodeSpec]) -> list[EpisodeSpec]:
    """Check every setting before anything runs; return the specs with the policy's hash.

    Loads each PPO policy once (a missing or corrupt file fails here, not in every
    episode) and builds the filtered environment of each distinct setting once, so
    that the filter's and the environment's own validation run up front.

    Raises
    ------
    PolicyFileError
        If a policy file is missing, corrupt or does not load.
    InvalidParameterError, ScenarioError, ConfigError
        For a setting the filter or the environment rejects.
    """
    hashes: dict[str, str] = {}
    checked = []
    built: set[tuple] = set()
    seed = KEY_FIELDS.index("seed")
    for spec in specs:
        if spec.planner == "ppo":
            if spec.policy_path not in hashes:
                _, hashes[spec.policy_path] = load_policy(spec.policy_path)
            sha = hashes[spec.policy_path]
            if spec.policy_sha256 and spec.policy_sha256 != sha:
                raise InvalidParameterError(
                    f"policy_sha256 {spec.policy_sha256[:12]}... does not match the file "
                    f"{spec.policy_path or 'shipped'} ({sha[:12]}...)")
            if spec.policy_sha256 != sha:
                # The spec was checked when it was made and the hash is a checked string:
                # a copy with the hash, without replace's second check of every field
                # (thousands of specs, in the parent, before the workers get any).
                spec = copy.copy(spec)
                object.__setattr__(spec, "policy_sha256", sha)
        key = spec.key()
        setting = key[:seed] + key[seed + 1:]  # one environment per setting, any seed
        if setting not in built:
            env, _ = make_env(spec)
            env.close()
            built.add(setting)
        checked.append(spec)
    return checked


def output_folder(output: str | Path) -> Path:
    """``output`` as a path, if it can be an output folder (it is not made here).

    Raises
    ------
    OutputPathError
        If ``output`` or one of its parents is a file.
    """
    output = Path(output)
    for folder in (output, *output.parents):
        if folder.exists():
            if not folder.is_dir():
                raise OutputPathError(f"output folder {output} cannot be made: {folder} is a "
                                      "file; choose another --output")
            break
    return output


def _resume(path: Path, specs: Sequence[EpisodeSpec], key: dict[str, Any],
            overwrite: bool) -> list[EpisodeRecord]:
    """The finished records of ``specs`` in ``path``; drops its failed rows from the file."""
    if overwrite:
        for old in (path, run_key_path(path)):
            old.unlink(missing_ok=True)
    check_run_key(path, key)
    if not (path.exists() and path.stat().st_size):
        return []
    try:
        stored = read_records(path)
    except RecordsFileError as exc:
        raise RecordsFileError(f"{exc}; use another output folder or --overwrite") from None
    latest = {record.key(): record for record in stored}
    kept = [r for r in latest.values() if not r.error]
    if len(kept) != len(stored):  # failed or repeated rows: rewrite without them
        write_records(path, kept)
    wanted = {spec.key() for spec in specs}
    return [r for r in kept if r.key() in wanted]


def evaluate(
    scenarios: Sequence[str] = PAPER_SCENARIOS,
    risks: Sequence[str] = RISKS,
    *,
    episodes: int = 100,
    seed: int = 0,
    workers: int = 1,
    executor: str | Executor = "process",
    address: str | None = None,
    csv_path: str | Path | None = None,
    progress: bool = True,
    overwrite: bool = False,
    specs: Sequence[EpisodeSpec] | None = None,
    vary: Sequence[str] = (),
    **spec_kwargs: Any,
) -> EvaluationRecords:
    """Run the Monte Carlo comparison of risk settings and return every episode's record.

    Parameters
    ----------
    scenarios
        Scenario names (``"HeadOn"``, ...; gym ids are accepted with a warning).
    risks
        Risk settings, ``"none"`` being the unfiltered planner.
    episodes
        Episodes per (scenario, risk); episode ``i`` uses seed ``seed + i``.
    workers
        Local worker processes (``executor="process"``).
    executor
        ``"process"`` (default) or ``"ray"``: an executor made here, started before the
        settings are checked (its workers get ready meanwhile) and closed at the end; or
        an :class:`~agents.evaluation.executors.Executor` to reuse across calls (left open).
    csv_path
        If given, records are appended there as they finish, and the finished episodes
        of the same run are not run again (an interrupted run resumes; failed rows are
        run again). The run key (``<csv stem>.run.json``) must match.
    progress
        Show a progress bar.
    overwrite
        Delete the CSV and its run key first.
    specs
        Run these episodes instead of the (scenarios x risks x episodes) grid.
    vary
        Key fields besides scenario, risk and seed that vary within the run (see
        :func:`agents.evaluation.records.run_key`).
    **spec_kwargs
        ``planner``, ``reference``, ``alpha``, ``delta``, ``epsilon``, ``policy_path``,
        ``noise``, ``filter_options``, ``env_options`` (see :class:`EpisodeSpec`).

    Returns
    -------
    EvaluationRecords
        A list of EpisodeRecord sorted by scenario, risk and seed, whatever the order they
        finished in, so the result does not depend on the number of workers; its
        ``reused`` attribute counts the records read back from ``csv_path``.

    Raises
    ------
    PolicyFileError, InvalidParameterError, ScenarioError, ConfigError
        For a bad setting or policy, before any episode runs.
    RunMismatchError, RecordsFileError, OutputPathError
        If ``csv_path`` holds another run's results or cannot be written.
    EvaluationInterrupted
        On Ctrl-C, after saving the finished episodes.
    """
    if specs is None:
        specs = episode_specs(scenarios, risks, episodes, seed, **spec_kwargs)
    elif spec_kwargs:
        raise InvalidParameterError(f"pass either specs or settings, got both ({spec_kwargs})")
    # An executor given is left open (its owner closes it); one made here is closed at the
    # end of the block, and stopped at once on an error or Ctrl-C.
    with (nullcontext(executor) if isinstance(executor, Executor)
          else make_executor(executor, workers, address=address)) as runner:
        runner.start()  # its workers get ready while the policy loads here
        return _run(check_specs(specs), runner, csv_path, vary, progress, overwrite)


def _run(specs: list[EpisodeSpec], executor: Executor, csv_path: str | Path | None,
         vary: Sequence[str], progress: bool, overwrite: bool) -> EvaluationRecords:
    """The records of ``specs`` (resumed from ``csv_path``, the rest run on ``executor``)."""
    done: list[EpisodeRecord] = []
    writer = path = None
    if csv_path is not None:
        path = output_folder(Path(csv_path).parent) / Path(csv_path).name
        if path.exists() and not path.is_file():
            raise OutputPathError(f"results file {path} is a folder")
        done = _resume(path, specs, run_key(specs, vary=vary), overwrite)
        writer = RecordWriter(path)
    finished = {r.key() for r in done}
    todo = [spec for spec in specs if spec.key() not in finished] if done else list(specs)
    records = list(done)
    from tqdm.auto import tqdm

    bar = tqdm(executor.run(todo), total=len(todo), desc="episodes", unit="ep",
               disable=not (progress and todo))
    try:
        for record in bar:
            if writer is not None:
                writer(record)
            records.append(record)
    except KeyboardInterrupt as exc:
        raise EvaluationInterrupted(len(records), len(specs), path, len(done)) from exc
    finally:
        bar.close()
        if writer is not None:
            writer.close()
    result = EvaluationRecords(sort_records(records))
    result.reused = len(done)
    return result


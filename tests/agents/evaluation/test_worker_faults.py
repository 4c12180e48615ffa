"""A worker process killed mid-run: the evaluation completes, every episode recorded once."""

from __future__ import annotations

import os
import signal
from dataclasses import replace

import pytest

import agents.evaluation.executors
from agents.errors import WorkersLostError
from agents.evaluation.evaluate import episode_specs, evaluate
from agents.evaluation.executors import ProcessExecutor
from agents.evaluation.records import TIMING_FIELDS, read_records

TIMING = dict.fromkeys(TIMING_FIELDS, 0.0)
"""The columns that measure time (they differ between any two runs); the rest must match."""


def _timeless(records):
    return [replace(r, **TIMING) for r in records]


class KillsAWorker(ProcessExecutor):
    """Kills one of its worker processes (SIGKILL) when the first episode comes back."""

    def __init__(self, workers: int) -> None:
        super().__init__(workers)
        self.killed: list[int] = []

    def run(self, specs):
        for record in super().run(specs):
            if not self.killed:
                pid = self.worker_pids()[0]
                os.kill(pid, signal.SIGKILL)
                self.killed.append(pid)
            yield record


def test_a_killed_worker_loses_and_repeats_no_episode(tmp_path):
    kwargs = dict(episodes=6, seed=3, progress=False, planner="mpc")
    clean = evaluate(["HeadOn"], ["none"], workers=1, **kwargs)
    path = tmp_path / "episodes.csv"
    with KillsAWorker(2) as executor:
        faulty = evaluate(["HeadOn"], ["none"], executor=executor, csv_path=path,
                          **kwargs)
        # The kill broke the pool mid-run (episodes were left) and one fresh pool finished.
        assert len(executor.killed) == 1 and executor.restarts == 1 and executor.starts == 2
    with pytest.raises(ProcessLookupError):
        os.kill(executor.killed[0], 0)  # really gone
    rows = read_records(path)
    assert len(rows) == len(clean) == 6
    assert len({r.key() for r in rows}) == 6  # each episode exactly once
    assert _timeless(faulty) == _timeless(clean)
    assert sorted(_timeless(rows), key=lambda r: r.key()) == sorted(_timeless(clean),
                                                                    key=lambda r: r.key())


def _dies(specs, policies=None, task=None):
    os._exit(1)  # the worker process dies with the episode (a segfault, the OOM killer)


def test_workers_that_keep_dying_stop_the_run_with_a_clear_error(monkeypatch):
    # Pickled by reference, so the spawned workers import this module and run _dies.
    monkeypatch.setattr(agents.evaluation.executors, "run_specs_chunk", _dies)
    specs = episode_specs(["HeadOn"], ["none"], 2, planner="mpc")
    with ProcessExecutor(2, max_restarts=1) as executor:
        with pytest.raises(WorkersLostError, match="broke 2 times in a row"):
            list(executor.run(specs))
        assert executor.restarts == 1 and executor.starts == 2

"""Where episodes run: in this process, in a pool of local processes, or on Ray.

An executor runs :func:`agents.evaluation.runner.run_spec` over episode specs and yields the
records as they finish (order of completion; :func:`agents.evaluation.evaluate.evaluate`
sorts them). Executors keep their workers between calls to :meth:`Executor.run`
until closed, so a sweep pays the start-up (spawn, imports, policy load) once.

Episodes are seeded individually, so every executor gives the same records.

Ray (``--executor ray``, the ``ray`` extra): connects to the cluster named by
``RAY_ADDRESS`` if set (``ray start --head`` on the head node, ``ray start
--address=...`` on the others, the project installed on every node), otherwise
starts a local Ray instance.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Iterator, Sequence
from typing import Any

from agents.evaluation.records import EpisodeRecord, EpisodeSpec
from agents.evaluation.runner import run_spec
from filters.errors import InvalidParameterError

__all__ = ["EXECUTORS", "Executor", "ProcessExecutor", "RayExecutor", "SerialExecutor",
           "make_executor", "run_on_ray", "worker_init"]

EXECUTORS = ("process", "ray")
"""Executor kinds of :func:`make_executor` (``"process"`` with one worker runs serially)."""


def worker_init() -> None:
    """Set up a worker process: one thread per library, Ctrl-C left to the parent.

    The parent handles Ctrl-C (it saves what has finished and stops the workers), so
    workers ignore SIGINT instead of dying mid-episode with a traceback each. torch
    is not imported here (seconds per worker, and the MPC planner needs none):
    :func:`agents.evaluation.runner.load_policy` sets its threads when it loads a policy.
    """
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # pragma: no cover - not the main thread (e.g. some Ray workers)
        pass
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)


class Executor:
    """Runs episodes; use as a context manager (or call :meth:`close`)."""

    def run(self, specs: Sequence[EpisodeSpec]) -> Iterator[EpisodeRecord]:
        """Yield the record of every spec as it finishes."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the workers (waiting for none: nothing is running between calls)."""

    def terminate(self) -> None:
        """Stop the workers now (after Ctrl-C); episodes running are lost."""
        self.close()

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, exc_type: Any, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.terminate()


class SerialExecutor(Executor):
    """Runs episodes one after the other in this process."""

    def run(self, specs: Sequence[EpisodeSpec]) -> Iterator[EpisodeRecord]:
        for spec in specs:
            yield run_spec(spec)


class ProcessExecutor(Executor):
    """A pool of ``workers`` spawned processes, started at the first run and kept."""

    def __init__(self, workers: int) -> None:
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            raise InvalidParameterError(f"workers must be an integer >= 1, got {workers!r}")
        self.workers = workers
        self._pool: Any = None
        self.starts = 0
        """How many times a pool was started (1 for a whole sweep)."""

    def _ensure_pool(self) -> Any:
        if self._pool is None:
            import multiprocessing

            context = multiprocessing.get_context("spawn")
            self._pool = context.Pool(self.workers, initializer=worker_init)
            self.starts += 1
        return self._pool

    def run(self, specs: Sequence[EpisodeSpec]) -> Iterator[EpisodeRecord]:
        specs = list(specs)
        if not specs:
            return
        pool = self._ensure_pool()
        # One episode per task: a record is saved as soon as it finishes (an episode
        # takes 0.05-1 s, the round trip to a worker well under a millisecond).
        yield from pool.imap_unordered(run_spec, specs, chunksize=1)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.close()
            self._pool.join()
            self._pool = None

    def terminate(self) -> None:
        if self._pool is not None:
            self._pool.terminate()
            self._pool.join()
            self._pool = None


def _ray_task(spec: EpisodeSpec) -> EpisodeRecord:
    worker_init()
    return run_spec(spec)


class RayExecutor(Executor):
    """Episodes as Ray tasks, at most ``max_in_flight`` submitted at once.

    Parameters
    ----------
    address
        Ray cluster address; ``None`` uses ``RAY_ADDRESS`` or a running/local instance.
    max_in_flight
        Bound on submitted tasks (bounded memory for big sweeps).
    """

    def __init__(self, *, address: str | None = None, max_in_flight: int = 256) -> None:
        try:
            import ray
        except ImportError as exc:  # pragma: no cover - depends on the extra
            raise ImportError("--executor ray needs Ray: pip install -e '.[ray]'") from exc
        self._ray = ray
        self.address = address
        self.max_in_flight = int(max_in_flight)
        self._in_flight: list[Any] = []

    def run(self, specs: Sequence[EpisodeSpec]) -> Iterator[EpisodeRecord]:
        ray = self._ray
        if not ray.is_initialized():
            ray.init(address=self.address, include_dashboard=False, log_to_driver=False)
        task = ray.remote(num_cpus=1)(_ray_task)
        pending = list(specs)[::-1]
        self._in_flight = []
        while pending or self._in_flight:
            while pending and len(self._in_flight) < self.max_in_flight:
                self._in_flight.append(task.remote(pending.pop()))
            done, self._in_flight = ray.wait(self._in_flight, num_returns=1)
            yield from ray.get(done)

    def terminate(self) -> None:
        for ref in self._in_flight:
            self._ray.cancel(ref, force=True)
        self._in_flight = []


def run_on_ray(specs: Sequence[EpisodeSpec], *, address: str | None = None,
               max_in_flight: int = 256) -> Iterator[EpisodeRecord]:
    """Yield the records of ``specs`` as their Ray tasks finish."""
    yield from RayExecutor(address=address, max_in_flight=max_in_flight).run(specs)


def make_executor(kind: str = "process", workers: int = 1) -> Executor:
    """An executor: ``"process"`` with ``workers`` local processes (1: this process), or
    ``"ray"``.

    Raises
    ------
    InvalidParameterError
        For another ``kind`` or ``workers < 1``.
    """
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise InvalidParameterError(f"workers must be an integer >= 1, got {workers!r}")
    if kind == "ray":
        return RayExecutor()
    if kind != "process":
        raise InvalidParameterError(f"executor must be one of {EXECUTORS}, got {kind!r}")
    return SerialExecutor() if workers == 1 else ProcessExecutor(workers)

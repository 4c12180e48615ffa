"""Where episodes run: in this process, in a pool of local processes, or on Ray.

An executor runs a task over episodes and yields its results as they finish (order of
completion; :func:`agents.evaluation.evaluate.evaluate` sorts them). The task is
:func:`agents.evaluation.runner.run_spec` (episode spec -> record) unless the caller
passes another module-level function of one episode (``safe-nav reproduce`` runs
:func:`agents.experiments.encounters.run_encounter`, which keeps each trajectory).
Executors keep their workers between calls to :meth:`Executor.run` until closed, so a
sweep pays the start-up (processes, imports, policy load) once.

Episodes are seeded individually, so every executor gives the same results, and an
episode run again (its worker died) gives the same result too: a worker process killed
mid-run or a Ray node lost costs the episodes it was running, which run again, and
every episode is yielded exactly once.

Ray (``--executor ray``, the ``ray`` extra): runs on the cluster at ``--address``
(``HOST:PORT`` of a head started with ``ray start --head --port=PORT``, or ``auto``),
else on the one named by ``RAY_ADDRESS`` if set, else starts a local Ray instance.
Every node needs the project installed (``ray start --address=HEAD:PORT`` on the
others); see docs/ray.md.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from agents.errors import WorkersLostError
from agents.evaluation.policy_files import exported_policies, preload_policies
from agents.evaluation.runner import run_spec
from filters._validation import integer_at_least
from filters.errors import InvalidParameterError

__all__ = ["EXECUTORS", "Executor", "ProcessExecutor", "RayExecutor", "SerialExecutor",
           "make_executor", "stop_fork_server", "worker_init"]

EXECUTORS = ("process", "ray")
"""Executor kinds of :func:`make_executor` (``"process"`` with one worker runs serially)."""

Task = Callable[[Any], Any]
"""A function of one episode (:func:`run_spec`, the default, takes an
:class:`~agents.evaluation.records.EpisodeSpec`), defined at module level so that it
pickles by reference to the workers; it records an episode's own failure in its result
instead of raising."""


def worker_init() -> None:
    """Set up a worker process: one thread per library, Ctrl-C left to the parent.

    The parent handles Ctrl-C (it saves what has finished and stops the workers), so
    workers ignore SIGINT instead of dying mid-episode with a traceback each. torch
    is not imported here (seconds per worker, and the MPC planner needs none): local
    workers get the parent's numpy export of each policy with their episodes
    (:func:`run_specs_chunk`); a policy they load themselves
    (:func:`agents.evaluation.policy_files.load_policy`) sets torch's threads.
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

    def run(self, specs: Sequence[Any], task: Task | None = None) -> Iterator[Any]:
        """Yield ``task(spec)`` of every spec as it finishes (``task`` ``None``:
        :func:`run_spec`, the spec's :class:`~agents.evaluation.records.EpisodeRecord`)."""
        raise NotImplementedError

    def start(self) -> None:
        """Start the workers now, so that they get ready while the caller does other work
        (:func:`agents.evaluation.evaluate.evaluate` checks the settings and loads the
        policies meanwhile); :meth:`run` starts them otherwise."""

    def close(self) -> None:
        """Release the workers (waiting for none: nothing is running between calls)."""

    def terminate(self) -> None:
        """Stop the workers now (after Ctrl-C); episodes running are lost."""
        self.close()

    def __enter__(self) -> Executor:
        self.start()  # the workers start while the caller imports and checks
        return self

    def __exit__(self, exc_type: Any, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.terminate()


class SerialExecutor(Executor):
    """Runs episodes one after the other in this process."""

    def run(self, specs: Sequence[Any], task: Task | None = None) -> Iterator[Any]:
        run = task or run_spec
        for spec in specs:
            yield run(spec)


class ProcessExecutor(Executor):
    """A pool of ``workers`` processes, started on entering the context (or at the first
    run) and kept; they fork from a server that imported the episode code once
    (:func:`_worker_context`).

    A worker that dies mid-run (killed, out of memory) breaks the pool: the episodes
    not yet returned are run again on a fresh pool (they are seeded, so they give
    the same results), and every episode is yielded exactly once. The parent never
    waits on a dead worker.

    Parameters
    ----------
    workers
        Worker processes (>= 1).
    max_restarts
        Fresh pools started in a row without an episode finishing in between before
        :class:`~agents.errors.WorkersLostError` is raised (>= 0).
    """

    def __init__(self, workers: int, *, max_restarts: int = 3) -> None:
        self.workers = integer_at_least("workers", workers)
        self.max_restarts = integer_at_least("max_restarts", max_restarts, low=0)
        self._pool: Any = None
        self._starter: Any = None  # the thread of start(), while it starts the workers
        self.starts = 0
        """How many times a pool was started (1 for a whole sweep without faults)."""
        self.restarts = 0
        """How many of those starts replaced a pool broken by a lost worker."""

    def _ensure_pool(self) -> Any:
        if self._pool is None:
            from concurrent.futures import ProcessPoolExecutor

            self._pool = ProcessPoolExecutor(self.workers, mp_context=_worker_context(),
                                             initializer=worker_init)
            self.starts += 1
        return self._pool

    def start(self) -> None:
        """Start every worker process, in a thread: the first start waits for the fork
        server to import the project (about a second) while the caller goes on."""
        if self._starter is not None:
            return
        pool = self._ensure_pool()
        missing = self.workers - len(pool._processes or {})
        if missing > 0:
            import threading

            self._starter = threading.Thread(target=_start_workers, args=(pool, missing),
                                             name="safe-nav-workers-start", daemon=True)
            self._starter.start()

    def _started(self) -> None:
        """Wait until the workers :meth:`start` is starting have started."""
        if self._starter is not None:
            self._starter.join()
            self._starter = None

    def _live_workers(self) -> list[Any]:
        """The pool's live worker processes (none before the first run or start)."""
        self._started()
        processes = (self._pool._processes or {}) if self._pool is not None else {}
        return [p for p in list(processes.values()) if p.is_alive()]

    def worker_pids(self) -> list[int]:
        """Process ids of the pool's live workers (none before the first run or start)."""
        return [p.pid for p in self._live_workers()]

    def run(self, specs: Sequence[Any], task: Task | None = None) -> Iterator[Any]:
        from concurrent.futures import FIRST_COMPLETED, wait
        from concurrent.futures.process import BrokenProcessPool

        self._started()
        pending = list(specs)[::-1]  # a stack: episodes are submitted in their order
        # Episodes go to the workers in chunks (a few ms of work each: one round trip per
        # chunk, not per episode) of at most 16 episodes and at most an eighth of a
        # worker's share of those left (the chunks shrink towards the end, so that the
        # workers finish together instead of one running the last chunk alone), two
        # chunks per worker in flight so workers never wait for the parent. A broken
        # pool loses at most those chunks: their episodes run again, none is yielded twice
        # (a chunk's results are yielded together when it returns).
        # The policies the parent loaded (evaluate's check_specs does) travel with every
        # chunk as numpy arrays (tens of kB): workers skip torch, SB3 and the file's load.
        policies = exported_policies()
        in_flight: dict[Any, list[Any]] = {}
        lost_in_a_row = 0
        try:
            while pending or in_flight:
                pool = self._ensure_pool()
                while pending and len(in_flight) < 2 * self.workers:
                    size = max(1, min(CHUNK_EPISODES, len(pending) // (8 * self.workers)))
                    chunk = [pending.pop() for _ in range(size)]
                    in_flight[pool.submit(run_specs_chunk, chunk, policies, task)] = chunk
                done, _ = wait(in_flight, return_when=FIRST_COMPLETED)
                if any(isinstance(f.exception(), BrokenProcessPool) for f in done):
                    done, _ = wait(in_flight)  # a broken pool fails all its futures
                lost: list[Any] = []
                for future in done:
                    chunk = in_flight.pop(future)
                    if isinstance(future.exception(), BrokenProcessPool):
                        lost.extend(chunk)
                        continue
                    lost_in_a_row = 0
                    yield from future.result()  # a task records an episode's own errors
                if lost:  # drop the broken pool: the next round starts a fresh one
                    lost_in_a_row += 1
                    pending.extend(lost[::-1])
                    self.terminate()
                    if lost_in_a_row > self.max_restarts:
                        raise WorkersLostError(
                            f"the worker pool broke {lost_in_a_row} times in a row without an "
                            f"episode finishing ({len(pending)} episodes left): a worker "
                            "process keeps dying (out of memory? killed?); the finished "
                            "episodes are saved: run the same command again to resume, or "
                            "with --workers 1 to see the error")
                    self.restarts += 1
        finally:
            for future in in_flight:
                future.cancel()

    def close(self) -> None:
        self._started()
        if self._pool is not None:  # nothing runs between calls but start()'s empty tasks
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def terminate(self) -> None:
        """Kill the workers now; episodes running are lost."""
        for process in self._live_workers():
            process.kill()
        self.close()


CHUNK_EPISODES = 16
"""Most episodes a local worker runs per task (:class:`ProcessExecutor`)."""


def _worker_context() -> Any:
    """How the pool starts its processes: from a fork server that imported the episode
    code once (each worker forks from it, ready at once, instead of importing it again),
    else (no ``fork`` on this platform) spawned."""
    import multiprocessing

    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")  # pragma: no cover - Windows
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload([__name__])  # this module imports the runner
    return context


def stop_fork_server() -> None:
    """Stop the fork server of :func:`_worker_context` (if it runs) and wait for it.

    Its workers are its children, not this process's: their CPU time reaches this
    process's ``RUSAGE_CHILDREN`` only once the server has exited (the evaluation
    benchmark calls this before reading it). A later pool starts a new server.
    """
    import multiprocessing.forkserver

    multiprocessing.forkserver._forkserver._stop()


def run_specs_chunk(specs: Sequence[Any], policies: dict[tuple[str, str], Any] | None = None,
                    task: Task | None = None) -> list[Any]:
    """``task(spec)`` (default :func:`run_spec`) of every spec, in order (one task of a
    local worker).

    ``policies``: the parent's loaded policies
    (:func:`agents.evaluation.policy_files.exported_policies`), used instead of loading the files.
    """
    preload_policies(policies or {})
    run = task or run_spec
    return [run(spec) for spec in specs]


def _start_workers(pool: Any, count: int) -> None:
    """Have ``pool`` start ``count`` more worker processes (it starts one per task submitted
    while none is idle)."""
    for _ in range(count):
        try:
            pool.submit(_ready)
        except RuntimeError:  # pragma: no cover - the pool broke or was shut down meanwhile
            return


def _ready() -> None:
    """A task that does nothing: its worker has started and imported this module."""


def _ray_task(spec: Any, task: Task | None = None) -> Any:
    worker_init()
    return (task or run_spec)(spec)


class RayExecutor(Executor):
    """Episodes as Ray tasks, at most :attr:`MAX_IN_FLIGHT` submitted at once.

    A task whose worker or node dies is run again by Ray (:attr:`MAX_RETRIES` times; the
    episodes are seeded, so a retry gives the same result), and each episode is
    yielded once, when its task returns.

    Parameters
    ----------
    address
        Ray cluster address, ``"HOST:PORT"`` (the head's GCS port, ``ray start --head
        --port=PORT``) or ``"auto"`` (the cluster ``ray start`` started on this
        machine); ``None`` uses ``RAY_ADDRESS`` if set, else starts a local Ray.
        Ignored if Ray is already initialised in this process.
    """

    MAX_IN_FLIGHT = 256
    """Bound on submitted tasks (bounded memory for big sweeps)."""
    MAX_RETRIES = 3
    """Runs of a task again after its worker process or node died."""

    def __init__(self, *, address: str | None = None) -> None:
        try:
            import ray
        except ImportError as exc:  # pragma: no cover - depends on the extra
            from agents.errors import MissingExtraError

            raise MissingExtraError("--executor ray needs the 'ray' extra, which is not "
                                    "installed: pip install -e '.[ray]'") from exc
        if address is not None and (not isinstance(address, str) or not address.strip()):
            raise InvalidParameterError(f"address must be HOST:PORT or 'auto', got {address!r}")
        self._ray = ray
        self.address = address
        self._in_flight: dict[Any, Any] = {}
        self._initialised = False

    def run(self, specs: Sequence[Any], task: Task | None = None) -> Iterator[Any]:
        ray = self._ray
        if not ray.is_initialized():
            try:
                ray.init(address=self.address, log_to_driver=False)
            except ConnectionError as exc:
                raise WorkersLostError(
                    f"cannot connect to the Ray cluster at {self.address or 'RAY_ADDRESS'}: "
                    f"{exc} (is it running? a cluster with token authentication, recent Ray's "
                    "default, also needs RAY_AUTH_MODE=token and its token: see docs/ray.md)"
                ) from None
            self._initialised = True
        # SPREAD: episodes go to every node (the default packs them on the driver's node
        # first, leaving the others idle on a small cluster).
        remote = ray.remote(num_cpus=1, max_retries=self.MAX_RETRIES,
                          scheduling_strategy="SPREAD")(_ray_task)
        pending = list(specs)[::-1]
        self._in_flight = {}
        while pending or self._in_flight:
            while pending and len(self._in_flight) < self.MAX_IN_FLIGHT:
                spec = pending.pop()
                self._in_flight[remote.remote(spec, task)] = spec
            done, _ = ray.wait(list(self._in_flight), num_returns=1)
            spec = self._in_flight.pop(done[0])
            try:
                result = ray.get(done[0])
            except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError,
                    ray.exceptions.ObjectLostError) as exc:
                raise WorkersLostError(
                    f"episode {spec.scenario} {spec.risk} seed {spec.seed} was lost "
                    f"{self.MAX_RETRIES + 1} times with its Ray worker or node "
                    f"({type(exc).__name__}); the finished episodes are saved: run the "
                    "same command again to resume") from exc
            yield result

    def close(self) -> None:
        """Disconnect from Ray (and stop it if this executor started it)."""
        if self._initialised:
            self._ray.shutdown()
            self._initialised = False

    def terminate(self) -> None:
        for ref in self._in_flight:
            self._ray.cancel(ref, force=True)
        self._in_flight = {}
        self.close()


def make_executor(kind: str = "process", workers: int = 1, *,
                  address: str | None = None) -> Executor:
    """An executor: ``"process"`` with ``workers`` local processes (1: this process), or
    ``"ray"`` (on the cluster at ``address``, see :class:`RayExecutor`).

    Raises
    ------
    InvalidParameterError
        For another ``kind``, ``workers < 1``, or an ``address`` without ``"ray"``.
    """
    integer_at_least("workers", workers)
    if kind == "ray":
        return RayExecutor(address=address)
    if kind != "process":
        raise InvalidParameterError(f"executor must be one of {EXECUTORS}, got {kind!r}")
    if address is not None:
        raise InvalidParameterError(f"a Ray address ({address!r}) needs the ray executor "
                                    "(--executor ray)")
    return SerialExecutor() if workers == 1 else ProcessExecutor(workers)

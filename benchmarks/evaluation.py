"""``safe-nav bench --evaluation``: evaluation episodes per second on 1 and 2 local workers.

The workload is ``safe-nav evaluate`` with its defaults (the shipped PPO policy, the four
paper scenarios, risks none / mean / CVaR / DR-CVaR, 300 episodes each: 4,800 episodes)
and ``--no-plots --no-progress``, run end to end as a user runs it: a fresh interpreter
per run (imports, the policy check, the worker pool's start, the CSV, the summary and
its audit all count). Runs with 1 and 2 workers alternate, ``runs`` of each, so that
both see the same load on a shared machine; the speed-up is the ratio of the median
wall times (the ratio of episodes per second),

.. math:: S_2 = \\tilde t_1 / \\tilde t_2 .

With a serial part :math:`s` and a part :math:`p` that the workers share,
:math:`t_1 = s + p` and :math:`t_2 = s + p/2`, so :math:`s = 2 t_2 - t_1` (Amdahl; an
estimate, it also absorbs what the parent takes from the workers' two cores).

The wall time depends on the load; the CPU seconds (user + system) do not, much: each
run reports those of the ``evaluate`` process (the parent) and of its worker processes.
Both folders' CSVs are compared, timing columns aside: 1 and 2 workers must write the
same rows.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from benchmarks.timing import alternate, clock, median
from filters._validation import integer_at_least

WORKER_COUNTS = (1, 2)
"""Worker counts compared (``--workers``)."""

_RUNNER = """\
import json, resource, sys
from agents.cli import main
code = main(json.loads(sys.argv[1]))
from agents.evaluation.executors import stop_fork_server
stop_fork_server()  # its workers' CPU time counts once it has exited
own = resource.getrusage(resource.RUSAGE_SELF)
children = resource.getrusage(resource.RUSAGE_CHILDREN)
print("BENCH-EVALUATION " + json.dumps([code, own.ru_utime + own.ru_stime,
                                        children.ru_utime + children.ru_stime]))
"""
"""Runs ``safe-nav evaluate`` in a fresh interpreter; prints its exit code and the CPU
seconds of the process and of its (finished) worker processes."""


@dataclass(frozen=True)
class EvaluationRun:
    """One ``safe-nav evaluate`` run.

    Attributes
    ----------
    workers
        ``--workers``.
    wall
        Wall time of the whole command, in s (interpreter start to exit).
    parent_cpu, workers_cpu
        CPU seconds (user + system) of the ``evaluate`` process and of its workers.
    load
        1-minute load average of the machine just before the run.
    """

    workers: int
    wall: float
    parent_cpu: float
    workers_cpu: float
    load: float


@dataclass(frozen=True)
class EvaluationScaling:
    """Alternating runs on 1 and 2 workers of the same evaluation."""

    episodes: int  # episodes per run (all scenarios and risks)
    runs: tuple[EvaluationRun, ...]
    same_rows: bool  # 1 and 2 workers wrote the same CSV rows (timing columns aside)

    def wall(self, workers: int) -> float:
        """Median wall time in s on ``workers`` workers."""
        return median(run.wall for run in self.runs if run.workers == workers)

    def cpu(self, workers: int) -> float:
        """Median CPU seconds (parent + workers) on ``workers`` workers."""
        return median(run.parent_cpu + run.workers_cpu for run in self.runs
                      if run.workers == workers)

    @property
    def speedup(self) -> float:
        """Episodes per second on 2 workers over 1 (ratio of the median wall times)."""
        return self.wall(1) / self.wall(2)

    @property
    def serial(self) -> float:
        """Amdahl's serial part in s, ``2 t_2 - t_1`` (medians)."""
        return 2.0 * self.wall(2) - self.wall(1)

    def format(self) -> str:
        loads = [run.load for run in self.runs]
        return "\n".join([
            f"evaluation scaling: safe-nav evaluate, defaults, {self.episodes} episodes, "
            "--no-plots, end to end; runs alternate 1 and 2 workers",
            "  run  workers  wall (s)  episodes/s  CPU parent (s)  CPU workers (s)  load before",
            *(f"  {i:>3}  {run.workers:>7}  {run.wall:>8.1f}  {self.episodes / run.wall:>10.1f}"
              f"  {run.parent_cpu:>14.1f}  {run.workers_cpu:>15.1f}  {run.load:>11.2f}"
              for i, run in enumerate(self.runs)),
            *(f"  {n} worker{'s' if n > 1 else ' '}: median {self.wall(n):.1f} s "
              f"({self.episodes / self.wall(n):.1f} episodes/s), CPU {self.cpu(n):.1f} s "
              f"({1e3 * self.cpu(n) / self.episodes:.2f} ms per episode)" for n in WORKER_COUNTS),
            f"  speed-up 2 workers / 1: {self.speedup:.2f}x (target >= 1.8x); serial part "
            f"(Amdahl, 2 t2 - t1) {self.serial:.1f} s",
            f"  same rows on 1 and 2 workers (timing columns aside): "
            f"{'yes' if self.same_rows else 'NO'}",
            f"  load average before the runs: median {median(loads):.2f}, max {max(loads):.2f}"
            " (2 cores; above ~0.5 other work shares them)",
        ])


def _evaluate_once(workers: int, episodes: int, output: Path) -> EvaluationRun:
    """Run ``safe-nav evaluate`` in a fresh interpreter; time it."""
    argv = ["evaluate", "--episodes", str(episodes), "--workers", str(workers), "--no-plots",
            "--no-progress", "--overwrite", "--output", str(output)]
    load = os.getloadavg()[0]
    done, wall_ms = clock(subprocess.run, [sys.executable, "-c", _RUNNER, json.dumps(argv)],
                          capture_output=True, text=True, check=False)
    lines = [line for line in done.stdout.splitlines() if line.startswith("BENCH-EVALUATION ")]
    code, parent_cpu, workers_cpu = (json.loads(lines[-1].split(" ", 1)[1]) if lines
                                     else (done.returncode or 1, 0, 0))
    if code != 0:
        raise RuntimeError(f"safe-nav evaluate exited with {code}: {done.stderr.strip()[-500:]}")
    return EvaluationRun(workers, wall_ms / 1e3, parent_cpu, workers_cpu, load)


def same_rows(first: Path, second: Path) -> bool:
    """Whether two ``episodes.csv`` hold the same rows, timing columns and order aside."""
    from agents.evaluation.records import TIMING_FIELDS

    def rows(path: Path) -> list[tuple]:
        with open(path, newline="") as handle:
            return sorted(tuple((k, v) for k, v in row.items() if k not in TIMING_FIELDS)
                          for row in csv.DictReader(handle))

    return rows(first) == rows(second)


def benchmark_evaluation(episodes: int = 300, runs: int = 3, *,
                         progress: bool = False) -> EvaluationScaling:
    """Time ``safe-nav evaluate`` (defaults, ``episodes`` per scenario and risk) on 1 and 2
    workers, ``runs`` of each, alternating (see the module docstring).

    Raises
    ------
    InvalidParameterError
        If ``episodes`` or ``runs`` is not an integer >= 1.
    """
    integer_at_least("episodes", episodes)
    integer_at_least("runs", runs)
    from agents.cli.main import build_parser

    defaults = build_parser().parse_args(["evaluate"])
    total = episodes * len(defaults.scenarios) * len(defaults.risks)
    results: list[EvaluationRun] = []
    with tempfile.TemporaryDirectory(prefix="bench-evaluation-") as folder:
        def measure(workers: int) -> None:
            results.append(run := _evaluate_once(workers, episodes,
                                                 Path(folder) / f"workers{workers}"))
            if progress:
                print(f"  run {-(-len(results) // len(WORKER_COUNTS))}/{runs}, {workers} "
                      f"worker(s): {run.wall:.1f} s, load {run.load:.2f}", file=sys.stderr,
                      flush=True)

        alternate(WORKER_COUNTS, runs, measure, swap=True)
        same = same_rows(*(Path(folder) / f"workers{w}" / "episodes.csv"
                           for w in WORKER_COUNTS))
    return EvaluationScaling(total, tuple(results), same)

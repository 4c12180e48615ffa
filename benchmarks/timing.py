"""What every benchmark needs: a wall clock in ms, medians, counts and the machine line.

The machines are shared and noisy, so the benchmarks report medians, and ratios of
numbers measured in the same run.
"""

from __future__ import annotations

import platform
import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any, TypeVar

import numpy as np

K = TypeVar("K")
R = TypeVar("R")


def clock(function: Callable[..., Any], *args: Any, **kwargs: Any) -> tuple[Any, float]:
    """Call ``function(*args, **kwargs)``; return its result and its wall time in ms."""
    begin = time.perf_counter()
    result = function(*args, **kwargs)
    return result, 1e3 * (time.perf_counter() - begin)


def clock_cpu(function: Callable[..., Any], *args: Any,
              cpu: Callable[[], float] = time.process_time, **kwargs: Any
              ) -> tuple[Any, float, float]:
    """Call ``function(*args, **kwargs)``; return its result, its wall and its ``cpu``
    time in ms (default: the CPU time of this process)."""
    begin, begin_cpu = time.perf_counter(), cpu()
    result = function(*args, **kwargs)
    return result, 1e3 * (time.perf_counter() - begin), 1e3 * (cpu() - begin_cpu)


def alternate(kinds: Sequence[K], rounds: int, measure: Callable[[K], R], *,
              swap: bool = False) -> list[tuple[K, R]]:
    """``(kind, measure(kind))`` for each of ``kinds`` in turn, ``rounds`` times (with
    ``swap`` in reverse order every other round), in the order measured: alternating
    runs see the same load on a shared machine."""
    return [(kind, measure(kind)) for index in range(rounds)
            for kind in (kinds[::-1] if swap and index % 2 else kinds)]


def drive(env: Any, steps: int, seed: int, act: Callable[[Any, bool], Any]
          ) -> Iterator[tuple[dict, float]]:
    """Step ``env`` ``steps`` times with ``act(obs, new_episode)``, resetting it with
    ``seed``, ``seed + 1``, ... whenever an episode ends; yield each step's ``info`` and
    the wall time of its ``env.step`` in ms."""
    episode, done = 0, True
    for _ in range(steps):
        new_episode = done
        if done:
            obs, _ = env.reset(seed=seed + episode)
            episode += 1
        (obs, _, terminated, truncated, info), ms = clock(env.step, act(obs, new_episode))
        done = terminated or truncated
        yield info, ms


def median(values: Iterable[float], where: Iterable[bool] | None = None) -> float:
    """Median of ``values`` (of those where ``where`` is true); NaN when there are none."""
    values = np.asarray(list(values), dtype=float)
    if where is not None:
        values = values[np.asarray(list(where), dtype=bool)]
    return float(np.median(values)) if values.size else float("nan")


def p90(values: Iterable[float]) -> float:
    """90th percentile of ``values``."""
    return float(np.percentile(np.asarray(list(values), dtype=float), 90))


def counts(items: Iterable[object], pair: str = "{} {}", sep: str = ", ") -> str:
    """How often each item occurs, sorted: ``"optimal 471, soft 29"`` by default."""
    return sep.join(pair.format(k, v) for k, v in sorted(Counter(items).items()))


def machine() -> str:
    """``"python 3.11.7, numpy 2.4.6, x86_64"``: the first line of a report."""
    return f"python {platform.python_version()}, numpy {np.__version__}, {platform.machine()}"

"""``safe-nav bench --training``: PPO training steps per second with and without the filter.

Item (d) of :mod:`benchmarks.suite`: :func:`benchmark_training` trains a plain and a
DR-CVaR-filtered PPO model side by side in alternating chunks, so both see the same load
on a shared machine, and returns a :class:`TrainingThroughput` (rates and their ratio).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class TrainingThroughput:
    """PPO training steps per second without and with the DR-CVaR filter in the loop.

    Two models train side by side in one process, in alternating chunks (a plain chunk,
    a filtered chunk, ...; a chunk is one rollout and its update with the defaults), so
    both see the same load on a shared machine; every rate is ``chunk / time``.

    Attributes
    ----------
    chunk
        Steps per chunk (summed over the environments).
    plain_wall, filtered_wall
        Steps per wall second, one per chunk.
    plain_cpu, filtered_cpu
        Steps per CPU second of this process (``time.process_time``), one per chunk.
    filter_us
        Wall time per filtered step in µs (medians over the chunks of the per-chunk
        means): ``"reference"``, ``"halfspaces"``, ``"qp"`` (from the filter reports),
        ``"qp_not_optimal"`` (the part of ``"qp"`` spent on the steps whose status is not
        ``"optimal"``: the hard QP had no answer, the recovery QP or braking followed; 0
        if absent) and ``"step"`` (the whole filtered training step, ``1 / rate``).
    not_optimal_share
        Median over the chunks of the share of filtered steps whose status is not
        ``"optimal"`` (NaN if not measured).
    n_envs
        Number of in-process vector environments of each model.
    """

    chunk: int
    plain_wall: tuple[float, ...]
    filtered_wall: tuple[float, ...]
    plain_cpu: tuple[float, ...]
    filtered_cpu: tuple[float, ...]
    filter_us: dict[str, float]
    not_optimal_share: float = math.nan
    n_envs: int = 8

    @property
    def timesteps(self) -> int:
        """Timed steps of each kind."""
        return self.chunk * len(self.plain_wall)

    @property
    def ratio(self) -> float:
        """Median filtered over median plain steps per wall second."""
        return float(np.median(self.filtered_wall) / np.median(self.plain_wall))

    @property
    def cpu_ratio(self) -> float:
        """Median filtered over median plain steps per CPU second."""
        return float(np.median(self.filtered_cpu) / np.median(self.plain_cpu))

    @property
    def pair_ratio(self) -> float:
        """Median over the back-to-back pairs of filtered over plain wall rate."""
        return float(np.median(np.asarray(self.filtered_wall) / np.asarray(self.plain_wall)))

    def format(self) -> str:
        us = self.filter_us
        plain_us = 1e6 / float(np.median(self.plain_wall))
        rest = us["step"] - plain_us - us["reference"] - us["halfspaces"] - us["qp"]
        lines = [
            f"(d) PPO training, RandomCrossing, {self.n_envs} "
            f"environment{'s' if self.n_envs != 1 else ''}, {self.timesteps} steps of "
            f"each kind in {len(self.plain_wall)} alternating chunks of {self.chunk}, medians:",
            f"    plain    {np.median(self.plain_wall):6.0f} steps/s, "
            f"{np.median(self.plain_cpu):6.0f} per CPU s",
            f"    dr_cvar  {np.median(self.filtered_wall):6.0f} steps/s, "
            f"{np.median(self.filtered_cpu):6.0f} per CPU s",
            f"    ratio filtered / plain: {self.ratio:.2f} (wall), {self.cpu_ratio:.2f} (CPU), "
            f"{self.pair_ratio:.2f} (median of the pairs)   (target >= 0.75)",
            f"    per step: plain {plain_us:.0f} us; filtered {us['step']:.0f} us = plain + "
            f"{us['step'] - plain_us:.0f} us: reference {us['reference']:.0f}, halfspaces "
            f"{us['halfspaces']:.0f}, QP {us['qp']:.0f}, the rest {rest:.0f}",
        ]
        if not math.isnan(self.not_optimal_share):
            lines.append(
                f"    of the QP's {us['qp']:.0f} us: {us.get('qp_not_optimal', 0.0):.0f} on the "
                f"{100 * self.not_optimal_share:.0f} % of steps not optimal (the hard QP had no "
                f"answer: the recovery QP or braking followed)")
        return "\n".join(lines)


def _filter_clock() -> Any:
    """An SB3 callback summing the filter reports' reference, halfspace and QP times (and
    the QP time and count of the steps whose status is not ``"optimal"``)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class FilterClock(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.times = {"reference": 0.0, "halfspaces": 0.0, "qp": 0.0,
                          "qp_not_optimal": 0.0}
            self.reports = 0
            self.not_optimal = 0

        def _on_step(self) -> bool:
            times = self.times
            for info in self.locals["infos"]:
                report = info.get("filter")
                if report is not None:
                    qp = report.filter_time - report.halfspace_time
                    times["reference"] += report.reference_time
                    times["halfspaces"] += report.halfspace_time
                    times["qp"] += qp
                    self.reports += 1
                    if report.status != "optimal":
                        times["qp_not_optimal"] += qp
                        self.not_optimal += 1
            return True

    return FilterClock()


def benchmark_training(timesteps: int = 20_480, chunk: int = 2048, seed: int = 0, *,
                       filter_kwargs: dict | None = None,
                       warmup_steps: int = 2048, n_envs: int = 8) -> TrainingThroughput:
    """Training steps per second with and without the filter, in alternating chunks.

    What ``safe-nav train`` runs without and with ``--filter dr_cvar``
    (:func:`agents.train_ppo` defaults: RandomCrossing, ``n_envs`` in-process environments,
    8 by default, the held-action reference): both models are made (and warmed up: imports, first
    allocations) by ``train_ppo(total_timesteps=warmup_steps)``, then
    trained on ``chunk`` steps at a time, plain and filtered in turn, until each has
    ``timesteps`` timed steps. A chunk of 2048 steps is one rollout and its PPO update.

    Parameters
    ----------
    filter_kwargs
        The filter's keywords (default ``{"risk": "dr_cvar"}``: the wrapper's defaults).
    n_envs
        In-process vector environments of each model (``train_ppo(n_envs=...)``).
    """
    from agents.training.ppo import train_ppo

    filter_kwargs = {"risk": "dr_cvar"} if filter_kwargs is None else dict(filter_kwargs)
    models = {kind: train_ppo(total_timesteps=max(1, warmup_steps), seed=seed, n_envs=n_envs,
                              filter_kwargs=filter_kwargs if kind else None,
                              progress_bar=False)[0] for kind in (False, True)}
    rates: dict[bool, list[tuple[float, float]]] = {False: [], True: []}
    parts: list[dict[str, float]] = []
    shares: list[float] = []
    for _ in range(max(1, timesteps // chunk)):
        for filtered, model in models.items():
            clock = _filter_clock()
            before = model.num_timesteps
            wall, cpu = time.perf_counter(), time.process_time()
            model.learn(chunk, reset_num_timesteps=False, callback=clock)
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            steps = model.num_timesteps - before
            rates[filtered].append((steps / wall, steps / cpu))
            if filtered:
                parts.append({key: 1e6 * value / steps for key, value in clock.times.items()})
                shares.append(clock.not_optimal / max(1, clock.reports))
    for model in models.values():
        model.get_env().close()
    filtered_wall = tuple(r[0] for r in rates[True])
    filter_us = {key: float(np.median([p[key] for p in parts]))
                 for key in ("reference", "halfspaces", "qp", "qp_not_optimal")}
    filter_us["step"] = 1e6 / float(np.median(filtered_wall))
    return TrainingThroughput(
        chunk=chunk, plain_wall=tuple(r[0] for r in rates[False]), filtered_wall=filtered_wall,
        plain_cpu=tuple(r[1] for r in rates[False]), filtered_cpu=tuple(r[1] for r in rates[True]),
        filter_us=filter_us, not_optimal_share=float(np.median(shares)), n_envs=n_envs,
    )

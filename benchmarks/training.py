"""``safe-nav bench --training``: PPO training steps per second with and without the filter.

:func:`benchmark_training` trains a plain and a DR-CVaR-filtered PPO model side by side
in alternating chunks, so both see the same load on a shared machine, and returns a
:class:`TrainingThroughput` (rates and their ratio).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from benchmarks.timing import alternate, clock_cpu, median

PARTS = ("reference", "halfspaces", "qp", "qp_not_optimal")
"""Parts of a filtered step timed from the filter reports (:class:`TrainingThroughput`)."""


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
        return median(self.filtered_wall) / median(self.plain_wall)

    @property
    def cpu_ratio(self) -> float:
        """Median filtered over median plain steps per CPU second."""
        return median(self.filtered_cpu) / median(self.plain_cpu)

    @property
    def pair_ratio(self) -> float:
        """Median over the back-to-back pairs of filtered over plain wall rate."""
        return median(np.asarray(self.filtered_wall) / np.asarray(self.plain_wall))

    def format(self) -> str:
        us = self.filter_us
        plain_us = 1e6 / median(self.plain_wall)
        rest = us["step"] - plain_us - us["reference"] - us["halfspaces"] - us["qp"]
        lines = [
            f"(d) PPO training, RandomCrossing, {self.n_envs} environment"
            f"{'s' if self.n_envs != 1 else ''}, {self.timesteps} steps of each kind in "
            f"{len(self.plain_wall)} alternating chunks of {self.chunk}, medians:",
            *(f"    {name:<8} {median(wall):6.0f} steps/s, {median(cpu):6.0f} per CPU s"
              for name, wall, cpu in (("plain", self.plain_wall, self.plain_cpu),
                                      ("dr_cvar", self.filtered_wall, self.filtered_cpu))),
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
    """An SB3 callback summing the filter reports' times (s) of :data:`PARTS`, and counting
    the reports and those whose status is not ``"optimal"``."""
    from stable_baselines3.common.callbacks import BaseCallback

    class FilterClock(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.times = dict.fromkeys(PARTS, 0.0)
            self.reports = self.not_optimal = 0

        def _on_step(self) -> bool:
            for report in filter(None, (info.get("filter") for info in self.locals["infos"])):
                qp, late = report.filter_time - report.halfspace_time, report.status != "optimal"
                for key, value in zip(PARTS, (report.reference_time, report.halfspace_time,
                                              qp, qp * late), strict=True):
                    self.times[key] += value
                self.reports, self.not_optimal = self.reports + 1, self.not_optimal + late
            return True

    return FilterClock()


def benchmark_training(timesteps: int = 20_480, chunk: int = 2048, seed: int = 0, *,
                       warmup_steps: int = 2048, n_envs: int = 8) -> TrainingThroughput:
    """Training steps per second with and without the filter, in alternating chunks.

    What ``safe-nav train`` runs without and with ``--filter dr_cvar``
    (:func:`agents.train_ppo` defaults: RandomCrossing, ``n_envs`` in-process
    environments, the held-action reference): both models are made (and warmed up:
    imports, first allocations) by ``train_ppo(total_timesteps=warmup_steps)``, then
    trained on ``chunk`` steps at a time, plain and filtered in turn, until each has
    ``timesteps`` timed steps. A chunk of 2048 steps is one rollout and its PPO update.
    """
    from agents.training.ppo import train_ppo

    models = {filtered: train_ppo(total_timesteps=max(1, warmup_steps), seed=seed,
                                  n_envs=n_envs, progress_bar=False,
                                  filter_kwargs={"risk": "dr_cvar"} if filtered else None)[0]
              for filtered in (False, True)}

    def learn(filtered: bool) -> tuple[float, float, dict[str, float], float]:
        """One chunk: steps per wall and CPU second, µs per step of each part, share."""
        model, callback = models[filtered], _filter_clock()
        before = model.num_timesteps
        _, wall_ms, cpu_ms = clock_cpu(model.learn, chunk, reset_num_timesteps=False,
                                       callback=callback)
        steps = model.num_timesteps - before
        return (1e3 * steps / wall_ms, 1e3 * steps / cpu_ms,
                {key: 1e6 * value / steps for key, value in callback.times.items()},
                callback.not_optimal / max(1, callback.reports))

    runs = alternate((False, True), max(1, timesteps // chunk), learn)
    for model in models.values():
        model.get_env().close()
    (plain_wall, plain_cpu, _, _), (filtered_wall, filtered_cpu, parts, shares) = (
        tuple(zip(*(run for filtered, run in runs if filtered is kind), strict=True))
        for kind in (False, True))
    filter_us = {key: median(p[key] for p in parts) for key in PARTS}
    filter_us["step"] = 1e6 / median(filtered_wall)
    return TrainingThroughput(chunk, plain_wall, filtered_wall, plain_cpu, filtered_cpu,
                              filter_us, median(shares), n_envs)

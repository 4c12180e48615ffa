r"""How the sparse back ends' time per QP grows with the horizon, measured interleaved.

The scaling grid (:mod:`benchmarks.scaling`) times each point in a pass of its
own, seconds to minutes apart from the others, so a ratio of two points' times also
measures how the shared machine's speed drifted in between (on this 2-core host the same
code gave T = 80 over T = 20 ratios from 3.9x to 5.6x in two runs of the grid). Here the
recorded QPs of a short and a long horizon are solved alternately, one step of each in
turn, so both horizons see the same machine:

* Clarabel and PIQP on the **hard** QP of each step (the QP every step solves first);
* the Riccati method on the **recovery** QP of each step (the QP it solves: every
  halfspace, arena and terminal row soft).

For each back end the ratio of the median CPU times of the thread (long over short: at
most ``long / short`` for linear growth) splits into the ratio of the median iteration
counts (a property of the instances) and the ratio of the median CPU times per iteration
(the back end's work per iteration).

The instances are the grid's (:func:`~benchmarks.scaling.make_scaling_instances`,
with the same seeds), so both measurements describe the same QPs.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from benchmarks.filter_qp import RADIUS, double_integrator, filter_kwargs
from benchmarks.scaling import make_scaling_instances
from filters import Disc, MPCSafetyFilter, safe_halfspaces
from filters.errors import InvalidParameterError
from filters.mpc.result import StepData

__all__ = ["BACKENDS", "GrowthRatio", "benchmark_growth", "format_growth"]

#: The back ends measured, and which QP of each step each one solves.
BACKENDS = {"clarabel": "hard", "piqp": "hard", "riccati": "recovery"}


@dataclass(frozen=True)
class GrowthRatio:
    """One back end's growth from ``short`` to ``long`` at one obstacle count and N_s.

    Times are medians over the steps and repeats of the CPU time of the thread, in ms.
    """

    backend: str
    qp: str  # "hard" or "recovery"
    n_obstacles: int
    n_samples: int
    short: int
    long: int
    short_ms: float
    long_ms: float
    short_iterations: float
    long_iterations: float
    short_per_iteration_us: float
    long_per_iteration_us: float

    @property
    def ratio(self) -> float:
        """``long_ms / short_ms`` (linear growth: at most ``long / short``)."""
        return self.long_ms / self.short_ms

    @property
    def iteration_ratio(self) -> float:
        return self.long_iterations / self.short_iterations

    @property
    def per_iteration_ratio(self) -> float:
        return self.long_per_iteration_us / self.short_per_iteration_us


def _recorded_steps(n_obstacles: int, horizon: int, n_samples: int, steps: int, seed: int,
                    family: str) -> list[StepData]:
    """The grid point's recorded steps as the back ends take them (zero input reference)."""
    rng = np.random.default_rng([seed, n_obstacles, horizon, n_samples])
    instances = make_scaling_instances(steps, n_obstacles, horizon, n_samples, rng,
                                       family=family)
    shapes = [Disc(RADIUS)] * n_obstacles
    zero = np.zeros((horizon, 2))
    recorded = []
    for instance in instances:
        hs = safe_halfspaces(instance.reference_states[1:, :2], instance.samples,
                             ego_shape=Disc(RADIUS), obstacle_shapes=shapes, risk="dr_cvar",
                             ego_velocity=instance.x0[2:])
        recorded.append(StepData(instance.x0, instance.reference_states[1:], zero,
                                 np.asarray(hs.normals), np.asarray(hs.offsets)))
    return recorded


def _solvers(n_obstacles: int, horizon: int) -> dict[str, object]:
    from filters.mpc.backends.clarabel import ClarabelBackend
    from filters.mpc.backends.piqp import PIQPBackend
    from filters.mpc.backends.riccati import RiccatiBackend

    A, B, C = double_integrator()
    hard = MPCSafetyFilter(A, B, C, **filter_kwargs(horizon, n_obstacles)).problem
    recovery = hard.with_soft_rows({"halfspaces", "bounds"})
    return {"clarabel": ClarabelBackend(hard), "piqp": PIQPBackend(hard),
            "riccati": RiccatiBackend(recovery)}


def benchmark_growth(
    n_obstacles: int, n_samples: int, *, short: int = 20, long: int = 80, steps: int = 100,
    repeats: int = 2, seed: int = 0, family: str = "straight",
) -> list[GrowthRatio]:
    """Solve the recorded QPs of horizons ``short`` and ``long`` alternately; one
    :class:`GrowthRatio` per back end of :data:`BACKENDS`.

    Raises
    ------
    InvalidParameterError
        If ``short >= long``, or ``steps`` or ``repeats`` is below 1.
    """
    if not 1 <= short < long:
        raise InvalidParameterError(f"need 1 <= short < long, got short={short}, long={long}")
    if steps < 1 or repeats < 1:
        raise InvalidParameterError(f"steps and repeats must be >= 1, got {steps}, {repeats}")
    horizons = (short, long)
    recorded = {T: _recorded_steps(n_obstacles, T, n_samples, steps, seed, family)
                for T in horizons}
    solvers = {T: _solvers(n_obstacles, T) for T in horizons}
    for T in horizons:  # first calls: numba loads the kernel, the solvers set up
        for solver in solvers[T].values():
            solver.solve(recorded[T][0])
    samples: dict[tuple[str, int], list[tuple[float, int]]] = {
        (name, T): [] for name in BACKENDS for T in horizons}
    count = min(len(recorded[short]), len(recorded[long]))
    for _ in range(repeats):
        for index in range(count):
            for name in BACKENDS:
                for T in horizons:  # one step of each horizon in turn
                    begin = time.thread_time()
                    solution = solvers[T][name].solve(recorded[T][index])
                    samples[name, T].append((1e3 * (time.thread_time() - begin),
                                             max(int(solution.iterations), 1)))
    ratios = []
    for name, qp in BACKENDS.items():
        medians = {}
        for T in horizons:
            table = np.array(samples[name, T], dtype=float)
            medians[T] = (float(np.median(table[:, 0])), float(np.median(table[:, 1])),
                          float(np.median(1e3 * table[:, 0] / table[:, 1])))
        ratios.append(GrowthRatio(name, qp, n_obstacles, n_samples, short, long,
                                  medians[short][0], medians[long][0], medians[short][1],
                                  medians[long][1], medians[short][2], medians[long][2]))
    return ratios


def format_growth(ratios: list[GrowthRatio]) -> str:
    """One line per back end: medians (and ranges) of the ratios over the measured
    obstacle counts x N_s."""
    if not ratios:
        return "sparse back ends' growth, interleaved: needs two horizons >= 20"
    short, long = ratios[0].short, ratios[0].long
    combos = {(r.n_obstacles, r.n_samples) for r in ratios}

    def spread(values: list[float]) -> str:
        array = np.array(values)
        return f"{np.median(array):.2f}x (range {array.min():.2f}x to {array.max():.2f}x)"

    lines = [f"sparse back ends' growth, the QPs of T = {short} and T = {long} solved "
             f"alternately (CPU time of the thread; linear growth: at most "
             f"{long / short:.0f}x), medians over {len(combos)} obstacle counts x N_s:"]
    for name, qp in BACKENDS.items():
        mine = [r for r in ratios if r.backend == name]
        lines.append(
            f"  {name} ({qp} QP): time {spread([r.ratio for r in mine])}; iterations "
            f"{spread([r.iteration_ratio for r in mine])}, per iteration "
            f"{spread([r.per_iteration_ratio for r in mine])}")
    return "\n".join(lines)

"""Safe-halfspace computation times: the paper's Table I, and ours.

Setup of Example 1 (Safaoui & Summers, Sec. II-C): ego reference
:math:`y^r = (-0.9, -0.8)`, nominal obstacle :math:`p = (0.5, 0)`, margin
:math:`r = 0.6` m (two discs of radius 0.3 m), samples from
:math:`\\mathcal{N}(p, 0.01 I)`, :math:`\\alpha = 0.2`, :math:`\\delta = 0.1`,
:math:`\\epsilon = 0.05`. For each sample count a fresh CVXPY problem is built
and solved (Clarabel) ``repeats`` times with new samples, and we report CVXPY's
compilation ("setup"), the solver's solve time and the wall-clock time of
``problem.solve`` ("call"), in milliseconds, next to the paper's Table I (ECOS,
2023 hardware). Our :func:`filters.halfspaces.safe_halfspaces` is timed for one
obstacle at one step and for 3 obstacles x 10 steps in one call.

Part of the paper's reproduction (:func:`agents.experiments.reproduce.reproduce`, through
:func:`halfspace_timing_table`); ``safe-nav bench`` prints it too. Usage::

    from agents.experiments.table_one import benchmark_table_one, format_table_one
    print(format_table_one(benchmark_table_one()))
"""

from __future__ import annotations

import math
import timeit
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from filters.constants import ALPHA, DELTA, EPSILON
from filters.geometry import Disc
from filters.halfspaces import safe_halfspaces
from safe_nav_env.constants import N_SAMPLES, OBSTACLE_RADIUS

__all__ = ["EXAMPLE_ONE", "PAPER_TABLE_ONE", "CvxpyTiming", "OurTiming", "TableOneResult",
    "benchmark_table_one", "format_table_one", "halfspace_timing_table"]

#: The paper's Table I: mean (solve, call) times in ms, keyed by (risk, N_s); CVXPY + ECOS
#: on a Xeon E3-1535M.
PAPER_TABLE_ONE: dict[tuple[str, int], tuple[float, float]] = {
    ("cvar", 50): (0.144, 2.23),
    ("cvar", 500): (1.91, 4.32),
    ("cvar", 1500): (5.98, 8.95),
    ("dr_cvar", 50): (0.236, 9.10),
    ("dr_cvar", 500): (2.58, 73.4),
    ("dr_cvar", 1500): (8.53, 216.0),
}

EXAMPLE_ONE = dict(reference=(-0.9, -0.8), obstacle=(0.5, 0.0), radius=OBSTACLE_RADIUS,
                   n_samples=N_SAMPLES, variance=0.01, alpha=ALPHA, delta=DELTA,
                   epsilons=(EPSILON, 0.1, 0.2))
"""Example 1 of the paper (Sec. II-C): ego reference, nominal obstacle position (m), disc
radius (m), samples of N(obstacle, variance I), and the risk parameters."""

_Y_REF = np.array(EXAMPLE_ONE["reference"])
_OBSTACLE = np.array(EXAMPLE_ONE["obstacle"])
_STD = math.sqrt(EXAMPLE_ONE["variance"])  # m: samples of N(p, 0.01 I)
_GRID = (3, 10)  # obstacles x steps


@dataclass(frozen=True)
class CvxpyTiming:
    """CVXPY times for one (risk, N_s) cell, in milliseconds.

    ``*_mean`` and ``*_median`` are over the repeats; ``paper_solve`` and
    ``paper_call`` are the paper's Table I means (NaN when the paper has no entry).
    """

    risk: str
    n_samples: int
    setup_mean: float
    setup_median: float
    solve_mean: float
    solve_median: float
    call_mean: float
    call_median: float
    paper_solve: float
    paper_call: float


@dataclass(frozen=True)
class OurTiming:
    """Median wall-clock times of :func:`safe_halfspaces`, in microseconds.

    ``speedup`` is CVXPY's mean call time for ONE halfspace divided by our time for
    all 3 x 10 halfspaces; ``speedup_same_work`` compares the same 30 halfspaces
    (30 CVXPY calls against one of ours).
    """

    risk: str
    n_samples: int
    one_halfspace_us: float
    grid_us: float
    speedup: float
    speedup_same_work: float


@dataclass(frozen=True)
class TableOneResult:
    """Result of :func:`benchmark_table_one`."""

    cvxpy: tuple[CvxpyTiming, ...]
    ours: tuple[OurTiming, ...]
    formulation: str
    repeats: int
    seed: int


def _time_cvxpy(
    rng: np.random.Generator, risk: str, n_samples: int, repeats: int, formulation: str
) -> CvxpyTiming:
    from filters.halfspace_cvxpy import time_cvxpy_halfspace

    normal = (_OBSTACLE - _Y_REF) / np.linalg.norm(_OBSTACLE - _Y_REF)
    times = 1e3 * np.array([
        time_cvxpy_halfspace(rng.normal(_OBSTACLE, _STD, size=(n_samples, 2)), normal,
                             2 * OBSTACLE_RADIUS, risk, alpha=ALPHA, delta=DELTA,
                             epsilon=EPSILON, formulation=formulation)
        for _ in range(repeats)])
    cells = np.stack([times.mean(axis=0), np.median(times, axis=0)], axis=1).ravel()  # (mean,
    return CvxpyTiming(risk, n_samples, *cells,  # median) of setup, solve, call
                       *PAPER_TABLE_ONE.get((risk, n_samples), (np.nan, np.nan)))


def _median_call_us(call: Callable[[], object], budget_s: float = 0.2) -> float:
    """Median wall-clock time of ``call()`` in microseconds, over batches within ``budget_s``."""
    call()  # warm-up
    timer = timeit.Timer(call)
    once = max(timer.timeit(1), 1e-7)
    number = max(1, int(0.01 / once))
    samples = timer.repeat(max(5, min(50, int(budget_s / (once * number)))), number)
    return float(np.median(samples)) / number * 1e6


def _time_ours(
    rng: np.random.Generator, risk: str, n_samples: int, cvxpy_call_ms: float
) -> OurTiming:
    n_obstacles, horizon = _GRID
    disc = Disc(OBSTACLE_RADIUS)
    options = dict(risk=risk, alpha=ALPHA, delta=DELTA, epsilon=EPSILON, ego_shape=disc)
    single = rng.normal(_OBSTACLE, _STD, size=(1, n_samples, 1, 2))
    grid = rng.normal(_OBSTACLE, _STD, size=(n_obstacles, n_samples, horizon, 2))
    y_one, y_grid = _Y_REF[None], np.tile(_Y_REF, (horizon, 1))
    one = _median_call_us(lambda: safe_halfspaces(y_one, single, obstacle_shapes=[disc], **options))
    shapes = [disc] * n_obstacles
    full = _median_call_us(lambda: safe_halfspaces(y_grid, grid, obstacle_shapes=shapes, **options))
    per_call = cvxpy_call_ms * 1e3 / full
    return OurTiming(risk, n_samples, one, full, per_call, per_call * n_obstacles * horizon)


def benchmark_table_one(sample_counts: Sequence[int] = (50, 500, 1500), repeats: int = 20,
                        seed: int = 0, *, risks: Sequence[str] = ("cvar", "dr_cvar"),
                        formulation: str = "vectorized") -> TableOneResult:
    """Reproduce the paper's Table I and time :func:`safe_halfspaces` on the same setup.

    Parameters
    ----------
    sample_counts
        Numbers of samples :math:`N_s`.
    repeats
        Fresh CVXPY problems per (risk, :math:`N_s`) (the paper used 500). With the
        default ``"vectorized"`` formulation the whole run takes a few seconds.
    seed
        Seed of the single :func:`numpy.random.default_rng` all samples come from.
    risks
        Risk metrics, among ``"mean"``, ``"cvar"``, ``"dr_cvar"``.
    formulation
        CVXPY formulation, ``"vectorized"`` or ``"paper"`` (eq. (6) per sample, as the
        authors' code; about 4 s per DR-CVaR problem at :math:`N_s = 1500` here,
        so use few repeats).

    Returns
    -------
    TableOneResult
        CVXPY timings (ms) with the paper's numbers alongside, and ours (µs) with the
        speed-up ratios.

    Raises
    ------
    InvalidParameterError
        For an unknown risk or formulation.
    """
    rng = np.random.default_rng(seed)
    cvxpy_rows, our_rows = [], []
    for risk in risks:
        for n_samples in sample_counts:
            row = _time_cvxpy(rng, risk, int(n_samples), repeats, formulation)
            cvxpy_rows.append(row)
            our_rows.append(_time_ours(rng, risk, int(n_samples), row.call_mean))
    return TableOneResult(tuple(cvxpy_rows), tuple(our_rows), formulation, repeats, seed)


def format_table_one(result: TableOneResult) -> str:
    """Plain-text rendering of :func:`benchmark_table_one`'s result."""
    lines = [
        f"Table I: one safe halfspace with CVXPY ({result.formulation}) + Clarabel, "
        f"ms, mean / median over {result.repeats} fresh problems (seed {result.seed})",
        f"{'risk':<8}{'N_s':>6}{'setup':>20}{'solve':>20}{'call':>20}"
        f"{'paper solve':>13}{'paper call':>12}",
    ]
    for row in result.cvxpy:
        cells = "".join(f"{getattr(row, key + '_mean'):.3g} / {getattr(row, key + '_median'):.3g}"
                        .rjust(20) for key in ("setup", "solve", "call"))
        lines.append(f"{row.risk:<8}{row.n_samples:>6}{cells}"
                     f"{row.paper_solve:>13.3g}{row.paper_call:>12.3g}")
    lines += [
        "",
        "Ours: safe_halfspaces, median wall-clock µs (one call)",
        f"{'risk':<8}{'N_s':>6}{'1 x 1':>10}{'3 x 10':>10}"
        f"{'CVXPY call / ours(3x10)':>26}{'30 calls / ours(3x10)':>24}",
    ]
    lines += [f"{row.risk:<8}{row.n_samples:>6}{row.one_halfspace_us:>10.1f}{row.grid_us:>10.1f}"
              f"{row.speedup:>25.0f}x{row.speedup_same_work:>23.0f}x" for row in result.ours]
    return "\n".join(lines)


def halfspace_timing_table(
    sample_counts: Sequence[int] = (50, 500, 1500), repeats: int = 100, seed: int = 0
) -> dict:
    """Table I as nested dicts (ms): ``cvxpy[risk][N_s] = {setup, solve, call}`` (means)
    and ``ours[N_s]`` = our DR-CVaR time for one halfspace; ``result`` is the raw
    :class:`TableOneResult`."""
    result = benchmark_table_one(sample_counts, repeats, seed)
    cvxpy: dict[str, dict[int, dict[str, float]]] = {}
    for row in result.cvxpy:
        cvxpy.setdefault(row.risk, {})[row.n_samples] = {
            "setup": row.setup_mean, "solve": row.solve_mean, "call": row.call_mean}
    ours = {row.n_samples: row.one_halfspace_us / 1e3 for row in result.ours
            if row.risk == "dr_cvar"}
    return {"cvxpy": cvxpy, "ours": ours, "result": result}

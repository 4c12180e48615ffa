"""Plot the safe-RL comparison: collision rate against time to goal, per scenario.

Reads the per-episode CSVs that ``safe-nav evaluate --risks none dr_cvar`` wrote for
each policy and draws one panel per scenario with a point per (policy, filtered or
not): the collision rate (continuous time, Wilson 95 % interval) against the mean time
to goal over the episodes that reached it (:func:`agents.experiments.pareto.plot_pareto`).

Usage (the README's comparison, 300 episodes per cell)::

    S="HeadOn Overtaking Intersection MultiObstacle RandomCrossing"
    safe-nav evaluate --scenarios $S --risks none dr_cvar --output results/ppo
    safe-nav evaluate --scenarios $S --risks none dr_cvar --output results/lagrangian \\
        --policy agents/pretrained/ppo_lagrangian.zip
    safe-nav evaluate --scenarios $S --risks none dr_cvar --output results/in_loop \\
        --policy agents/pretrained/ppo_dr_cvar_in_loop.zip
    python scripts/plot_safe_rl.py --run PPO=results/ppo \\
        --run PPO-Lagrangian=results/lagrangian \\
        --run "PPO (filter in the loop)"=results/in_loop --output safe_rl.png

Only the ``none`` and ``dr_cvar`` rows are drawn (a run may hold more risks).
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

from agents.evaluation.records import read_records
from agents.evaluation.summary import summarise
from agents.experiments.pareto import ParetoPoint, plot_pareto, point_from_summary

_FILTERS = {"none": "", "dr_cvar": " + DR-CVaR filter"}


def _run(text: str) -> tuple[str, Path]:
    label, sep, folder = text.partition("=")
    if not sep or not label or not folder:
        raise argparse.ArgumentTypeError(f"expected LABEL=FOLDER, got {text!r}")
    csv = Path(folder) / "episodes.csv"
    if not csv.is_file():
        raise argparse.ArgumentTypeError(f"no episodes.csv in {folder!r}")
    return label, csv


def panels(runs: list[tuple[str, Path]]) -> dict[str, list[ParetoPoint]]:
    """``{scenario: points}``: a point per policy x filter."""
    out: dict[str, list[ParetoPoint]] = defaultdict(list)
    for label, csv in runs:
        for row in summarise(read_records(csv)):
            if row.risk not in _FILTERS or row.method != row.risk:
                continue
            point = point_from_summary(row, label + _FILTERS[row.risk])
            if point is not None:
                out[row.scenario].append(point)
    return dict(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", type=_run, action="append", required=True,
                        metavar="LABEL=FOLDER", help="a policy's evaluate output folder")
    parser.add_argument("--output", type=Path, default=Path("safe_rl_pareto.png"))
    args = parser.parse_args(argv)
    data = panels(args.run)
    if not data:
        parser.error("no 'none' or 'dr_cvar' rows in the given runs")
    path = plot_pareto(data, args.output, columns=3,
                       title="Safe RL: collision rate against time to goal")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

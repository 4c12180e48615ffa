"""Print every speed benchmark of safe-nav (same as ``safe-nav bench``).

(a) the paper's Table I: CVaR / DR-CVaR halfspaces with CVXPY against ours;
(b) one filter step (3 obstacles, T = 10, N_s = 100: halfspaces + QP) against the
    same QP in CVXPY built once with Parameters;
(c) the unfiltered environment's steps per second per scenario.

Usage: ``python scripts/benchmark.py [--steps 500] [--repeats 100]``
"""

from __future__ import annotations

import sys

from agents.cli.main import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))

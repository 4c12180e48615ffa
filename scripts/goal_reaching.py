"""Does a PPO planner reach its goal from near it? Unfiltered, no obstacles.

See :mod:`agents.experiments.goal_reaching`.

    python scripts/goal_reaching.py                      # the shipped policy, 120 starts at rest
    python scripts/goal_reaching.py --policy my_ppo.zip --max-speed 3

Prints the goals reached out of the starts, at rest 0.4-1.2 m from six goals (the
paper's two, two of RandomCrossing's, the centre and a corner), and with ``--max-speed``
moving in a uniform direction.
"""

from __future__ import annotations

import argparse
import sys

from agents.experiments.goal_reaching import goal_reaching
from agents.training.ppo import load_ppo


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", default=None, help="PPO .zip (default: the shipped one)")
    parser.add_argument("--starts", type=int, default=120)
    parser.add_argument("--low", type=float, default=0.4, help="closest start to the goal, m")
    parser.add_argument("--high", type=float, default=1.2, help="farthest start, m")
    parser.add_argument("--max-speed", type=float, default=0.0,
                        help="initial speed U(0, max) in m/s in a uniform direction (0: at rest)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    result = goal_reaching(load_ppo(args.policy), starts=args.starts,
                           distance=(args.low, args.high), max_speed=args.max_speed,
                           seed=args.seed)
    print(f"goal reached from {result.reached} of {result.starts} starts "
          f"({100 * result.rate:.1f} %), mean {result.mean_steps:.1f} steps")
    for goal, start in result.misses[:10]:
        print(f"  missed: goal {goal}, start {tuple(round(v, 2) for v in start)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

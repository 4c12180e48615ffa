"""Median time per ``rgb_array`` frame of the environment's renderer, in ms.

Renders filtered episodes (the DR-CVaR wrapper draws its halfspaces through the
render hooks) and times ``env.render()`` alone::

    python scripts/benchmark_render.py --frames 100
"""

from __future__ import annotations

import argparse
import sys
import time

import gymnasium as gym
import numpy as np

import safe_nav_env  # noqa: F401  (registers the ids)
from filters import SafetyFilterWrapper

SCENARIOS = ("SafeNav/HeadOn-v0", "SafeNav/MultiObstacle-v0", "SafeNav/RandomCrossing-v0")


def time_frames(
    env_id: str, frames: int, *, risk: str = "dr_cvar", seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Wall and CPU (this process) seconds per ``render()`` call over ``frames`` steps.

    Episodes restart as needed. On a shared machine the CPU time is the steadier number.
    """
    env = SafetyFilterWrapper(gym.make(env_id, render_mode="rgb_array"), risk=risk)
    env.reset(seed=seed)
    env.render()  # the first frame of a layout draws and caches the static scene
    times, cpu = np.empty(frames), np.empty(frames)
    for k in range(frames):
        _, _, terminated, truncated, _ = env.step(np.zeros(2))
        if terminated or truncated:
            env.reset(seed=seed + k + 1)
        start, start_cpu = time.perf_counter(), time.process_time()
        frame = env.render()
        times[k] = time.perf_counter() - start
        cpu[k] = time.process_time() - start_cpu
    assert frame.shape == (600, 600, 3) and frame.dtype == np.uint8
    env.close()
    return times, cpu


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--risk", default="dr_cvar", help="'none': no render hooks")
    args = parser.parse_args(argv)
    for env_id in SCENARIOS:
        wall, cpu = (t * 1e3 for t in time_frames(env_id, args.frames, risk=args.risk))
        print(f"{env_id:28s} median {np.median(wall):5.2f} ms (CPU {np.median(cpu):5.2f} ms)  "
              f"p90 {np.percentile(wall, 90):5.2f} ms  max {wall.max():6.2f} ms  "
              f"({args.frames} frames, risk={args.risk})")
    return 0


if __name__ == "__main__":
    sys.exit(main())

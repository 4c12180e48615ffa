"""The environment's speed: steps per second of each scenario, and time per rendered frame."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from benchmarks.timing import clock, clock_cpu, drive, median
from safe_nav_env.registration import ENV_IDS, SCENE_IDS

RENDERED = ("SafeNav/HeadOn-v0", "SafeNav/MultiObstacle-v0", "SafeNav/RandomCrossing-v0")
"""Scenarios :func:`render_frames` times."""


def steps_per_second(env_id: str, *, n_steps: int = 5000, repeats: int = 5, seed: int = 0,
                     **make_kwargs: object) -> float:
    """Median over ``repeats`` runs of the ``gym.make(env_id, **make_kwargs)`` steps per second.

    Each run resets with ``seed`` and steps ``n_steps`` times with pre-drawn uniform
    random accelerations, resetting when an episode ends (resets are counted in the
    time). Rendering is off.
    """
    env = gym.make(env_id, **make_kwargs)
    high = env.action_space.high
    actions = np.random.default_rng(seed).uniform(
        -high, high, size=(n_steps, *env.action_space.shape)).astype(np.float32)
    env.reset(seed=seed)
    env.step(actions[0])  # the passive checker inspects the first step only

    def run() -> None:
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()

    rates = []
    for _ in range(repeats):
        env.reset(seed=seed)
        rates.append(1e3 * n_steps / clock(run)[1])
    env.close()
    return median(rates)


def normal_draws_per_second(*, size: int = 6000, repeats: int = 5, seed: int = 0) -> float:
    """Median rate of ``numpy`` standard normal draws, in draws/s: a machine reference.

    Each MultiObstacle step draws ``3 x 100 x 10 x 2 = 6000`` prediction normals, the
    irreducible part of the step, so this rate bounds what the environment can reach.
    """
    rng = np.random.default_rng(seed)

    def draw() -> None:
        for _ in range(200):
            rng.standard_normal(size)

    return median(2e5 * size / clock(draw)[1] for _ in range(repeats))


def benchmark(*, n_steps: int = 5000, repeats: int = 5, seed: int = 0,
              **make_kwargs: object) -> dict[str, float]:
    """Steps per second (median of ``repeats``) of every registered id except
    ``SafeNav/Custom-v0``, the scene environments (recorded pedestrians, the crowd) with
    their default options included. See :func:`steps_per_second`."""
    ids = [i for i in ENV_IDS if i != "SafeNav/Custom-v0"] + list(SCENE_IDS)
    return {env_id: steps_per_second(env_id, n_steps=n_steps, repeats=repeats, seed=seed,
                                     **make_kwargs) for env_id in ids}


def render_frames(frames: int = 100, *, seed: int = 0) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Wall and CPU (this process) ms of each ``render()`` of :data:`RENDERED`, by id.

    DR-CVaR filtered episodes (the wrapper draws its halfspaces through the render hooks)
    under zero actions, restarting with ``seed + 1``, ... as needed; the first frame,
    which draws and caches the static scene, is not timed. On a shared machine the CPU
    time is the steadier one.
    """
    from filters import SafetyFilterWrapper

    times = {}
    for env_id in RENDERED:
        env = SafetyFilterWrapper(gym.make(env_id, render_mode="rgb_array"), risk="dr_cvar")
        env.reset(seed=seed)
        env.render()
        rows = [clock_cpu(env.render)[1:] for _ in drive(env, frames, seed,
                                                          lambda obs, new: np.zeros(2))]
        env.close()
        times[env_id] = tuple(np.array(rows).T)
    return times

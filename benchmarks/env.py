"""Steps per second of the unfiltered environment, per scenario."""

from __future__ import annotations

import statistics
import time
from collections.abc import Iterable

import gymnasium as gym
import numpy as np

from safe_nav_env.registration import ENV_IDS, SCENE_IDS


def steps_per_second(
    env_id: str,
    *,
    n_steps: int = 5000,
    repeats: int = 5,
    seed: int = 0,
    raw: bool = False,
    **make_kwargs: object,
) -> float:
    """Median over ``repeats`` runs of the environment steps per second.

    Each run resets with ``seed`` and steps ``n_steps`` times with pre-drawn uniform
    random accelerations, resetting when an episode ends (resets are counted in
    the time). Rendering is off.

    Parameters
    ----------
    env_id
        A registered id, e.g. ``"SafeNav/MultiObstacle-v0"``.
    n_steps, repeats
        Steps per timed run and number of runs.
    seed
        Seed of the environment and of the actions.
    raw
        Time ``env.unwrapped`` instead of the ``gym.make`` wrapper stack.
    make_kwargs
        Passed to :func:`gymnasium.make` (e.g. ``n_samples``, ``horizon``).
    """
    env = gym.make(env_id, **make_kwargs)
    target = env.unwrapped if raw else env
    rng = np.random.default_rng(seed)
    high = env.action_space.high
    actions = rng.uniform(-high, high, size=(n_steps, *env.action_space.shape)).astype(np.float32)
    rates = []
    target.reset(seed=seed)
    target.step(actions[0])  # the passive checker inspects the first step only
    for _ in range(repeats):
        target.reset(seed=seed)
        start = time.perf_counter()
        for action in actions:
            _, _, terminated, truncated, _ = target.step(action)
            if terminated or truncated:
                target.reset()
        rates.append(n_steps / (time.perf_counter() - start))
    env.close()
    return statistics.median(rates)


def normal_draws_per_second(*, size: int = 6000, repeats: int = 5, seed: int = 0) -> float:
    """Median rate of ``numpy`` standard normal draws, in draws/s: a machine reference.

    Each MultiObstacle step draws ``3 x 100 x 10 x 2 = 6000`` prediction normals, the
    irreducible part of the step, so this rate bounds what the environment can reach.
    """
    rng = np.random.default_rng(seed)
    rates = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(200):
            rng.standard_normal(size)
        rates.append(200 * size / (time.perf_counter() - start))
    return statistics.median(rates)


def benchmark(
    env_ids: Iterable[str] | None = None,
    *,
    n_steps: int = 5000,
    repeats: int = 5,
    seed: int = 0,
    raw: bool = False,
    **make_kwargs: object,
) -> dict[str, float]:
    """Steps per second (median of ``repeats``) for each id; default: every registered id
    except ``SafeNav/Custom-v0``, the scene environments (recorded pedestrians, the crowd)
    with their default options included. See :func:`steps_per_second`."""
    ids = ([i for i in ENV_IDS if i != "SafeNav/Custom-v0"] + list(SCENE_IDS)
           if env_ids is None else list(env_ids))
    return {
        env_id: steps_per_second(env_id, n_steps=n_steps, repeats=repeats, seed=seed, raw=raw,
                                 **make_kwargs)
        for env_id in ids
    }

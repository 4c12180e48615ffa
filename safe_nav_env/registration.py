"""Registration of the ``SafeNav/...`` environment ids with Gymnasium."""

from __future__ import annotations

import gymnasium as gym

ENTRY_POINT = "safe_nav_env.env:SafeNavEnv"

ENV_IDS: dict[str, str | None] = {
    "SafeNav/HeadOn-v0": "head_on",
    "SafeNav/Overtaking-v0": "overtaking",
    "SafeNav/Intersection-v0": "intersection",
    "SafeNav/MultiObstacle-v0": "multi_obstacle",
    "SafeNav/RandomCrossing-v0": "random_crossing",
    "SafeNav/Custom-v0": None,
}
"""Registered ids and the scenario each uses (``None``: pass ``scenario=`` to ``gym.make``)."""


def register_envs() -> None:
    """Register every id of :data:`ENV_IDS` (ids already registered are left alone).

    The time limit is the environment's own (``episode_length``), so no
    ``max_episode_steps`` is registered; ``gym.make(..., max_episode_steps=n)``
    can still shorten episodes with a :class:`gymnasium.wrappers.TimeLimit`.
    """
    for env_id, scenario in ENV_IDS.items():
        if env_id in gym.registry:
            continue
        kwargs = {} if scenario is None else {"scenario": scenario}
        gym.register(id=env_id, entry_point=ENTRY_POINT, kwargs=kwargs)

"""Registration of the ``SafeNav/...`` environment ids with Gymnasium."""

from __future__ import annotations

import gymnasium as gym

from safe_nav_env.scenarios import CUSTOM, SCENARIO_NAMES, SCENES, env_id

ENTRY_POINT = "safe_nav_env.env:SafeNavEnv"

ENV_IDS: dict[str, str | None] = {
    env_id(name): (None if name == CUSTOM else name) for name in SCENARIO_NAMES
    if name not in SCENES
}
"""Registered ids and the scenario each uses (``None``: pass ``scenario=`` to ``gym.make``).

The scenario's name is the id's: ``"SafeNav/HeadOn-v0"`` runs ``SCENARIOS["HeadOn"]``."""

SCENE_IDS: dict[str, str] = {env_id(name): entry for name, entry in SCENES.items()}
"""Ids of the environments with scenes of their own (:data:`~safe_nav_env.scenarios.SCENES`)
and their entry points."""


PEDESTRIANS_ID = env_id("Pedestrians")
"""Id of the recorded-pedestrians environment (:mod:`safe_nav_env.pedestrians`), option
``scene=`` (default ``"eth"``)."""


def register_envs() -> None:
    """Register every id of :data:`ENV_IDS` and :data:`SCENE_IDS` (ids already registered
    are left alone).

    The time limit is the environment's own (``episode_length``), so no
    ``max_episode_steps`` is registered; ``gym.make(..., max_episode_steps=n)``
    can still shorten episodes with a :class:`gymnasium.wrappers.TimeLimit`.
    """
    entries = [(i, ENTRY_POINT, {} if s is None else {"scenario": s}) for i, s in ENV_IDS.items()]
    for env_id_, entry_point, kwargs in entries + [(i, e, {}) for i, e in SCENE_IDS.items()]:
        if env_id_ not in gym.registry:  # scenes load at gym.make, not here
            gym.register(id=env_id_, entry_point=entry_point, kwargs=kwargs)

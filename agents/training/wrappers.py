"""Wrappers for learners: episode cost for ``Monitor``, and a normalised action view.

:class:`SafetyTally` is the one per-episode tally (collision, cost, success, mean
intervention, filter statuses): :class:`EpisodeCostInfo` closes each episode with it, and
the callbacks of :mod:`agents.training.callbacks` count rollouts and evaluations with it.

The stack :func:`agents.training.ppo.make_training_env` builds, inside out::

    gym.make(id)                 physical units: accelerations in m/s², box [-10, 10]²
    SafetyFilterWrapper          (optional) the filter, in physical units
    EpisodeCostInfo              puts "episode_cost", ... into the episode's last info
    Monitor(info_keywords=EPISODE_INFO_KEYS)   logs them with the return and the length
    NormalisedActions            the learner's view: actions in [-1, 1]²

:class:`NormalisedActions` sits *outside* the filter, so the filter still reads and
writes physical accelerations; only the learner sees ``[-1, 1]`` (what
Stable-Baselines3's ``check_env`` asks for). Policies trained on the physical box
(the shipped one) still load and act: :func:`is_normalised_policy` tells the two
apart from the policy's action space, and :class:`PhysicalUnitsPolicy` turns a
normalised policy's answers back into m/s² where a physical action is needed (the
filter's policy roll-out reference).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from filters._validation import finite_scalar
from filters.errors import InvalidParameterError, InvalidTypeError
from filters.mpc.result import FilterStatus
from filters.report import PASSTHROUGH

EPISODE_INFO_KEYS = ("episode_cost", "episode_collision", "episode_intervention")
"""Keys :class:`EpisodeCostInfo` adds to the last info of an episode (pass them to
``Monitor(info_keywords=...)``)."""


class EpisodeCostInfo(gym.Wrapper):
    """Sum ``info["cost"]`` over each episode and report it in the episode's last info.

    At the step that ends an episode (``terminated or truncated``) the info gets

    ``episode_cost``
        :math:`\\sum_t c_t`, the sum of ``info["cost"]`` over the episode's steps (with
        the environment's collision indicator: the number of steps in collision).
    ``episode_collision``
        Whether any step had ``info["collision"]`` (the environment reports it in
        continuous time: the exact minimum clearance over each step).
    ``episode_intervention``
        Mean of ``info["filter"].intervention`` over the steps, in m/s², where a
        safety filter reports one; 0.0 without a filter.

    so that ``Monitor(env, info_keywords=EPISODE_INFO_KEYS)`` writes them next to the
    episode's return.

    Raises
    ------
    InvalidParameterError
        (From :meth:`step`.) If ``info["cost"]`` is NaN or infinite.
    """

    def reset(self, **kwargs: Any):  # gymnasium refuses a step before the first reset
        self._tally = SafetyTally(1)
        return self.env.reset(**kwargs)

    def step(self, action: Any):
        obs, reward, terminated, truncated, info = self.env.step(action)
        finite_scalar("info['cost']", info.get("cost", 0.0))
        episode = self._tally.step(0, info, terminated or truncated)
        if episode is not None:
            info.update(episode_cost=episode.cost, episode_collision=episode.collision,
                        episode_intervention=episode.intervention)
        return obs, reward, terminated, truncated, info


FILTER_STATUSES = (*(status.value for status in FilterStatus), PASSTHROUGH)
"""Filter statuses always logged (share 0 when absent), so the CSV columns are fixed;
any other status seen is logged too."""


@dataclass(frozen=True)
class EpisodeSafety:
    """What one finished episode did.

    Attributes
    ----------
    collision
        Some step had ``info["collision"]``.
    cost
        Sum of ``info["cost"]`` over the steps.
    success
        ``info["is_success"]`` at the last step.
    steps
        Episode length in steps.
    intervention
        Mean filter intervention over the episode's filtered steps, m/s² (0 without filter).
    """

    collision: bool
    cost: float
    success: bool
    steps: int
    intervention: float


class SafetyTally:
    """Per-environment accumulators over steps, closed into :class:`EpisodeSafety` at ``done``.

    Parameters
    ----------
    n_envs
        Number of environments of the vector environment.
    """

    def __init__(self, n_envs: int) -> None:
        self.n_envs = int(n_envs)
        self._cost = np.zeros(self.n_envs)
        self._collision = np.zeros(self.n_envs, dtype=bool)
        self._steps = np.zeros(self.n_envs, dtype=int)
        self._intervention = np.zeros(self.n_envs)
        self._filtered = np.zeros(self.n_envs, dtype=int)
        self.clear_window()

    def clear_window(self) -> None:
        """Forget finished episodes and step counts (not the episodes in progress)."""
        self.episodes: list[EpisodeSafety] = []
        self.statuses = Counter()
        self.intervention_sum = 0.0
        self.filtered_steps = 0

    def step(self, index: int, info: dict[str, Any], done: bool) -> EpisodeSafety | None:
        """Add one step of environment ``index``; returns the episode if it ended."""
        self._cost[index] += float(info.get("cost", 0.0))
        self._collision[index] |= bool(info.get("collision", False))
        self._steps[index] += 1
        report = info.get("filter")
        if report is not None:
            value = float(report["intervention"])  # a FilterReport or a plain dict
            self._intervention[index] += value
            self._filtered[index] += 1
            self.intervention_sum += value
            self.filtered_steps += 1
            self.statuses[str(report["status"])] += 1
        if not done:
            return None
        filtered = self._filtered[index]
        episode = EpisodeSafety(
            collision=bool(self._collision[index]), cost=float(self._cost[index]),
            success=bool(info.get("is_success", False)), steps=int(self._steps[index]),
            intervention=float(self._intervention[index] / filtered) if filtered else 0.0,
        )
        self._cost[index], self._collision[index], self._steps[index] = 0.0, False, 0
        self._intervention[index], self._filtered[index] = 0.0, 0
        self.episodes.append(episode)
        return episode

    def metrics(self) -> dict[str, float]:
        """The numbers of the current window (see the module docstring), keys without prefix."""
        out: dict[str, float] = {"episodes": float(len(self.episodes))}
        if self.episodes:
            out["collision_rate"] = float(np.mean([e.collision for e in self.episodes]))
            out["episode_cost"] = float(np.mean([e.cost for e in self.episodes]))
            out["goal_rate"] = float(np.mean([e.success for e in self.episodes]))
        if self.filtered_steps:
            out["intervention"] = self.intervention_sum / self.filtered_steps
            for status in sorted(set(FILTER_STATUSES) | set(self.statuses)):
                out[f"status_{status}"] = self.statuses[status] / self.filtered_steps
        return out


def _box_map(space: spaces.Space, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Centre and half width (float64) of a finite Box."""
    if not isinstance(space, spaces.Box):
        raise InvalidTypeError(f"{what} must be a gymnasium Box, got {space!r}")
    low = np.asarray(space.low, dtype=np.float64)
    high = np.asarray(space.high, dtype=np.float64)
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high)) and np.all(high > low)):
        raise InvalidParameterError(
            f"{what} must have finite bounds with high > low, got low={low}, high={high}"
        )
    return 0.5 * (high + low), 0.5 * (high - low)


class NormalisedActions(gym.ActionWrapper):
    """The learner's view of a Box action space: actions in ``[-1, 1]``.

    .. math:: u = c + w \\odot a, \\qquad c = (u_{max} + u_{min})/2,\\quad
              w = (u_{max} - u_{min})/2,

    in float64. For the symmetric box ``[-10, 10]²`` of ``safe_nav_env``, c = 0 and
    w = 10, so the physical action is exactly ``10 * a`` (m/s²). Out-of-range actions
    are passed on (the environment and the filter clip to the physical box).
    Place it outside :class:`filters.SafetyFilterWrapper`, so the filter works in
    physical units.

    Raises
    ------
    InvalidTypeError, InvalidParameterError
        If the wrapped action space is not a Box with finite bounds.
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.centre, self.half_width = _box_map(env.action_space, "the action space")
        self.action_space = spaces.Box(-1.0, 1.0, shape=env.action_space.shape,
                                       dtype=np.float32)

    def action(self, action: Any) -> np.ndarray:
        """Physical action (float64) of the normalised ``action``."""
        return self.centre + self.half_width * np.asarray(action, dtype=np.float64)

    def normalise(self, action: Any) -> np.ndarray:
        """Inverse map: the normalised action (float64) of a physical ``action``."""
        return (np.asarray(action, dtype=np.float64) - self.centre) / self.half_width


def is_normalised_policy(policy: Any, physical_space: spaces.Space) -> bool:
    """Whether ``policy`` acts in ``[-1, 1]`` (True) or in ``physical_space`` (False).

    Decided from ``policy.action_space`` (every Stable-Baselines3 model has one);
    an object without one (e.g. :class:`agents.MPCReferencePlanner`) is taken to
    act in physical units.

    Raises
    ------
    InvalidTypeError
        If the policy's action space is neither ``[-1, 1]`` nor ``physical_space``.
    """
    space = getattr(policy, "action_space", None)
    if space is None:
        return False
    if not isinstance(space, spaces.Box) or space.shape != physical_space.shape:
        raise InvalidTypeError(
            f"the policy's action space {space!r} does not match the environment's "
            f"{physical_space!r}"
        )
    low, high = np.asarray(space.low, float), np.asarray(space.high, float)
    physical = np.array_equal(low, physical_space.low) and np.array_equal(high, physical_space.high)
    if physical or (np.all(low == -1.0) and np.all(high == 1.0)):
        return not physical
    raise InvalidTypeError(
        f"the policy acts in [{low}, {high}], neither [-1, 1] (normalised) nor the "
        f"environment's box [{physical_space.low}, {physical_space.high}]"
    )


class PhysicalUnitsPolicy:
    """A policy trained on :class:`NormalisedActions`, answering in physical units.

    ``predict`` returns ``c + w * a`` (float64, as :class:`NormalisedActions`), so the
    filter's policy roll-out reference (:class:`filters.references.PolicyRolloutReference`)
    gets accelerations in m/s².

    Parameters
    ----------
    policy
        Anything with Stable-Baselines3's ``predict``, acting in ``[-1, 1]``.
    physical_space
        The environment's Box action space.
    """

    def __init__(self, policy: Any, physical_space: spaces.Space) -> None:
        if not callable(getattr(policy, "predict", None)):
            raise InvalidTypeError(f"policy must have a predict method, got {policy!r}")
        self.policy = policy
        self.centre, self.half_width = _box_map(physical_space, "physical_space")
        self.action_space = physical_space

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = False) -> tuple[np.ndarray, Any]:
        action, state = self.policy.predict(observation, state=state,
                                            episode_start=episode_start,
                                            deterministic=deterministic)
        return self.centre + self.half_width * np.asarray(action, dtype=np.float64), state


def in_physical_units(policy: Any, physical_space: spaces.Space) -> Any:
    """``policy`` answering in ``physical_space``'s units: wrapped in
    :class:`PhysicalUnitsPolicy` if it acts in ``[-1, 1]`` (:func:`is_normalised_policy`),
    else ``policy`` itself."""
    return (PhysicalUnitsPolicy(policy, physical_space)
            if is_normalised_policy(policy, physical_space) else policy)


__all__ = [
    "EPISODE_INFO_KEYS", "FILTER_STATUSES", "EpisodeCostInfo", "EpisodeSafety", "NormalisedActions",
    "PhysicalUnitsPolicy", "SafetyTally", "in_physical_units", "is_normalised_policy",
]

"""Does a planner reach its goal from where a safety filter may leave it?

A filtered planner can end up near its goal at rest, or moving the wrong way (the
filter bent its approach, the arena rows braked it at a wall). :func:`goal_reaching`
starts the *unfiltered* policy from such states with no obstacle in the arena and
counts the goals reached: a property of the planner alone, the first thing to check
when a filtered evaluation misses goals.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from filters._validation import integer_at_least
from filters.errors import InvalidParameterError

GOALS: tuple[tuple[float, float], ...] = ((4.7, 0.0), (1.0, -3.0), (4.5, 2.0), (4.5, -2.0),
                                          (0.0, 0.0), (-3.0, 3.0))
"""Goals of the check, in m: the paper's two (HeadOn/Overtaking/MultiObstacle,
Intersection), two of RandomCrossing's (near a wall), the centre and a corner
region no training scenario uses."""


@dataclass(frozen=True)
class GoalReaching:
    """Counts of :func:`goal_reaching`.

    Attributes
    ----------
    reached, starts
        Goals reached, and starts run.
    mean_steps
        Mean steps to the goal over the starts that reached it (nan if none did).
    misses
        ``(goal, start state)`` of every start that missed, for tracing.
    """

    reached: int
    starts: int
    mean_steps: float
    misses: tuple[tuple[tuple[float, float], tuple[float, ...]], ...]

    @property
    def rate(self) -> float:
        """``reached / starts``."""
        return self.reached / self.starts


def goal_reaching(policy: Any, *, starts: int = 120, distance: tuple[float, float] = (0.4, 1.2),
                  max_speed: float = 0.0, seed: int = 0, episode_length: float = 8.0,
                  goals: tuple[tuple[float, float], ...] = GOALS) -> GoalReaching:
    """Run ``policy`` unfiltered from random starts near each goal, no obstacles; count arrivals.

    Start ``i`` uses goal ``goals[i % len(goals)]`` and a state drawn by
    :class:`safe_nav_env.starts.RandomStart` (always near the goal, at a distance
    :math:`U(\\text{distance})` in m, with a speed :math:`U(0, \\text{max\\_speed})` in a
    uniform direction; at rest when ``max_speed`` is 0), from the environment seeded
    ``seed + i``. An episode lasts ``episode_length`` s (the goal tolerance is the
    environment's, 0.3 m). The episodes run on the evaluation runner
    (:func:`agents.evaluation.runner.run_episode`, risk ``"none"``).

    Parameters
    ----------
    policy
        Anything with SB3's ``predict(obs, deterministic=True)``, acting in m/s² or in
        [-1, 1] (:func:`agents.training.wrappers.is_normalised_policy` tells them apart).

    Raises
    ------
    InvalidParameterError
        If ``starts < 1``, the distance range is not ``0 < low <= high``, a goal is not
        inside the arena, or an episode fails (the policy raises, or its action is not a
        finite 2-vector).
    """
    from agents.evaluation.records import EpisodeSpec
    from agents.evaluation.runner import run_episode
    from safe_nav_env import RandomStart, Scenario
    from safe_nav_env.errors import SafeNavEnvError

    integer_at_least("starts", starts)
    try:
        start = RandomStart(probability=1.0, near_goal=1.0, goal_distance=distance,
                            max_speed=max_speed, rest=1.0 if max_speed == 0 else 0.0,
                            clearance=0.0)
        scenarios = [Scenario(name="GoalReaching", ego_start=(0.0, 0.0), goal=goal,
                              episode_length=episode_length) for goal in goals]
    except SafeNavEnvError as exc:
        raise InvalidParameterError(str(exc)) from exc
    steps, misses = [], []
    for i in range(starts):
        scenario = scenarios[i % len(scenarios)]
        # The evaluation runner, unfiltered; a policy in [-1, 1] acts through NormalisedActions.
        record, trajectory = run_episode(
            EpisodeSpec(scenario="Custom", risk="none", seed=seed + i), policy=policy,
            record_trajectory=True, env_kwargs={"scenario": scenario, "random_start": start})
        if record.error:  # the runner records an episode's failure: here it is the policy's
            raise InvalidParameterError(f"policy {type(policy).__name__} failed from start {i} "
                                        f"(seed {seed + i}): {record.error.split(' | ')[0]}")
        if record.goal_reached:
            steps.append(record.steps)
        else:
            misses.append((scenario.goal, tuple(float(v) for v in trajectory.ego_states[0])))
    return GoalReaching(len(steps), starts, float(np.mean(steps)) if steps else float("nan"),
                        tuple(misses))


__all__ = ["GOALS", "GoalReaching", "goal_reaching"]

"""``SafeNav/Crowd-v0``: CrowdNav's circle crossing with the double-integrator ego.

The protocol of CrowdNav (Chen, Liu, Kreiss & Alahi, "Crowd-Robot Interaction:
Crowd-aware Robot Navigation with Attention-based Deep Reinforcement Learning",
ICRA 2019; code: github.com/vita-epfl/CrowdNav, ``crowd_nav/configs/env.config``):
five humans (radius 0.3 m, preferred speed 1 m/s) start on a circle of radius 4 m,
each at a uniform angle with a uniform offset in ``[-0.5, 0.5)`` m per axis, and walk
to the antipode of their start; a human is redrawn while it starts or ends within
``r_h + r + 0.2`` m of an agent placed before it (the robot first, at ``(0, -4)``
with goal ``(0, 4)``). Humans follow ORCA or the social force model and see the robot
or not (:mod:`safe_nav_env.crowd.humans`). An episode ends at the goal (success), at
the first collision, or after 25 s (timeout). Test case ``i`` is ``reset(seed=i)``.

Where this differs from CrowdNav: the robot is the paper's double integrator
(acceleration input, ``|u_i| <= 10`` m/s², sampling time 0.2 s) rather than a
holonomic robot that sets its velocity every 0.25 s; collisions are checked in
continuous time over each step; the humans' start offsets come from the episode's
seeded generator, so the 500 cases are not CrowdNav's draws.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from safe_nav_env.constants import EGO_RADIUS
from safe_nav_env.crowd.humans import HUMAN_POLICIES, make_humans
from safe_nav_env.crowd.model import CrowdModel
from safe_nav_env.env import SafeNavEnv
from safe_nav_env.errors import ConfigError
from safe_nav_env.options import _option
from safe_nav_env.scenarios import ObstacleSpec, Scenario, env_id

__all__ = ["CIRCLE_RADIUS", "DISCOMFORT_DISTANCE", "HUMAN_RADIUS", "HUMAN_SPEED", "N_HUMANS",
           "TIME_LIMIT", "CrowdEnv"]

N_HUMANS = 5
"""Humans in the scene (CrowdNav's ``human_num``)."""

CIRCLE_RADIUS = 4.0
"""Radius of the circle the humans and the robot start on, m."""

HUMAN_RADIUS = 0.3
"""Human disc radius, m."""

HUMAN_SPEED = 1.0
"""Preferred human speed, m/s; also the scale of the start offsets (±0.5 v_pref m)."""

DISCOMFORT_DISTANCE = 0.2
"""A step is uncomfortable when the ego comes within this clearance of a human, m."""

TIME_LIMIT = 25.0
"""Episode length, s."""

ROBOT_MAX_SPEED = 1.0
"""Default ego speed limit, m/s: CrowdNav's robot preferred speed (``v_pref = 1``)."""

_DRAWS = 1000  # start draws per human before giving up


class CrowdEnv(SafeNavEnv):
    """Reach the far side of a circle that five reactive humans cross (see the module docstring).

    The ego, observation (all humans in the slots), action, reward, continuous-time
    collisions, ``info`` keys and safety-filter attributes are
    :class:`~safe_nav_env.env.SafeNavEnv`'s; the obstacles are the humans
    (:class:`~safe_nav_env.crowd.model.CrowdModel`). ``info["discomfort"]`` is
    ``True`` when the sampled clearance to some human is below ``discomfort_distance``
    (CrowdNav counts those steps for its discomfort frequency).

    Parameters
    ----------
    human_policy
        ``"orca"`` (default, CrowdNav's) or ``"social_force"``.
    robot_visible
        Whether the humans react to the ego (default ``False``, CrowdNav's main table).
    n_humans, circle_radius, human_radius, human_speed, discomfort_distance
        See the module constants (m, m/s).
    predictor
        ``"environment"`` (default: each human's current velocity extrapolated, plus
        the prediction law, see :mod:`safe_nav_env.crowd.model`), ``"kalman"`` (a
        constant-velocity Kalman filter on the observed positions; about 5x slower
        per step) or a callable (:mod:`safe_nav_env.predictors`). All use the past only.
    **options
        The other :class:`~safe_nav_env.env.SafeNavEnv` options; ``episode_length``
        defaults to :data:`TIME_LIMIT`, ``max_speed`` to :data:`ROBOT_MAX_SPEED` (1 m/s)
        and ``terminate_on_collision`` to ``True``.

    Raises
    ------
    ConfigError
        For an unknown human policy or an invalid option.
    """

    _scene_id = env_id("Crowd")

    def __init__(self, *, human_policy: str = "orca", robot_visible: bool = False,
                 n_humans: int = N_HUMANS, circle_radius: float = CIRCLE_RADIUS,
                 human_radius: float = HUMAN_RADIUS, human_speed: float = HUMAN_SPEED,
                 discomfort_distance: float = DISCOMFORT_DISTANCE, predictor: Any = "environment",
                 **options: Any) -> None:
        if human_policy not in HUMAN_POLICIES:
            raise ConfigError(f"human_policy must be one of {HUMAN_POLICIES}, got "
                              f"{human_policy!r}")
        if "scenario" in options:
            raise ConfigError(f"scenario does not apply to {self._scene_id}: the scene is the "
                              "circle crossing (pass n_humans=, circle_radius=, ...)")
        self.human_policy = human_policy
        self.robot_visible = bool(robot_visible)
        self.n_humans = _option("n_humans", n_humans, low=1, integer=True)
        self.circle_radius = _option("circle_radius", circle_radius, strict=True)
        self.human_radius = _option("human_radius", human_radius, strict=True)
        self.human_speed = _option("human_speed", human_speed, strict=True)
        self.discomfort_distance = _option("discomfort_distance", discomfort_distance)
        options.setdefault("episode_length", TIME_LIMIT)
        options.setdefault("max_speed", ROBOT_MAX_SPEED)
        options.setdefault("terminate_on_collision", True)
        options.setdefault("max_obstacles", self.n_humans)
        super().__init__(scenario=self._draw_scenario, predictor=predictor, pad_info=False,
                         **options)

    def _draw_scenario(self, rng: np.random.Generator) -> Scenario:
        """The robot on the circle's bottom, the humans drawn as CrowdNav draws them."""
        r = self.circle_radius
        placed = [((0.0, -r), (0.0, r), EGO_RADIUS)]  # (start, goal, radius); the ego's: Scenario's
        for index in range(self.n_humans):
            for _ in range(_DRAWS):
                angle = rng.random() * 2.0 * math.pi
                offset = (rng.random(2) - 0.5) * self.human_speed
                start = np.array([r * math.cos(angle), r * math.sin(angle)]) + offset
                if all(min(math.dist(start, other), math.dist(start, goal))
                       >= self.human_radius + radius + self.discomfort_distance
                       for other, goal, radius in placed):
                    break
            else:
                raise ConfigError(f"no free start for human {index} on a circle of radius {r} m "
                                  f"in {_DRAWS} draws; use fewer humans or a larger circle")
            placed.append((tuple(start), tuple(-start), self.human_radius))
        bound = r + 2.0
        return Scenario(
            name="Crowd", ego_start=(0.0, -r, 0.0, 0.0), goal=(0.0, r),
            obstacles=tuple(ObstacleSpec(start=p, velocity=(0.0, 0.0), radius=self.human_radius)
                            for p, _, _ in placed[1:]),
            episode_length=TIME_LIMIT, arena=((-bound, -bound), (bound, bound)))

    def _obstacle_model(self, scenario: Scenario) -> CrowdModel:
        """The humans of ``scenario``, walking to the antipodes of their starts."""
        simulator = make_humans(self.human_policy, dt=self.dt, radius=self.human_radius,
                                preferred_speed=self.human_speed, robot_radius=scenario.ego_radius,
                                robot_visible=self.robot_visible)
        goals = [(-o.start[0], -o.start[1]) for o in scenario.obstacles]
        return CrowdModel(simulator, scenario.obstacles, goals, self.dt,
                          robot_state=lambda: self.ego_state)

    def _info(self, distances: np.ndarray, swept: np.ndarray,
              distance_to_goal: float) -> dict[str, Any]:
        info = super()._info(distances, swept, distance_to_goal)
        info["discomfort"] = info["min_distance_to_collision"] < self.discomfort_distance
        return info

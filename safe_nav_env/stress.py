"""The stress suite: encounters where the filter's model of the world is wrong in a known way.

Every risk formulation promises something *if* the predictions describe reality
(exactly, in law, in their first two moments, or up to a Wasserstein radius), and the
MPC assumes the ego is the double integrator it plans with. The stress suite breaks
these assumptions, one failure class at a time: each a named :class:`StressCase` of
(scenario, noise, predictor, environment options) in :data:`STRESS_SUITE`.

``"understated_1.5x"``, ``"understated_2x"``
    :data:`~safe_nav_env.scenarios.MULTI_OBSTACLE`; predictions ``N(0, 0.01 I)`` as in
    the paper, but the realised Laplace noise has 1.5 (2) times their standard
    deviation per axis (variance ``0.01 f²``, :func:`understated_noise`): the
    predictions understate the spread.
``"heavy_tail"``
    The head-on encounter; predictions ``N(0, 0.01 I)``, but the realised motion noise
    is Student-t with ``ν = 3`` (same covariance, the ``"student_t"`` preset of
    :mod:`safe_nav_env.noise`): rare large jumps.
``"biased"``
    The head-on encounter; the realised noise (Laplace, the paper's covariance) has a
    constant mean :data:`DRIFT` per step that the predictor does not know: the
    obstacle drifts by ``(-0.03, +0.03)`` m per 0.2 s step (0.21 m/s), towards the ego
    along the lane and across it. Along the lane the prediction error grows with the
    look-ahead (``k · 0.03`` m); across it the obstacle settles ``0.03`` m off its lane.
``"crossing5"``
    :data:`CROSSING5`: five obstacles crossing the ego's path, alternately upwards
    and downwards, timed to reach it as the ego would at its start speed
    (:func:`crossing_scenario`).
``"dense8"``
    :data:`DENSE8`: a dense crowd, eight such crossers 0.8 m apart.
``"fast"``
    :class:`FasterObstacles`: each episode one of the four paper scenes (HeadOn,
    Overtaking, Intersection, MultiObstacle, uniformly) with every obstacle's velocity
    multiplied by a factor drawn uniformly in ``[1.5, 2]``; the predictions know the
    new velocity (the scene is faster, not mispredicted).
``"turning"``
    :data:`TURNING`: two obstacles that each turn towards the ego's path with
    probability 0.5 per episode; the predictor samples both hypotheses (bimodal
    predictions, see :class:`~safe_nav_env.scenarios.ObstacleSpec`).
``"stopping"``
    :data:`STOPPING`: three crossers, each halting at a time drawn uniformly in
    ``[1, 4]`` s (``ObstacleSpec.stop_window``), possibly on the ego's path; the
    predictions keep the lane speed (the halt is never predicted).
``"lag"``, ``"drag"``
    MultiObstacle with ego actuation the filter does not model
    (:mod:`safe_nav_env.actuation`): a first-order actuator lag of :data:`ACTUATOR_LAG`
    s (the acceleration reaches 63 % of a command within one step), or a linear drag
    of :data:`DRAG` 1/s.
``"stale1"``, ``"stale2"``
    MultiObstacle with late predictions: a constant-velocity Kalman filter on the
    observed positions (:class:`~safe_nav_env.predictors.ConstantVelocityKalman`)
    whose output is one (two) steps old
    (:class:`~safe_nav_env.predictors.StalePredictor`): each predicted position lags
    the true motion by ``k`` steps. The Kalman filter is needed because the
    environment's own sampler predicts from the true current state.

Only the named assumption is broken; everything else is the paper's setting. Use a
case with::

    env = gym.make("SafeNav/Custom-v0", **STRESS_SUITE["stopping"].env_kwargs())

New scenarios are defined here rather than in :mod:`safe_nav_env.scenarios`, whose
names are canonical elsewhere.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from safe_nav_env.constants import EGO_START_SPEED, NOISE_VARIANCE
from safe_nav_env.errors import ScenarioError
from safe_nav_env.noise import NOISE_PRESETS, Laplace, NoiseModel
from safe_nav_env.options import _option
from safe_nav_env.predictors import Predictor, StalePredictor, resolve_predictor
from safe_nav_env.scenarios import (
    HEAD_ON,
    INTERSECTION,
    MULTI_OBSTACLE,
    OVERTAKING,
    ObstacleSpec,
    Scenario,
    _paper,
)

__all__ = ["ACTUATOR_LAG", "CROSSING5", "DENSE8", "DRAG", "DRIFT", "STOPPING", "STRESS_SUITE",
    "TURNING", "FasterObstacles", "StressCase", "crossing_scenario", "understated_noise"]


DRIFT: tuple[float, float] = (-0.03, 0.03)
"""Mean of the realised per-step noise in the ``"biased"`` case, m per step (x, y)."""

ACTUATOR_LAG = 0.2
"""Actuator time constant of the ``"lag"`` case, in s (one sampling period)."""

DRAG = 0.5
"""Linear drag coefficient of the ``"drag"`` case, in 1/s (1 m/s² at 2 m/s)."""


def understated_noise(factor: float) -> NoiseModel:
    """Predictions ``N(0, 0.01 I)``; realised Laplace noise with ``factor`` times their std.

    Parameters
    ----------
    factor
        Ratio of the realised to the predicted standard deviation per axis, ``>= 1``
        (1: the paper's noise).

    Raises
    ------
    ScenarioError
        If ``factor`` is not a finite number ``>= 1``.
    """
    factor = _option("factor", factor, low=1.0, error=ScenarioError)
    return NoiseModel(reality=Laplace(NOISE_VARIANCE * factor**2))  # the paper's predictions


TURNING = _paper(
    "turning", (-4.7, 0.0), (4.7, 0.0),
    # Heading -x above the path; may turn counter-clockwise (towards -y) by 45°.
    ObstacleSpec(start=(3.0, 1.2), velocity=(-1.0, 0.0), turn_rate=0.8,
                 turn_probability=0.5, turn_start=0.8, turn_angle=math.pi / 4),
    # Heading -x below the path; may turn clockwise (towards +y) by 45°.
    ObstacleSpec(start=(1.5, -1.4), velocity=(-1.0, 0.0), turn_rate=-0.8,
                 turn_probability=0.5, turn_start=0.4, turn_angle=math.pi / 4),
    duration=5.0)
"""Two obstacles that may turn (probability 0.5 each) into the ego's path: bimodal predictions."""


def crossing_scenario(name: str, xs: Sequence[float], *, speed: float = 0.8,
                      stop_window: tuple[float, float] | None = None, duration: float = 6.0,
                      episode_length: float = 10.0) -> Scenario:
    """Obstacles crossing the ego's path ``(-4.7, 0) -> (4.7, 0)`` at the given ``x``.

    Obstacle ``j`` moves vertically at ``speed`` (m/s), upwards for even ``j`` and
    downwards for odd ``j``, and starts ``speed · t_j`` m from the path, with ``t_j =
    (x_j + 4.7) / 1.5`` s the time an ego at its start speed (1.5 m/s) reaches ``x_j``:
    each crosser reaches the path when the ego would.

    Parameters
    ----------
    name
        The scenario's name.
    xs
        Where each obstacle crosses the path, in m, inside ``(-4.7, 4.7)``.
    speed
        Crossing speed, in m/s, ``> 0``.
    stop_window
        Every obstacle's ``stop_window`` (see :class:`~safe_nav_env.scenarios.ObstacleSpec`).
    duration, episode_length
        As :class:`~safe_nav_env.scenarios.Scenario`, in s.

    Raises
    ------
    ScenarioError
        If ``xs`` is empty or outside the path, or a value is invalid.
    """
    xs = [float(x) for x in xs]
    if not xs or not all(-4.7 < x < 4.7 for x in xs):
        raise ScenarioError(f"xs must be crossing points in (-4.7, 4.7) m, got {xs!r}")
    speed = _option("speed (m/s)", speed, strict=True, error=ScenarioError)
    specs = []
    for index, x in enumerate(xs):
        arrival = (x + 4.7) / EGO_START_SPEED  # when an ego at its start speed reaches x
        sign = 1.0 if index % 2 == 0 else -1.0  # upwards, downwards, ...
        specs.append(ObstacleSpec(start=(x, -sign * speed * arrival), velocity=(0.0, sign * speed),
                                  stop_window=stop_window))
    return Scenario(name=name, ego_start=(-4.7, 0.0, EGO_START_SPEED, 0.0), goal=(4.7, 0.0),
                    obstacles=tuple(specs), duration=duration, episode_length=episode_length)


CROSSING5 = crossing_scenario("crossing5", (-2.0, -1.0, 0.0, 1.0, 2.0))
"""Five obstacles crossing the ego's path at x = -2, -1, 0, 1, 2 m (0.8 m/s, alternating)."""

DENSE8 = crossing_scenario("dense8", tuple(np.round(np.linspace(-2.8, 2.8, 8), 6)))
"""A dense crowd: eight obstacles crossing at x = -2.8 .. 2.8 m, 0.8 m apart (0.8 m/s)."""

STOPPING = crossing_scenario("stopping", (-1.5, 0.5, 2.5), stop_window=(1.0, 4.0))
"""Three crossers that each halt at a random time in [1, 4] s, unpredicted."""


@dataclass(frozen=True)
class FasterObstacles:
    """A scenario family ``rng -> Scenario``: a scene with its obstacles sped up.

    Each call picks one of ``scenes`` uniformly and multiplies every obstacle's velocity
    by a factor drawn uniformly in ``[low, high]`` (the predictions follow the new
    velocity). Pass it as the environment's ``scenario``.

    Attributes
    ----------
    scenes
        The scenes to draw from (default: the four paper scenes).
    low, high
        The speed factor's range, ``0 < low <= high``.

    Raises
    ------
    ScenarioError
        If ``scenes`` is empty or the range is invalid.
    """

    scenes: tuple[Scenario, ...] = (HEAD_ON, OVERTAKING, INTERSECTION, MULTI_OBSTACLE)
    low: float = 1.5
    high: float = 2.0

    def __post_init__(self) -> None:
        if not self.scenes or not all(isinstance(s, Scenario) for s in self.scenes):
            raise ScenarioError(
                f"scenes must be a non-empty tuple of Scenario, got {self.scenes!r}")
        _option("high (>= low)", self.high,
                low=_option("low", self.low, strict=True, error=ScenarioError),
                error=ScenarioError)

    def __call__(self, rng: np.random.Generator) -> Scenario:
        """One episode's scene, drawn with ``rng``."""
        scene = self.scenes[int(rng.integers(len(self.scenes)))]
        factor = float(self.low + (self.high - self.low) * rng.random())
        obstacles = tuple(dataclasses.replace(o, velocity=(factor * o.velocity[0],
                                                           factor * o.velocity[1]))
                          for o in scene.obstacles)
        return dataclasses.replace(scene, name=f"{scene.name}_fast", obstacles=obstacles)


@dataclass(frozen=True)
class StressCase:
    """One stress case: a scenario, a noise model, a predictor and environment options.

    Attributes
    ----------
    name
        The key in :data:`STRESS_SUITE`.
    scenario
        The encounter, or a scenario family ``rng -> Scenario``.
    noise
        The noise model (prediction law, realised law, number of samples).
    predictor
        ``None`` (the environment's sampler), a predictor name or a callable; see
        :mod:`safe_nav_env.predictors`.
    description
        One line for tables and plots.
    env_options
        Further ``gym.make`` keywords (e.g. ``{"actuator_lag": 0.2}``).
    """

    name: str
    scenario: Any
    noise: NoiseModel
    predictor: Predictor | str | None = None
    description: str = ""
    env_options: Mapping[str, Any] = field(default_factory=dict)

    def env_kwargs(self) -> dict[str, Any]:
        """Keywords for ``gym.make("SafeNav/Custom-v0", **kwargs)`` / :class:`SafeNavEnv`.

        The predictor is a fresh object on each call (resolved from its name, or a deep
        copy): a stateful predictor is never shared between environments.
        """
        kwargs: dict[str, Any] = {"scenario": self.scenario, "noise": self.noise,
                                  **self.env_options}
        predictor = resolve_predictor(self.predictor) if isinstance(self.predictor, str) else (
            copy.deepcopy(self.predictor)
        )
        if predictor is not None:
            kwargs["predictor"] = predictor
        return kwargs


_PAPER_NOISE = NOISE_PRESETS["paper"]

STRESS_SUITE: dict[str, StressCase] = {case.name: case for case in (
    StressCase("understated_1.5x", MULTI_OBSTACLE, understated_noise(1.5),
               description="MultiObstacle, realised noise 1.5x the predicted std"),
    StressCase("understated_2x", MULTI_OBSTACLE, understated_noise(2.0),
               description="MultiObstacle, realised noise 2x the predicted std"),
    StressCase("heavy_tail", HEAD_ON, NOISE_PRESETS["student_t"],
               description="head-on, realised noise Student-t (nu = 3), predicted Gaussian"),
    StressCase("biased", HEAD_ON,
               NoiseModel(reality=Laplace(NOISE_VARIANCE, mean=DRIFT)),
               description="head-on, realised noise drifts (-0.03, 0.03) m per step, not "
               "predicted"),
    StressCase("crossing5", CROSSING5, _PAPER_NOISE,
               description="five obstacles crossing the path"),
    StressCase("dense8", DENSE8, _PAPER_NOISE,
               description="dense crowd: eight obstacles crossing the path"),
    StressCase("fast", FasterObstacles(), _PAPER_NOISE,
               description="a paper scene, obstacles 1.5-2x faster"),
    StressCase("turning", TURNING, _PAPER_NOISE,
               description="two obstacles may turn into the path (p = 0.5): bimodal predictions"),
    StressCase("stopping", STOPPING, _PAPER_NOISE,
               description="three crossers halt at a random time in [1, 4] s, unpredicted"),
    StressCase("lag", MULTI_OBSTACLE, _PAPER_NOISE, env_options={"actuator_lag": ACTUATOR_LAG},
               description=f"MultiObstacle, ego actuator lag tau = {ACTUATOR_LAG} s, not modelled"),
    StressCase("drag", MULTI_OBSTACLE, _PAPER_NOISE, env_options={"drag": DRAG},
               description=f"MultiObstacle, ego linear drag {DRAG} 1/s, not modelled"),
    StressCase("stale1", MULTI_OBSTACLE, _PAPER_NOISE, StalePredictor("kalman", delay=1),
               description="MultiObstacle, Kalman predictions one step late"),
    StressCase("stale2", MULTI_OBSTACLE, _PAPER_NOISE, StalePredictor("kalman", delay=2),
               description="MultiObstacle, Kalman predictions two steps late"),
)}
"""The stress suite by name (see the module docstring)."""

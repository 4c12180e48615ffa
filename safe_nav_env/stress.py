"""The stress suite: encounters where the predictions are wrong in a known way.

Every risk formulation promises something *if* the predictions describe reality
(exactly, in law, in their first two moments, or up to a Wasserstein radius). The
stress suite breaks that assumption in four documented ways, each a named
:class:`StressCase` of (scenario, noise, predictor) in :data:`STRESS_SUITE`:

``"heavy_tail"``
    The head-on encounter; predictions ``N(0, 0.01 I)`` as in the paper, but the
    realised motion noise is Student-t with ``ν = 3`` (same covariance, the
    ``"student_t"`` preset of :mod:`safe_nav_env.noise`): rare large jumps.
``"biased"``
    The head-on encounter; the realised noise (Laplace, the paper's covariance) has a
    constant mean :data:`DRIFT` per step that the predictor does not know: the
    obstacle drifts by ``(-0.03, +0.03)`` m per 0.2 s step (0.21 m/s), towards the ego
    along the lane and across it. Along the lane the prediction error grows with the
    look-ahead (``k · 0.03`` m); across it the obstacle settles ``0.03`` m off its lane.
``"turning"``
    :data:`TURNING`: two obstacles that each turn towards the ego's path with
    probability 0.5 per episode; the predictor samples both hypotheses (bimodal
    predictions, see :class:`~safe_nav_env.scenarios.ObstacleSpec`).
``"crossing5"``
    :data:`CROSSING5`: five obstacles crossing the ego's path, alternately upwards
    and downwards, timed to reach it as the ego would at its start speed.

All use the environment's own sampler as predictor (``predictor=None``), so the
mismatch is the one named. Use a case with::

    env = gym.make("SafeNav/Custom-v0", **STRESS_SUITE["biased"].env_kwargs())

New scenarios are defined here rather than in :mod:`safe_nav_env.scenarios`, whose
names are canonical elsewhere.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from safe_nav_env.constants import EGO_START_SPEED, N_SAMPLES
from safe_nav_env.noise import NOISE_PRESETS, Gaussian, Laplace, NoiseModel
from safe_nav_env.predictors import Predictor, resolve_predictor
from safe_nav_env.scenarios import HEAD_ON, ObstacleSpec, Scenario

__all__ = ["CROSSING5", "DRIFT", "STRESS_SUITE", "TURNING", "StressCase"]


DRIFT: tuple[float, float] = (-0.03, 0.03)
"""Mean of the realised per-step noise in the ``"biased"`` case, m per step (x, y)."""

TURNING = Scenario(
    name="turning",
    ego_start=(-4.7, 0.0, EGO_START_SPEED, 0.0),
    goal=(4.7, 0.0),
    obstacles=(
        # Heading -x above the path; may turn counter-clockwise (towards -y) by 45°.
        ObstacleSpec(start=(3.0, 1.2), velocity=(-1.0, 0.0), turn_rate=0.8,
                     turn_probability=0.5, turn_start=0.8, turn_angle=math.pi / 4),
        # Heading -x below the path; may turn clockwise (towards +y) by 45°.
        ObstacleSpec(start=(1.5, -1.4), velocity=(-1.0, 0.0), turn_rate=-0.8,
                     turn_probability=0.5, turn_start=0.4, turn_angle=math.pi / 4),
    ),
    duration=5.0,
    episode_length=8.0,
)
"""Two obstacles that may turn (probability 0.5 each) into the ego's path: bimodal predictions."""


def _crossers() -> tuple[ObstacleSpec, ...]:
    speed = 0.8  # m/s, vertical
    specs = []
    for index, x in enumerate((-2.0, -1.0, 0.0, 1.0, 2.0)):
        arrival = (x + 4.7) / EGO_START_SPEED  # when an ego at its start speed reaches x
        sign = 1.0 if index % 2 == 0 else -1.0  # upwards, downwards, ...
        specs.append(ObstacleSpec(start=(x, -sign * speed * arrival), velocity=(0.0, sign * speed)))
    return tuple(specs)


CROSSING5 = Scenario(
    name="crossing5",
    ego_start=(-4.7, 0.0, EGO_START_SPEED, 0.0),
    goal=(4.7, 0.0),
    obstacles=_crossers(),
    duration=6.0,
    episode_length=10.0,
)
"""Five obstacles crossing the ego's path at x = -2, -1, 0, 1, 2 m (0.8 m/s, alternating)."""


@dataclass(frozen=True)
class StressCase:
    """One stress case: a scenario, a noise model and a predictor.

    Attributes
    ----------
    name
        The key in :data:`STRESS_SUITE`.
    scenario
        The encounter.
    noise
        The noise model (prediction law, realised law, number of samples).
    predictor
        ``None`` (the environment's sampler), a predictor name or a callable; see
        :mod:`safe_nav_env.predictors`.
    description
        One line for tables and plots.
    """

    name: str
    scenario: Scenario
    noise: NoiseModel
    predictor: Predictor | str | None = None
    description: str = ""

    def env_kwargs(self) -> dict[str, Any]:
        """Keywords for ``gym.make("SafeNav/Custom-v0", **kwargs)`` / :class:`SafeNavEnv`.

        A predictor given by name is resolved to a fresh object on each call (a
        stateful predictor is never shared between environments).
        """
        kwargs: dict[str, Any] = {"scenario": self.scenario, "noise": self.noise}
        predictor = resolve_predictor(self.predictor) if isinstance(self.predictor, str) else (
            self.predictor
        )
        if predictor is not None:
            kwargs["predictor"] = predictor
        return kwargs


STRESS_SUITE: dict[str, StressCase] = {
    "heavy_tail": StressCase(
        "heavy_tail", HEAD_ON, NOISE_PRESETS["student_t"],
        description="head-on, realised noise Student-t (nu = 3), predicted Gaussian",
    ),
    "biased": StressCase(
        "biased", HEAD_ON,
        NoiseModel(Gaussian(0.01), Laplace(0.01, mean=DRIFT), n_samples=N_SAMPLES),
        description="head-on, realised noise drifts (-0.03, 0.03) m per step, not predicted",
    ),
    "turning": StressCase(
        "turning", TURNING, NOISE_PRESETS["paper"],
        description="two obstacles may turn into the path (p = 0.5): bimodal predictions",
    ),
    "crossing5": StressCase(
        "crossing5", CROSSING5, NOISE_PRESETS["paper"],
        description="five obstacles crossing the path",
    ),
}
"""The stress suite by name (see the module docstring)."""

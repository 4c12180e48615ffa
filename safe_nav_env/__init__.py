"""safe_nav_env: the Gymnasium environment of safe-nav.

A double-integrator robot must reach a goal among disc obstacles whose motion is
noisy and predicted by samples (Safaoui & Summers, ICRA 2024, Section IV-B).
Importing the package registers the ids ``SafeNav/HeadOn-v0``,
``SafeNav/Overtaking-v0``, ``SafeNav/Intersection-v0``,
``SafeNav/MultiObstacle-v0``, ``SafeNav/RandomCrossing-v0``,
``SafeNav/Custom-v0`` and ``SafeNav/Pedestrians-v0`` (recorded ETH/UCY pedestrians,
:mod:`safe_nav_env.pedestrians`, imported when such an environment is made)::

    import gymnasium as gym
    import safe_nav_env

    env = gym.make("SafeNav/HeadOn-v0", noise="authors_code")
    obs, info = env.reset(seed=0)
    info["predictions"].shape  # (n_obstacles, n_samples, horizon, 2)

matplotlib is imported only when rendering; torch, Stable-Baselines3 and
:mod:`filters` are never imported.
"""

from safe_nav_env.dynamics import double_integrator, single_integrator
from safe_nav_env.env import SafeNavEnv
from safe_nav_env.errors import ConfigError, InvalidActionError, SafeNavEnvError, ScenarioError
from safe_nav_env.noise import (
    NOISE_PRESETS,
    Gaussian,
    Laplace,
    NoiseModel,
    StudentT,
    resolve_noise,
)
from safe_nav_env.obstacles import ObstacleModel, distance_to_collision
from safe_nav_env.predictors import (
    ConstantVelocityKalman,
    Predictor,
    StalePredictor,
    resolve_predictor,
)
from safe_nav_env.registration import ENV_IDS, PEDESTRIANS_ID, register_envs
from safe_nav_env.scenarios import (
    HEAD_ON,
    INTERSECTION,
    MULTI_OBSTACLE,
    OVERTAKING,
    SCENARIO_NAMES,
    SCENARIOS,
    SCENES,
    ObstacleSpec,
    Scenario,
    ScenarioNameWarning,
    env_id,
    random_crossing,
    scenario_name,
)
from safe_nav_env.starts import RandomStart
from safe_nav_env.stress import STRESS_SUITE, StressCase

register_envs()

__all__ = ["ENV_IDS", "HEAD_ON", "INTERSECTION", "MULTI_OBSTACLE", "NOISE_PRESETS", "OVERTAKING",
    "PEDESTRIANS_ID", "SCENARIOS", "SCENARIO_NAMES", "SCENES", "STRESS_SUITE", "ConfigError",
    "ConstantVelocityKalman", "Gaussian", "InvalidActionError", "Laplace", "NoiseModel",
    "ObstacleModel", "ObstacleSpec", "Predictor", "RandomStart", "SafeNavEnv", "SafeNavEnvError",
    "Scenario", "ScenarioError", "ScenarioNameWarning", "StalePredictor", "StressCase", "StudentT",
    "distance_to_collision", "double_integrator", "env_id", "random_crossing", "register_envs",
    "resolve_noise", "scenario_name", "resolve_predictor", "single_integrator"]

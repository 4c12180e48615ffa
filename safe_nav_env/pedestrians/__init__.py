"""Recorded pedestrians: the ETH and UCY scenes as obstacles (``SafeNav/Pedestrians-v0``).

Six raw scenes ship as package data (``data/``, with their README and licence), as
redistributed by Trajectron++ (MIT): ``eth`` and ``hotel`` from the BIWI Walking
Pedestrians data set (ETH), ``zara1``, ``zara2``, ``students001`` and
``students003`` from UCY Crowds-by-Example. Cite both wherever results on them are
shown:

* S. Pellegrini, A. Ess, K. Schindler and L. van Gool, "You'll never walk alone:
  modeling social behavior for multi-target tracking", ICCV 2009.
* A. Lerner, Y. Chrysanthou and D. Lischinski, "Crowds by example", Computer
  Graphics Forum (Eurographics), 2007.

Modules, one job each:

* :mod:`~safe_nav_env.pedestrians.recording`: parse ``frame pedestrian_id x y``
  files, resample each track to ``dt`` inside its observed span;
* :mod:`~safe_nav_env.pedestrians.forecast`: nominal constant-velocity and Kalman
  forecasts from the past only;
* :mod:`~safe_nav_env.pedestrians.residuals`: residual banks measured on the other
  scenes (leave one scene out), sampling;
* :mod:`~safe_nav_env.pedestrians.replay`: the replayed obstacles, the ``K``
  nearest pedestrians in fixed slots;
* :mod:`~safe_nav_env.pedestrians.env`: :class:`PedestrianEnv`, registered as
  ``SafeNav/Pedestrians-v0``::

      import gymnasium as gym
      import safe_nav_env

      env = gym.make("SafeNav/Pedestrians-v0", scene="zara1", predictor="kalman")
      obs, info = env.reset(seed=0)
      info["predictions"].shape  # (8, 100, 10, 2)
"""

from safe_nav_env.pedestrians.env import (
    EGO_SPEED,
    MAX_PEDESTRIANS,
    PEDESTRIAN_RADIUS,
    PedestrianEnv,
    time_limit,
)
from safe_nav_env.pedestrians.forecast import FORECASTERS, Forecaster
from safe_nav_env.pedestrians.recording import (
    SCENES,
    Recording,
    RecordingError,
    load_recording,
    parse_tracks,
)
from safe_nav_env.pedestrians.replay import PARK_DISTANCE, ReplayModel
from safe_nav_env.pedestrians.residuals import ResidualBank, residual_bank

__all__ = ["EGO_SPEED", "FORECASTERS", "MAX_PEDESTRIANS", "PARK_DISTANCE", "PEDESTRIAN_RADIUS",
    "SCENES", "Forecaster", "PedestrianEnv", "Recording", "RecordingError", "ReplayModel",
    "ResidualBank", "load_recording", "parse_tracks", "residual_bank", "time_limit"]

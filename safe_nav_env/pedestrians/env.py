"""``SafeNav/Pedestrians-v0``: the double-integrator ego among recorded ETH/UCY pedestrians."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from safe_nav_env.constants import DT, EGO_RADIUS, EGO_START_SPEED, HORIZON, N_SAMPLES
from safe_nav_env.env import SafeNavEnv, _read_only
from safe_nav_env.errors import ConfigError, ScenarioError
from safe_nav_env.obstacles import ObstacleModel
from safe_nav_env.options import _option
from safe_nav_env.pedestrians.forecast import Forecaster
from safe_nav_env.pedestrians.recording import Recording, load_recording
from safe_nav_env.pedestrians.replay import ReplayModel
from safe_nav_env.pedestrians.residuals import residual_bank
from safe_nav_env.scenarios import Scenario, _arena, env_id

__all__ = ["EGO_SPEED", "MAX_PEDESTRIANS", "MIN_SEPARATION", "PEDESTRIAN_RADIUS", "START_CLEARANCE",
    "PedestrianEnv", "time_limit"]

MAX_PEDESTRIANS = 8
"""Default number of obstacle slots ``K``: the 8 pedestrians nearest the ego. In the
densest scenes (students, zara) 8 covers everyone within about 3 m most of the
time; the filter's QP grows linearly with ``K``."""

PEDESTRIAN_RADIUS = 0.3
"""Pedestrian disc radius, m (the paper's obstacle radius, CrowdNav's human radius)."""

EGO_SPEED = EGO_START_SPEED
"""Nominal ego speed, m/s (the paper's, 1.5; people walk at about 1.3 m/s)."""

MAX_SPEED = 2.0
"""Default ego speed limit, m/s: a walking-pace robot, above the nominal :data:`EGO_SPEED`."""

MIN_SEPARATION = 5.0
"""Least start-goal distance, m (capped at half the diagonal of a small box)."""

START_CLEARANCE = 0.5
"""Least free gap between the ego's start disc and any pedestrian disc at the start, m."""

_EDGE = 0.5  # start and goal stay this far inside the arena, m
_DRAWS = 1000  # start/goal/start-time draws before giving up


def time_limit(distance: float, speed: float = EGO_SPEED) -> float:
    """Episode length for a start-goal ``distance`` (m): ``1.5 d / v + 4`` s.

    The straight path at the nominal speed ``v``, 50 % more for detours around
    people, and 4 s to accelerate, brake and wait.
    """
    return 1.5 * distance / speed + 4.0


class PedestrianEnv(SafeNavEnv):
    """Reach a goal across a recorded ETH/UCY scene among the people who walked there.

    The ego, observation, action, reward, continuous-time collisions, ``info`` keys
    and safety-filter attributes are :class:`~safe_nav_env.env.SafeNavEnv`'s; the
    obstacles are replayed pedestrians (:class:`~safe_nav_env.pedestrians.replay.ReplayModel`):

    * **Obstacles**: at every step the ``max_obstacles`` pedestrians present nearest
      the ego (radius ``pedestrian_radius``), in fixed slots (a pedestrian keeps its
      slot while it stays among the nearest). Pedestrians follow the recording and do
      not react to the ego: a collision while the ego stands still still counts.
      Free slots are absent: zeros with flag 0 in the observation; in ``info``
      ``obstacle_present`` is ``False`` and their rows are infinitely far (``inf``
      positions, predictions and distances, zero velocity), as in padded scenes; on
      ``env.unwrapped`` (what a safety filter reads) they sit at rest at a parking
      point 100 m beyond the arena, so every array keeps ``max_obstacles`` finite rows.
    * **Episode** (all from the seed): a start step in the recording, an ego start
      (at rest) and a goal uniform in the arena (0.5 m inside its edges), at least
      :data:`MIN_SEPARATION` m apart, the start at least :data:`START_CLEARANCE` m
      clear of every pedestrian present at the start step. The time limit is
      :func:`time_limit` of the start-goal distance (``1.5 d / 1.5 m/s + 4`` s, 9-24 s
      in the packaged scenes), and the start step is drawn so the episode ends
      inside the recording when it is long enough.
    * **Arena** (``position_bounds``): the scene's walkable box, the 2 %-98 %
      quantiles per axis of all recorded positions (a static map of the scene).
    * **Predictions** (``info["predictions"]``, ``(K, N_s, T, 2)``): the nominal
      ``predictor`` (``"constant_velocity"``, the last observed velocity, or
      ``"kalman"``) on each pedestrian's positions at steps ``<= t`` (its last
      ``history_steps``, including before the episode started), plus whole residual
      trajectories drawn with :attr:`np_random` from those measured on the *other*
      packaged scenes (all six for a file path); see
      :mod:`safe_nav_env.pedestrians.residuals`. ``obstacle_velocities`` are the
      predictor's velocity estimates (past only).
    * **Extra info**: ``obstacle_present`` (K,), ``pedestrian_index`` (K,) (index in
      :attr:`recording`, -1 for an absent slot), ``recording_step``, ``scene``. The same
      indices are :attr:`obstacle_ids` on ``env.unwrapped``: a safety filter's online
      calibration pairs each prediction with its own pedestrian's realised position
      through them, also when a slot passes to another pedestrian.

    Parameters
    ----------
    scene
        A packaged scene name (``"eth"``, ``"hotel"``, ``"zara1"``, ``"zara2"``,
        ``"students001"``, ``"students003"``), a path to a tab-separated
        ``frame pedestrian_id x y`` file (metres, 0.04 s per frame number), or a
        :class:`~safe_nav_env.pedestrians.recording.Recording` at ``dt``.
    predictor
        ``"constant_velocity"`` (default) or ``"kalman"``.
    max_obstacles
        Obstacle slots ``K`` (default :data:`MAX_PEDESTRIANS`), ``>= 1``.
    n_samples
        Prediction samples per obstacle (default 100).
    horizon
        Prediction horizon ``T`` in steps (default 10).
    dt
        Sampling time, s (default 0.2).
    history_steps
        Longest window of past positions the predictor uses, steps (default 8).
    pedestrian_radius
        Pedestrian disc radius, m (default 0.3).
    ego_speed
        Nominal ego speed, m/s, used for the time limit (default 1.5).
    arena
        ``((x_min, y_min), (x_max, y_max))`` in m; default the scene's walkable box.
        The box is the scene's map, computed once from the whole recording; it is no
        input of the predictions, but it does fix where starts and goals are drawn, so
        comparing two recordings episode for episode needs the same ``arena``.
    **options
        The other :class:`~safe_nav_env.env.SafeNavEnv` options (``render_mode``,
        ``episode_length``, ``max_acceleration``, ``max_speed`` (default
        :data:`MAX_SPEED`, 2 m/s), reward weights, ``goal_tolerance``,
        ``terminate_on_collision``); ``scenario``, ``noise``, ``predictor`` names of the
        base class, ``pad_info`` and ``random_start`` do not apply.

    Raises
    ------
    ConfigError
        For an unknown scene, a missing file or an invalid option.
    RecordingError
        For an empty or malformed file (the message names the line).
    """

    _scene_id = env_id("Pedestrians")

    def __init__(self, scene: str | Path | Recording = "eth", *,
                 predictor: str = "constant_velocity", max_obstacles: int = MAX_PEDESTRIANS,
                 n_samples: int = N_SAMPLES, horizon: int = HORIZON, dt: float = DT,
                 history_steps: int = 8, pedestrian_radius: float = PEDESTRIAN_RADIUS,
                 ego_speed: float = EGO_SPEED,
                 arena: tuple[tuple[float, float], tuple[float, float]] | None = None,
                 **options: Any) -> None:
        unsupported = sorted({"scenario", "noise", "pad_info", "random_start"} & set(options))
        if unsupported:
            raise ConfigError(
                f"{unsupported} do not apply to {self._scene_id} (the scene is the "
                "recording: pass scene=..., predictor=...)"
            )
        options.setdefault("max_speed", MAX_SPEED)
        dt = _option("dt", dt, strict=True)
        max_obstacles = _option("max_obstacles", max_obstacles, low=1, integer=True)
        self.pedestrian_radius = _option("pedestrian_radius", pedestrian_radius, strict=True)
        self.ego_speed = _option("ego_speed", ego_speed, strict=True)
        if isinstance(scene, Recording) and not math.isclose(scene.dt, dt):
            raise ConfigError(f"the recording is at dt={scene.dt} s, the environment at {dt}")
        self.recording: Recording = (scene if isinstance(scene, Recording)
                                     else load_recording(scene, dt=dt))
        self.scene: str = self.recording.name
        self.forecaster = Forecaster(predictor, dt, history_steps)
        self.arena = (self.recording.walkable_box() if arena is None
                      else _arena(arena, error=ConfigError))
        self._start_step: int | None = None
        super().__init__(  # validates horizon; the first scenario is drawn at reset
            scenario=self._draw_scenario, n_samples=n_samples, horizon=horizon, dt=dt,
            max_obstacles=max_obstacles, pad_info=False, predictor=None, **options,
        )
        self.residuals = residual_bank(self.scene, self.forecaster, self.horizon)
        self._replay = ReplayModel(
            self.recording, self.forecaster, self.residuals, max_obstacles=max_obstacles,
            radius=self.pedestrian_radius, arena=self.arena,
            ego_position=lambda: self.ego_state[:2],
        )

    # ----------------------------------------------------------------- episode

    def _draw_scenario(self, rng: np.random.Generator) -> Scenario:
        """Draw the start step, ego start and goal of an episode (see the class docstring)."""
        low, high = (np.asarray(corner) for corner in self.arena)
        inner_low, inner_high = low + _EDGE, high - _EDGE
        if np.any(inner_low >= inner_high):
            inner_low = inner_high = 0.5 * (low + high)
        separation = min(MIN_SEPARATION, 0.5 * float(np.hypot(*(inner_high - inner_low))))
        clearance = EGO_RADIUS + self.pedestrian_radius + START_CLEARANCE
        for _ in range(_DRAWS):
            start = rng.uniform(inner_low, inner_high)
            goal = rng.uniform(inner_low, inner_high)
            distance = float(np.hypot(*(goal - start)))
            if distance < separation:
                continue
            limit = time_limit(distance, self.ego_speed)
            steps = math.ceil(limit / self.dt - 1e-9)
            start_step = self._start_step
            if start_step is None:
                start_step = int(rng.integers(0, max(0, self.recording.n_steps - 1 - steps) + 1))
            _, people = self._replay.pedestrians_at(start_step)
            if people.shape[0]:
                gaps = np.hypot(*(people - start).T)
                if gaps.min() < clearance:
                    continue
            break
        else:
            raise ScenarioError(
                f"scene {self.scene!r}: no ego start {clearance} m clear of the pedestrians "
                f"and a goal {separation} m away in {_DRAWS} draws"
            )
        self._replay.start_step = start_step
        return Scenario(
            name=f"Pedestrians:{Path(self.scene).stem}",
            ego_start=(float(start[0]), float(start[1]), 0.0, 0.0),
            goal=(float(goal[0]), float(goal[1])),
            episode_length=limit,
            arena=self.arena,
        )

    def _load(self, scenario: Scenario | None) -> None:
        if scenario is None:  # before the first reset: no obstacle, but the scene's arena
            centre = tuple(0.5 * (np.asarray(self.arena[0]) + np.asarray(self.arena[1])))
            scenario = Scenario(name="unset", ego_start=centre, goal=centre, arena=self.arena)
        super()._load(scenario)

    def _obstacle_model(self, scenario: Scenario) -> ReplayModel | ObstacleModel:
        """The replay (the placeholder's empty model before :attr:`_replay` exists)."""
        return getattr(self, "_replay", None) or super()._obstacle_model(scenario)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode (see the class docstring).

        Parameters
        ----------
        seed
            Seeds :attr:`np_random`, the only source of randomness.
        options
            ``{"start_step": j}`` starts this episode at recording step ``j`` (the
            ego start and goal are still drawn; the start is clear of the people
            present at ``j``); default: drawn from the seed.

        Raises
        ------
        ConfigError
            If ``options`` asks for another scenario or holds a bad ``start_step``.
        """
        options = dict(options or {})
        start_step = options.pop("start_step", None)
        self._start_step = None if start_step is None else _option(
            "options['start_step'] (a recording step)", start_step, integer=True,
            high=self.recording.n_steps - 1)
        return super().reset(seed=seed, options=options or None)

    @property
    def obstacle_ids(self) -> np.ndarray | None:
        """The pedestrian in each slot (index in :attr:`recording`; -1: absent), ``(K,)``.

        ``None`` before the first reset. Read by
        :meth:`filters.calibration.OnlineCalibration.update` (``ids=``).
        """
        if self._model is not self._replay:
            return None
        return _read_only(self._replay.slots.copy())

    def _info(self, distances: np.ndarray, swept: np.ndarray,
              distance_to_goal: float) -> dict[str, Any]:
        info = super()._info(distances, swept, distance_to_goal)  # empty slots masked there
        info["pedestrian_index"] = self.obstacle_ids
        info["recording_step"] = self._replay.step_index
        info["scene"] = self.scene
        return info

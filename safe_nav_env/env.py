"""The Gymnasium environment: a double-integrator robot among noisy moving discs."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from safe_nav_env.actuation import Actuation, resolve_actuation
from safe_nav_env.collision import swept_clearance
from safe_nav_env.constants import DT, HORIZON, MAX_ACCELERATION, MAX_SPEED
from safe_nav_env.dynamics import applied_acceleration, double_integrator, parse_action
from safe_nav_env.errors import ConfigError, ScenarioError
from safe_nav_env.info import _padded
from safe_nav_env.noise import NoiseModel, resolve_noise
from safe_nav_env.obstacles import ObstacleModel
from safe_nav_env.options import _option
from safe_nav_env.predictors import Predictor, check_predictions, resolve_predictor
from safe_nav_env.scenarios import Scenario, ScenarioFactory, _resolve_scenario
from safe_nav_env.starts import RandomStart, resolve_random_start

_EGO_SIZE = 6  # ego position, ego velocity, goal - ego position
_SLOT_SIZE = 5  # relative position, relative velocity, present flag
_BIG = float(np.finfo(np.float32).max)


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


class SafeNavEnv(gym.Env[np.ndarray, np.ndarray]):
    """Reach a goal with a double-integrator robot among noisy moving disc obstacles.

    The setting of Safaoui & Summers (ICRA 2024), Section IV-B. The ego robot is
    the double integrator ``x_{t+1} = A x_t + B u_t``, ``y_t = C x_t`` with state
    ``x = [p_x, p_y, v_x, v_y]`` and sampling time ``T_s = dt`` (0.2 s); see
    :func:`~safe_nav_env.dynamics.double_integrator`. Obstacles are discs moving
    as single integrators along their lanes with noise; every step the environment
    also draws ``n_samples`` predicted trajectories per obstacle over the next
    ``horizon`` steps (see :mod:`safe_nav_env.obstacles`).

    **Action**: the acceleration ``u`` in m/s², a float32
    ``Box(-max_acceleration, max_acceleration, (2,))`` (default ±10 m/s² per axis,
    ample for the paper's manoeuvres). Actions outside the box are clipped. **Speed
    limit** ``||v||_2 <= max_speed`` (5 m/s): an action whose next velocity leaves that
    disc is replaced by the closest one that keeps it (the velocity projected onto the
    disc, within the box: :func:`~safe_nav_env.dynamics.applied_acceleration`).

    **Observation**: a float32 vector of length ``6 + 5 * max_obstacles`` (26 by default)::

        [0:2]   ego position p, in m
        [2:4]   ego velocity v, in m/s
        [4:6]   goal - p, in m
        then for each slot k = 0 .. max_obstacles - 1, at 6 + 5k:
        [+0:+2] obstacle position - p, in m
        [+2:+4] obstacle nominal velocity - v, in m/s
        [+4]    1.0 if the slot holds an obstacle, else 0.0 (and the slot is all zeros)

    Obstacles fill the slots nearest first (by centre distance to the ego); when a
    scenario has more than ``max_obstacles`` obstacles the farthest are left out of
    the observation (they still move, collide and appear in ``info``). The space's
    bounds are ±float32 max (flags in ``[0, 1]``; the ego velocity in
    ``[-max_speed, max_speed]``): positions are not clipped.

    **Reward** (every weight is a constructor option, so a ``gym.make`` keyword)::

        r = progress_weight * (||p_t - g|| - ||p_{t+1} - g||)      progress, per m
            + arrival_bonus            if ||p_{t+1} - g|| <= goal_tolerance
            - control_cost_weight * ||u||²      u: the (clipped) action, in m/s²
            - collision_penalty        on a collision in the step (continuous time, below)
            - time_penalty

    The defaults (1.0, 10.0, 1e-3, 1.0, 0.0; tolerance 0.3 m) make the plain policy
    goal-driven rather than safe: a collision costs little. Safe-RL code should use
    ``info["cost"]`` instead.

    **Episode end**: ``terminated`` when the ego reaches the goal (``is_success``), or
    on a collision if ``terminate_on_collision``; ``truncated`` after
    ``ceil(episode_length / dt)`` steps. The ego may leave the arena; that is
    recorded in ``info["out_of_bounds"]``, not enforced (the arena bound is a
    constraint for the safety filter).

    **Info** (after reset and every step), ``n`` obstacles, ``N_s`` samples, ``T`` steps:

    ``predictions`` (n, N_s, T, 2)
        Prediction samples for steps ``t+1 .. t+T``, drawn from the current state.
    ``obstacle_positions``, ``obstacle_velocities`` (n, 2)
        Current positions (m) and nominal velocities (m/s).
    ``distance_to_collision`` (n,)
        ``||y - p_i|| - r_A - r_O,i`` at the sample instant, in m (``<= 0``: overlap).
    ``min_distance_to_collision``
        Its minimum (``inf`` without obstacles).
    ``swept_distance_to_collision`` (n,), ``min_swept_distance_to_collision``
        The exact minimum clearance over the step just taken, in continuous time: the
        ego on its constant-acceleration arc ``p + s v + s²/2 u``, each obstacle on the
        chord between its realised positions, ``s`` in ``[0, dt]``
        (:func:`~safe_nav_env.collision.swept_clearance`). Never larger than the
        sampled clearance; after :meth:`reset` it equals it.
    ``collision``, ``cost``
        ``True`` / ``1.0`` when some swept clearance is ``<= 0`` (touching counts): a
        collision anywhere in the step, between the samples too. Else ``False`` /
        ``0.0``. This drives the reward, ``cost`` and ``terminate_on_collision``.
    ``sampled_collision``
        ``True`` when some clearance at the sample instant is ``<= 0`` (the paper's
        sampled statistic; it implies ``collision``).
    ``is_success``, ``distance_to_goal``, ``ego_state``, ``out_of_bounds``, ``time``
        Goal reached; ``||y - g||`` in m; ``x`` (4,); ego outside the arena; time in s.
    ``acceleration`` (2,)
        The input applied over the last step (the action clipped to the box and the
        speed limit), in m/s²; zeros after :meth:`reset`.

    With ``pad_info`` the per-obstacle entries have ``max_obstacles`` rows and
    ``info["obstacle_present"]`` marks the real ones; absent obstacles are
    infinitely far (``inf`` positions, predictions and distances, zero velocity).
    Gymnasium's vector environments stack info arrays, so they need one shape even
    when the obstacle count changes between episodes. An obstacle model whose rows are
    slots that may be empty (:attr:`~safe_nav_env.obstacles.ObstacleModel.present`, the
    recorded pedestrians') has its empty rows masked the same way, also without
    ``pad_info``, and left out of the observation. The arrays in ``info`` are
    read-only.

    **Safety-filter interface** (the :class:`filters.protocol.FilterableEnv`
    protocol, on ``env.unwrapped``): :attr:`dt`, :attr:`dynamics`, :attr:`ego_state`,
    :attr:`ego_radius`, :attr:`obstacle_radii`, :attr:`obstacle_positions`,
    :attr:`obstacle_velocities`, :attr:`predictions`, :attr:`input_bounds`,
    :attr:`position_bounds`, :attr:`goal`, :attr:`render_hooks`, :meth:`observe`; and
    :attr:`max_speed` and :meth:`applied_input`, for the filter's speed limit.
    They describe the current episode once :meth:`reset` has been called.

    Parameters
    ----------
    scenario
        A :class:`~safe_nav_env.scenarios.Scenario`, a name in
        :data:`~safe_nav_env.scenarios.SCENARIOS`, a mapping of Scenario fields, or a
        function ``rng -> Scenario`` called at each reset with :attr:`np_random`.
    render_mode
        ``None``, ``"rgb_array"`` (uint8 frames) or ``"human"`` (a matplotlib window).
    noise
        Overrides the scenario's noise model: a
        :class:`~safe_nav_env.noise.NoiseModel`, a preset name (``"paper"``,
        ``"authors_code"``, ``"gaussian_reality"``, ``"student_t"``) or a mapping.
    n_samples
        Prediction samples per obstacle; default: the noise model's (100 for ``"paper"``).
    horizon
        Prediction horizon ``T`` in steps (default 10).
    episode_length
        Time limit in s; default: the scenario's ``time_limit``.
    dt
        Sampling time in s (default 0.2).
    max_acceleration
        Bound of each action component, in m/s² (default 10).
    max_speed
        Speed limit ``v_max`` of the ego, in m/s, ``> 0`` (default
        :data:`~safe_nav_env.constants.MAX_SPEED`, 5 m/s); ``inf`` or ``None`` switch it off. A
        scenario whose ego starts faster is refused at :meth:`reset`.
    max_obstacles
        Obstacle slots in the observation (default 4).
    progress_weight, arrival_bonus, control_cost_weight, collision_penalty, time_penalty
        Reward terms, all ``>= 0`` (see above).
    goal_tolerance
        Arrival radius around the goal, in m (default 0.3).
    terminate_on_collision
        End the episode on the first collision (default ``False``).
    pad_info
        Pad per-obstacle info entries to ``max_obstacles`` rows; default: only when
        ``scenario`` is a function (the obstacle count may change).
    predictor
        Who draws ``info["predictions"]``: ``None`` / ``"environment"`` (default, the
        lane-aware sampler above), ``"kalman"`` (a constant-velocity Kalman filter on
        the observed positions), or a callable
        ``(history, *, dt, horizon, n_samples, rng) -> (n, N_s, T, 2)`` receiving the
        positions observed since reset, ``(n_steps, n, 2)``; see
        :mod:`safe_nav_env.predictors`.
    random_start
        For training only: start a share of the episodes at a random ego state (near
        the goal or anywhere in the arena, at rest or moving, optionally with a random
        goal; the obstacles stay the scenario's), so that a planner learns to reach its
        goal from the states a safety filter leads it into. ``None`` (default) or ``0``:
        the scenario's start, always; a probability in (0, 1]; a mapping of
        :class:`~safe_nav_env.starts.RandomStart` fields; or a ``RandomStart``.
    actuator_lag, drag
        Ego actuation the filter does not model (:mod:`safe_nav_env.actuation`): actuator
        time constant ``τ`` in s, linear drag ``c`` in 1/s (>= 0; default 0: off).

    Raises
    ------
    ConfigError, ScenarioError
        (Both ``ValueError``.) If an option or the scenario is invalid.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 5}
    _scene_id: str | None = None  # the gym id of an environment with a scene of its own

    def __init__(self, scenario: Scenario | ScenarioFactory | str | Mapping[str, Any] | None = None,
                 *, render_mode: str | None = None,
                 noise: NoiseModel | str | Mapping[str, Any] | None = None,
                 n_samples: int | None = None, horizon: int = HORIZON,
                 episode_length: float | None = None, dt: float = DT,
                 max_acceleration: float = MAX_ACCELERATION, max_speed: float | None = MAX_SPEED,
                 max_obstacles: int = 4, progress_weight: float = 1.0, arrival_bonus: float = 10.0,
                 control_cost_weight: float = 1e-3, collision_penalty: float = 1.0,
                 time_penalty: float = 0.0, goal_tolerance: float = 0.3,
                 terminate_on_collision: bool = False, pad_info: bool | None = None,
                 predictor: Predictor | str | None = None,
                 random_start: RandomStart | float | Mapping[str, Any] | None = None,
                 actuator_lag: float = 0.0, drag: float = 0.0) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ConfigError(f"render_mode must be None or one of "
                              f"{self.metadata['render_modes']}, got {render_mode!r}")
        self.render_mode = render_mode
        self._scenario_source = _resolve_scenario(scenario)
        self._noise_override = None if noise is None else resolve_noise(noise, "noise")
        self._n_samples_override = None if n_samples is None else _option(
            "n_samples", n_samples, low=1, integer=True)
        self.horizon: int = _option("horizon", horizon, low=1, integer=True)
        self._episode_length = None if episode_length is None else _option(
            "episode_length", episode_length, strict=True)
        self.dt: float = _option("dt", dt, strict=True)
        self.max_acceleration = _option("max_acceleration", max_acceleration, strict=True)
        self.max_speed: float = math.inf if max_speed is None else _option(  # None: JSON's null
            "max_speed (m/s; inf or None: no limit)", max_speed, strict=True, allow_inf=True)
        self.max_obstacles: int = _option("max_obstacles", max_obstacles, integer=True)
        self.progress_weight = _option("progress_weight", progress_weight)
        self.arrival_bonus = _option("arrival_bonus", arrival_bonus)
        self.control_cost_weight = _option("control_cost_weight", control_cost_weight)
        self.collision_penalty = _option("collision_penalty", collision_penalty)
        self.time_penalty = _option("time_penalty", time_penalty)
        self.goal_tolerance = _option("goal_tolerance", goal_tolerance, strict=True)
        self.terminate_on_collision = bool(terminate_on_collision)
        self.pad_info = (not isinstance(self._scenario_source, Scenario) if pad_info is None
                         else bool(pad_info))
        self.predictor: Predictor | None = resolve_predictor(predictor)
        self.random_start: RandomStart | None = resolve_random_start(random_start)
        self.actuation: Actuation | None = resolve_actuation(actuator_lag, drag, self.dt)

        # What a safety filter reads (filters.protocol.FilterableEnv).
        self.dynamics: tuple[np.ndarray, np.ndarray, np.ndarray] = double_integrator(self.dt)
        bound = np.full(2, self.max_acceleration)
        self.input_bounds: tuple[np.ndarray, np.ndarray] = (_read_only(-bound),
                                                           _read_only(bound.copy()))
        self.render_hooks: list[Callable[[Any], None]] = []

        self.action_space = spaces.Box(-self.max_acceleration, self.max_acceleration, (2,),
                                       dtype=np.float32)
        size = self._obs_size = _EGO_SIZE + _SLOT_SIZE * self.max_obstacles
        low, high = np.full(size, -_BIG, np.float32), np.full(size, _BIG, np.float32)
        flags = _EGO_SIZE + _SLOT_SIZE * np.arange(self.max_obstacles) + 4
        low[flags], high[flags] = 0.0, 1.0
        low[2:4], high[2:4] = max(-self.max_speed, -_BIG), min(self.max_speed, _BIG)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)

        self._renderer: Any = None
        self._model_scenario: Scenario | None = None
        first = self._scenario_source if isinstance(self._scenario_source, Scenario) else None
        self._load(first)

    def _predict(self, *, reset: bool) -> None:
        """Draw :attr:`predictions`: the obstacle model's sampler, or :attr:`predictor` given
        the positions observed since reset."""
        if self.predictor is None:
            samples = self._model.predict(self.np_random, self.noise.prediction, self.n_samples,
                                          self.horizon)
        else:
            if reset:
                self._history: list[np.ndarray] = []
            self._history.append(self.obstacle_positions)
            n, dim = self.obstacle_positions.shape
            samples = check_predictions(self.predictor(
                np.stack(self._history), dt=self.dt, horizon=self.horizon,
                n_samples=self.n_samples, rng=self.np_random), n, self.n_samples, self.horizon, dim)
        self.predictions = _read_only(samples)

    def _sense(self, *, reset: bool) -> tuple[np.ndarray, np.ndarray]:
        """The observation and the sampled clearances ``||y - p_i|| - r_A - r_O,i`` in m (as
        :func:`~safe_nav_env.obstacles.distance_to_collision`); records the positions for
        the renderer first (human mode: draws the frame)."""
        if self.render_mode is not None:
            if reset:
                self._trail = []
            self._trail.append((self.ego_state[:2].copy(), self.obstacle_positions))
            if self.render_mode == "human":
                self.render()
        delta = self.obstacle_positions - self.ego_state[:2]
        centre = np.hypot(delta[:, 0], delta[:, 1])
        clearance = _read_only(centre - self._radii_sum)
        velocities, present = self.obstacle_velocities, self._model.present
        if present is not None and not present.all():  # empty slots stay out of the observation
            delta, velocities, centre = delta[present], velocities[present], centre[present]
        return self._observe(self.ego_state, delta, velocities, centre), clearance

    # ------------------------------------------------------------------ setup

    def _load(self, scenario: Scenario | None) -> None:
        """Set the episode constants and the initial state from ``scenario``."""
        if scenario is None:  # a family before the first reset: empty placeholders
            scenario = Scenario(name="unset", ego_start=(0.0, 0.0), goal=(0.0, 0.0))
        self.scenario: Scenario = scenario
        self.noise: NoiseModel = self._noise_override or scenario.noise
        self.n_samples: int = self._n_samples_override or self.noise.n_samples
        length = self._episode_length or scenario.time_limit
        self.max_episode_steps: int = max(1, math.ceil(length / self.dt - 1e-9))
        if self._model_scenario is not scenario:  # always at the first _load
            self._model: ObstacleModel = self._obstacle_model(scenario)
            self._model_scenario = scenario
        self.ego_radius: float = scenario.ego_radius
        self.obstacle_radii: np.ndarray = self._model.radii
        self._radii_sum = self.obstacle_radii + self.ego_radius
        self.goal: np.ndarray = _read_only(np.array(scenario.goal, dtype=np.float64))
        self.position_bounds: tuple[np.ndarray, np.ndarray] = tuple(
            _read_only(np.array(corner, dtype=np.float64)) for corner in scenario.arena)
        self.ego_state: np.ndarray = _read_only(np.array(scenario.ego_start, dtype=np.float64))
        self.obstacle_positions: np.ndarray = _read_only(self._model.starts.copy())
        self.obstacle_velocities: np.ndarray = _read_only(self._model.initial_velocities.copy())
        self.predictions: np.ndarray = _read_only(np.zeros((self._model.n, self.n_samples,
                                                            self.horizon, 2)))
        self.step_count = 0
        self._applied = _read_only(np.zeros(2))
        start, goal = scenario.ego_start, scenario.goal
        self._distance_to_goal = math.hypot(start[0] - goal[0], start[1] - goal[1])

    def _obstacle_model(self, scenario: Scenario) -> ObstacleModel:
        """Where the obstacles of ``scenario`` start, how they move and how they are predicted.

        The hook of the scene environments: the crowd's reactive humans
        (:class:`~safe_nav_env.crowd.model.CrowdModel`) and the pedestrians' replay
        (:class:`~safe_nav_env.pedestrians.replay.ReplayModel`) override it; everything
        else (ego, observation, reward, collisions, ``info``) is this class's.
        """
        return ObstacleModel(scenario.obstacles, self.dt)

    @property
    def time(self) -> float:
        """Time since the start of the episode, in s."""
        return self.step_count * self.dt

    @property
    def n_obstacles(self) -> int:
        """Number of obstacles in the current episode."""
        return self._model.n

    # ------------------------------------------------------------ observation

    def observe(self, ego_state: np.ndarray, obstacle_positions: np.ndarray,
                obstacle_velocities: np.ndarray) -> np.ndarray:
        """Observation the agent would receive in the given (hypothetical) situation.

        Uses the current goal; does not touch the environment's state. Returns the
        float32 vector laid out as in the class docstring.

        Parameters
        ----------
        ego_state
            ``[p_x, p_y, v_x, v_y]``, shape ``(4,)``.
        obstacle_positions, obstacle_velocities
            Shape ``(n, 2)`` each, in m and m/s; ``n`` may differ from the scenario's.
        """
        x = np.asarray(ego_state, dtype=np.float64)
        positions = np.asarray(obstacle_positions, dtype=np.float64)
        velocities = np.asarray(obstacle_velocities, dtype=np.float64)
        if x.shape != (4,):
            raise ValueError(f"ego_state must have shape (4,), got {x.shape}")
        if positions.ndim != 2 or positions.shape[1] != 2 or velocities.shape != positions.shape:
            raise ValueError("obstacle_positions and obstacle_velocities must both have shape "
                             f"(n, 2), got {positions.shape} and {velocities.shape}")
        delta = positions - x[:2]
        return self._observe(x, delta, velocities, np.hypot(delta[:, 0], delta[:, 1]))

    def _observe(self, x: np.ndarray, delta: np.ndarray, velocities: np.ndarray,
                 centre: np.ndarray) -> np.ndarray:
        """:meth:`observe` without the checks, given ``delta = positions - p`` and its norms.

        The few entries are computed on Python floats (the same IEEE double operations
        as on arrays) and cast to float32 once: cheaper than a dozen small array ops.
        """
        px, py, vx, vy = x.tolist()
        gx, gy = self.goal.tolist()
        values = [px, py, vx, vy, gx - px, gy - py]
        n = delta.shape[0]
        if n and self.max_obstacles:
            rel = delta.tolist()
            vel = velocities.tolist()
            order = centre.argsort(kind="stable")[: self.max_obstacles].tolist() if n > 1 else [0]
            for i in order:  # nearest first, by centre distance
                dx, dy = rel[i]
                ox, oy = vel[i]
                values += (dx, dy, ox - vx, oy - vy, 1.0)
        obs = np.zeros(self._obs_size, dtype=np.float32)
        obs[: len(values)] = values
        return obs

    # ------------------------------------------------------------------ info

    def _info(self, distances: np.ndarray, swept: np.ndarray,
              distance_to_goal: float) -> dict[str, Any]:
        present = self._model.present
        if present is not None and not present.all():  # empty slots: infinitely far
            distances = _read_only(np.where(present, distances, np.inf))
            swept = _read_only(np.where(present, swept, np.inf))
        minimum = float(distances.min()) if distances.shape[0] else math.inf
        swept_minimum = float(swept.min()) if swept.shape[0] else math.inf
        collision = swept_minimum <= 0.0
        px, py = float(self.ego_state[0]), float(self.ego_state[1])
        low, high = self.scenario.arena
        info: dict[str, Any] = {
            "predictions": self.predictions,
            "obstacle_positions": self.obstacle_positions,
            "obstacle_velocities": self.obstacle_velocities,
            "distance_to_collision": distances,
            "min_distance_to_collision": minimum,
            "swept_distance_to_collision": swept,
            "min_swept_distance_to_collision": swept_minimum,
            "collision": collision,
            "sampled_collision": minimum <= 0.0,
            "cost": 1.0 if collision else 0.0,
            "is_success": distance_to_goal <= self.goal_tolerance,
            "distance_to_goal": distance_to_goal,
            "ego_state": self.ego_state,
            "out_of_bounds": not (low[0] <= px <= high[0] and low[1] <= py <= high[1]),
            "time": self.step_count * self.dt,
            "acceleration": self._applied,
        }
        if self.pad_info or present is not None:
            info.update(_padded(info, present, self.max_obstacles if self.pad_info
                                else self._model.n))
        return info

    # ------------------------------------------------------------------- API

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode.

        Parameters
        ----------
        seed
            Seeds :attr:`np_random`, the only source of randomness (scenario draws,
            turning decisions, predictions, realised noise).
        options
            ``{"scenario": ...}`` replaces the scenario from now on (same forms as the
            constructor's ``scenario``; not for an environment with a scene of its own).

        Raises
        ------
        ConfigError
            If ``options`` gives a scenario to an environment with a scene of its own
            (``SafeNav/Crowd-v0``, ``SafeNav/Pedestrians-v0``).
        ScenarioError
            If a scenario function does not return a :class:`Scenario`, or with
            ``pad_info`` a scenario has more than ``max_obstacles`` obstacles.
        """
        super().reset(seed=seed)
        if options and "scenario" in options:
            if self._scene_id is not None:
                raise ConfigError(f"options['scenario'] does not apply to {self._scene_id}; make "
                                  "a new environment with its scene options")
            self._scenario_source = _resolve_scenario(options["scenario"], "options['scenario']")
        source = self._scenario_source
        scenario = source if isinstance(source, Scenario) else source(self.np_random)
        if not isinstance(scenario, Scenario):
            raise ScenarioError(f"the scenario function returned {scenario!r}, not a Scenario")
        if self.pad_info and scenario.n_obstacles > self.max_obstacles:
            raise ScenarioError(f"scenario {scenario.name!r} has {scenario.n_obstacles} obstacles "
                                f"but max_obstacles={self.max_obstacles}; pass a larger one")
        self._load(scenario)
        self._model.reset(self.np_random)
        self.obstacle_positions = _read_only(self._model.positions)
        self.obstacle_velocities = _read_only(self._model.velocities)
        drawn = None if self.random_start is None else self.random_start.draw(
            self.np_random, goal=self.goal, goal_tolerance=self.goal_tolerance,
            arena=self.scenario.arena, ego_radius=self.ego_radius,
            obstacle_positions=self.obstacle_positions,
            obstacle_radii=self.obstacle_radii)  # training only: another ego start
        if drawn is not None:
            start, goal = drawn
            speed = math.hypot(start[2], start[3])
            if speed > self.max_speed:  # the draw's speed, capped at the limit
                start[2:4] *= self.max_speed / speed
            self.ego_state = _read_only(start)
            self.goal = _read_only(goal)
            self._distance_to_goal = math.hypot(start[0] - goal[0], start[1] - goal[1])
        speed = math.hypot(self.ego_state[2], self.ego_state[3])
        if speed > self.max_speed:
            raise ScenarioError(
                f"scenario {scenario.name!r}: the ego starts at {speed:g} m/s, above "
                f"max_speed={self.max_speed:g} m/s; pass a larger max_speed (inf: no limit)")
        self._predict(reset=True)
        obs, distances = self._sense(reset=True)
        return obs, self._info(distances, distances, self._distance_to_goal)

    def step(self, action: np.ndarray
             ) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        """Apply the acceleration ``action`` for one sampling period.

        Order of events: the ego moves (``x_{t+1} = A x_t + B u_t``), the obstacles
        move with reality noise, collisions are evaluated over the whole step (continuous
        time, see the class docstring) and at the new positions (sampled), the reward
        follows, and the predictions for the ``T`` steps after the new state are drawn.

        The applied input (``info["acceleration"]``) is the action after the actuation
        options, clipped to the box and the speed limit (:func:`~.dynamics.applied_acceleration`).

        Raises
        ------
        InvalidActionError
            If ``action`` does not have 2 entries or holds NaN or infinite values.
        """
        dt = self.dt
        half_dt2 = 0.5 * dt * dt
        start = self.ego_state.tolist()
        px, py, vx, vy = start
        u = np.clip(parse_action(action), -self.max_acceleration, self.max_acceleration)
        if self.actuation is not None:  # lag and drag the filter does not model
            u = self.actuation.apply(*u.tolist(), vx, vy, first=self.step_count == 0)
        ux, uy = applied_acceleration((vx, vy), tuple(u), dt, self.max_acceleration,
                                      self.max_speed)  # the box and the speed limit hold last
        self._applied = _read_only(np.array((ux, uy)))
        # x_{t+1} = A x_t + B u_t: p + T_s v + T_s²/2 u, v + T_s u.
        px, py = px + dt * vx + half_dt2 * ux, py + dt * vy + half_dt2 * uy
        vx, vy = vx + dt * ux, vy + dt * uy
        self.ego_state = _read_only(np.array((px, py, vx, vy)))

        model = self._model
        self.obstacle_positions = _read_only(model.step(self.np_random, self.noise.reality))
        before = model.chord_starts  # each obstacle's own position before the step
        self.obstacle_velocities = _read_only(model.velocities)
        self._predict(reset=False)
        self.step_count += 1

        obs, distances = self._sense(reset=False)
        swept = np.minimum(
            swept_clearance(start, (ux, uy), dt, before.tolist(),
                            self.obstacle_positions.tolist(), self._radii_sum.tolist()),
            distances,  # the end point, bit-for-bit: a sampled collision is a collision
        )
        gx, gy = self.goal.tolist()
        distance_to_goal = math.hypot(px - gx, py - gy)
        info = self._info(distances, _read_only(swept), distance_to_goal)

        reward = self.progress_weight * (self._distance_to_goal - distance_to_goal)
        reward -= self.control_cost_weight * (ux * ux + uy * uy) + self.time_penalty
        if info["is_success"]:
            reward += self.arrival_bonus
        if info["collision"]:
            reward -= self.collision_penalty
        self._distance_to_goal = distance_to_goal

        terminated = info["is_success"] or (self.terminate_on_collision and info["collision"])
        truncated = self.step_count >= self.max_episode_steps
        return obs, reward, bool(terminated), bool(truncated), info

    def applied_input(self, state: np.ndarray, action: np.ndarray) -> np.ndarray:
        """The input applied for ``action`` at ``state`` (the box, then the speed limit)."""
        return np.array(applied_acceleration((state[2], state[3]), (action[0], action[1]),
                                             self.dt, self.max_acceleration, self.max_speed))

    def render(self) -> np.ndarray | None:
        """Draw the scene with matplotlib (imported here, not at package import).

        Returns a uint8 ``(H, W, 3)`` frame for ``render_mode="rgb_array"``, shows
        a window and returns ``None`` for ``"human"``, and warns and returns ``None``
        without a render mode. The hooks in :attr:`render_hooks` are called with the
        axes after the scene is drawn.
        """
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' "
                            "or 'human' to gym.make")
            return None
        if self._renderer is None:
            from safe_nav_env.rendering import Renderer

            self._renderer = Renderer(human=self.render_mode == "human",
                                      fps=self.metadata["render_fps"])
        return self._renderer.draw(self, getattr(self, "_trail", []))

    def close(self) -> None:
        """Close the rendering figure, if any."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

"""Scenarios as data: who starts where, where the ego goes, how the obstacles move.

A :class:`Scenario` is a frozen, validated value. The paper's four encounters
(Section IV-B, with the numbers of the authors' simulation code) are
:data:`HEAD_ON`, :data:`OVERTAKING`, :data:`INTERSECTION` and :data:`MULTI_OBSTACLE`;
:func:`random_crossing` draws a randomised training scenario. :data:`SCENARIOS`
maps the scenario names to either.

One name per scenario: the canonical name is the one in the Gymnasium id
(``"HeadOn"`` for ``SafeNav/HeadOn-v0``), used by :data:`SCENARIOS`, the command
line and the evaluation records. The other spellings (``"head_on"``,
``"SafeNav/HeadOn-v0"``) are accepted everywhere a name is, with a
:class:`ScenarioNameWarning` naming the canonical one; :func:`scenario_name`
does the conversion and :func:`env_id` gives the Gymnasium id.

Positions are in m, velocities in m/s, times in s, angles in rad.
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np

from safe_nav_env.constants import ARENA, EGO_RADIUS, EGO_START_SPEED, OBSTACLE_RADIUS
from safe_nav_env.errors import ConfigError, ScenarioError
from safe_nav_env.noise import NoiseModel, resolve_noise
from safe_nav_env.options import _finite_array, _from_fields, _named, _option

Vector = tuple[float, ...]

DEFAULT_DURATION = 10.0
"""Length in s of a scenario given neither ``duration`` nor ``episode_length``."""


def _vector(value: Any, path: str, sizes: Sequence[int]) -> Vector:
    """Return ``value`` as a tuple of finite floats whose length is one of ``sizes``."""
    return tuple(_finite_array(path, value, "vector", " or ".join(f"({n},)" for n in sizes),
                               lambda shape: len(shape) == 1 and shape[0] in sizes,
                               ScenarioError).tolist())


_number = partial(_option, error=ScenarioError)  # scenario data: a ScenarioError


def _arena(value: Any, path: str = "arena", error: type[ValueError] = ScenarioError
           ) -> tuple[Vector, Vector]:
    """``((x_min, y_min), (x_max, y_max))`` as float tuples, finite with min < max, or ``error``."""
    try:
        box = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise error(f"{path} must be ((x_min, y_min), (x_max, y_max)), got {value!r}") from exc
    if box.shape != (2, 2) or not np.isfinite(box).all() or np.any(box[0] >= box[1]):
        raise error(f"{path} must have x_min < x_max and y_min < y_max, finite "
                    f"((x_min, y_min), (x_max, y_max)), got {value!r}")
    return tuple(box[0].tolist()), tuple(box[1].tolist())


_SPEC_BOUNDS: dict[str, dict[str, Any]] = {
    "radius": {"strict": True}, "turn_rate": {"low": -math.inf}, "turn_probability": {"high": 1.0},
    "turn_start": {}, "turn_angle": {"strict": True, "allow_inf": True}}
"""The numeric fields of :class:`ObstacleSpec` and their ranges (:func:`_option`'s keywords)."""


@dataclass(frozen=True)
class ObstacleSpec:
    """A disc-shaped obstacle moving as a single integrator along a lane.

    The *lane* is the line through ``start`` along ``velocity``. Each step the
    obstacle's nominal next position is its current position projected onto the
    lane plus ``velocity · T_s`` (constant speed along the lane; lateral drift is
    pulled back), and the realised position adds the scenario's reality noise; see
    :mod:`safe_nav_env.obstacles`. An obstacle with zero velocity holds station at
    ``start``.

    Turning: with ``turn_rate = ω != 0`` the obstacle *may* turn. At each reset it
    decides, with probability ``turn_probability``, to turn in this episode: from
    time ``turn_start`` its heading (and lane) rotates at ``ω`` until it has turned
    by ``turn_angle``. The predictor does not know the decision: each prediction
    sample follows the turning schedule with probability ``turn_probability`` and
    keeps the current heading otherwise, so with ``0 < turn_probability < 1`` the
    predictions are bimodal.

    Parameters
    ----------
    start
        Initial position ``(x, y)``, in m.
    velocity
        Nominal velocity ``(v_x, v_y)``, in m/s.
    radius
        Radius ``r_O`` of the disc, in m, ``> 0`` (default 0.3, the paper's).
    turn_rate
        Heading rate ``ω`` when turning, in rad/s (positive: counter-clockwise).
    turn_probability
        Probability in ``[0, 1]`` that the obstacle turns in an episode (used only
        when ``turn_rate != 0``).
    turn_start
        Time at which the turn starts, in s, ``>= 0``.
    turn_angle
        Total heading change of the turn, in rad, ``> 0`` (default: no limit).
    stop_window
        ``(earliest, latest)`` in s, ``0 <= earliest <= latest``: the obstacle halts at a
        time drawn uniformly in the window at each reset and holds station there (its
        realised motion is the reality noise around the halting point), or ``None``
        (default: never). The predictor is not told: the observed nominal velocity and
        the environment's predictions keep the lane speed.

    Raises
    ------
    ScenarioError
        If a field is invalid; the message names it.
    """

    start: Vector
    velocity: Vector
    radius: float = OBSTACLE_RADIUS
    turn_rate: float = 0.0
    turn_probability: float = 1.0
    turn_start: float = 0.0
    turn_angle: float = math.inf
    stop_window: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "start", _vector(self.start, "ObstacleSpec.start", (2,)))
        set_(self, "velocity", _vector(self.velocity, "ObstacleSpec.velocity", (2,)))
        for name, bounds in _SPEC_BOUNDS.items():
            set_(self, name, _number(f"ObstacleSpec.{name}", getattr(self, name), **bounds))
        if self.stop_window is not None:
            window = _vector(self.stop_window, "ObstacleSpec.stop_window", (2,))
            if not 0.0 <= window[0] <= window[1]:
                raise ScenarioError("ObstacleSpec.stop_window must be (earliest, latest) in s "
                                    f"with 0 <= earliest <= latest, got {self.stop_window!r}")
            set_(self, "stop_window", window)

    @property
    def speed(self) -> float:
        """Nominal speed ``||velocity||``, in m/s."""
        return math.hypot(*self.velocity)


@dataclass(frozen=True)
class Scenario:
    """A reach-avoid encounter: the ego drives from ``ego_start`` to ``goal`` among obstacles.

    Two lengths are kept apart. ``duration`` is the length of the encounter as
    simulated in the paper and the authors' code (3 s for the single-obstacle
    scenarios, 5 s for the multi-obstacle one): enough to pass the obstacles, not
    to reach a goal 9.4 m away at 1.5 m/s. ``episode_length`` is the environment's
    default time limit; the presets set it so that the goal is reachable (8 s for
    one obstacle, 10 s for three). To reproduce the paper's runs, pass
    ``episode_length=scenario.duration`` to the environment.

    A scenario given neither lasts :data:`DEFAULT_DURATION` (10 s, the
    multi-obstacle preset's episode length: a 9.4 m crossing at 1.5 m/s takes 6.3 s);
    one given only ``duration`` ends after ``duration``.

    Parameters
    ----------
    name
        Short identifier, e.g. ``"HeadOn"``.
    ego_start
        Initial ego state ``(p_x, p_y, v_x, v_y)`` or position ``(p_x, p_y)`` (then
        at rest); stored as the 4-vector. The position must lie in the arena.
    goal
        Goal position ``(x, y)`` in the arena, in m.
    obstacles
        :class:`ObstacleSpec` objects or mappings of their fields (possibly empty).
    duration
        Length of the encounter, in s, ``> 0``; ``None`` (default) means
        ``episode_length`` if given, else :data:`DEFAULT_DURATION`.
    episode_length
        Default time limit of an episode, in s, ``> 0``; ``None`` means ``duration``.
    noise
        :class:`~safe_nav_env.noise.NoiseModel`, preset name (see
        :data:`~safe_nav_env.noise.NOISE_PRESETS`) or mapping; default ``"paper"``.
    ego_radius
        Radius ``r_A`` of the ego disc, in m, ``> 0``.
    arena
        ``((x_min, y_min), (x_max, y_max))``, in m; default ``[-5, 5]²``.

    Raises
    ------
    ScenarioError
        If a field is invalid; the message starts with the field's path, e.g.
        ``"obstacles[1].radius must be > 0, got -0.3"``.
    """

    name: str
    ego_start: Vector
    goal: Vector
    obstacles: tuple[ObstacleSpec, ...] = ()
    duration: float | None = None
    episode_length: float | None = None
    noise: NoiseModel = field(default_factory=NoiseModel)
    ego_radius: float = EGO_RADIUS
    arena: tuple[Vector, Vector] = ARENA

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        if not isinstance(self.name, str) or not self.name:
            raise ScenarioError(f"name must be a non-empty string, got {self.name!r}")
        set_(self, "arena", _arena(self.arena))
        arena = np.asarray(self.arena)

        start = _vector(self.ego_start, "ego_start", (2, 4))
        if len(start) == 2:
            start = (*start, 0.0, 0.0)
        set_(self, "ego_start", start)
        set_(self, "goal", _vector(self.goal, "goal", (2,)))
        for label, point in (("ego_start", start[:2]), ("goal", self.goal)):
            if np.any(np.asarray(point) < arena[0]) or np.any(np.asarray(point) > arena[1]):
                raise ScenarioError(
                    f"{label} position {tuple(point)} is outside the arena "
                    f"[{arena[0, 0]}, {arena[1, 0]}] x [{arena[0, 1]}, {arena[1, 1]}]"
                )

        if isinstance(self.obstacles, Mapping | str) or not isinstance(
            self.obstacles, Sequence
        ):
            raise ScenarioError(f"obstacles must be a sequence of ObstacleSpec, got "
                                f"{self.obstacles!r}")
        set_(self, "obstacles",
             tuple(_from_fields(ObstacleSpec, o, f"obstacles[{i}]")
                   for i, o in enumerate(self.obstacles)))

        if self.episode_length is not None:
            set_(self, "episode_length", _number("episode_length", self.episode_length,
                                                 strict=True))
        if self.duration is None:
            set_(self, "duration", DEFAULT_DURATION if self.episode_length is None
                 else self.episode_length)
        set_(self, "duration", _number("duration", self.duration, strict=True))
        set_(self, "noise", resolve_noise(self.noise, "noise"))
        set_(self, "ego_radius", _number("ego_radius", self.ego_radius, strict=True))

    @property
    def time_limit(self) -> float:
        """Default episode length, in s: ``episode_length``, else ``duration``."""
        return self.duration if self.episode_length is None else self.episode_length

    @property
    def n_obstacles(self) -> int:
        """Number of obstacles."""
        return len(self.obstacles)



def _paper(name: str, ego: tuple[float, float], goal: Vector,
           *lanes: ObstacleSpec | tuple[Vector, Vector], duration: float = 3.0,
           episode_length: float = 8.0) -> Scenario:
    """A scenario of the paper's kind: the ego at ``ego`` at its start speed along +x; each
    obstacle an :class:`ObstacleSpec` or the ``(start, velocity)`` of a plain one."""
    return Scenario(name=name, ego_start=(*ego, EGO_START_SPEED, 0.0), goal=goal,
                    obstacles=tuple(o if isinstance(o, ObstacleSpec) else ObstacleSpec(*o)
                                    for o in lanes),
                    duration=duration, episode_length=episode_length)


HEAD_ON = _paper("HeadOn", (-4.7, 0.0), (4.7, 0.0), ((2.0, -0.01), (-1.0, 0.0)))
"""Head-on encounter: one obstacle coming towards the ego along its path."""

OVERTAKING = _paper("Overtaking", (-4.7, 0.0), (4.7, 0.0), ((-2.0, -0.05), (1.0, 0.0)))
"""Overtaking: one slower obstacle ahead of the ego, moving the same way."""

INTERSECTION = _paper("Intersection", (-3.5, 1.0), (1.0, -3.0), ((-2.5, -1.0), (1.5, 0.0)))
"""Intersection: the ego heads down-right across the lane of an obstacle moving along +x."""

MULTI_OBSTACLE = _paper("MultiObstacle", (-4.7, -1.0), (4.7, 0.0), ((-1.1, 1.01), (0.7, 0.0)),
                        ((-2.0, -1.01), (1.0, 0.0)), ((-1.0, -2.01), (0.7, 0.0)),
                        duration=5.0, episode_length=10.0)
"""Three obstacles moving along +x around the ego's path (the paper's Fig. 4)."""


def random_crossing(rng: np.random.Generator, *, noise: NoiseModel | str = "paper",
                    min_obstacles: int = 1, max_obstacles: int = 4,
                    duration: float = 8.0) -> Scenario:
    """Draw a randomised crossing scenario, for training.

    The ego starts at ``x = -4.5`` with ``y ~ U(-2.5, 2.5)`` and speed
    ``U(0, 1.5)`` m/s along +x, and must reach ``x = 4.5``, ``y ~ U(-2.5, 2.5)``.
    Between ``min_obstacles`` and ``max_obstacles`` obstacles (uniform count),
    radius 0.3 m, cross the straight start-goal segment: obstacle ``i`` crosses it at
    the fraction ``s ~ U(0.25, 0.75)`` of its length, at an angle ``U(30°, 150°)``
    to it (either side) and a speed ``U(0.5, 1.5)`` m/s, and is placed on its lane
    so that it reaches the crossing point when an ego moving along the segment at
    ``U(1, 3)`` m/s would. Obstacles may start outside the arena; one starting
    within 1 m of the ego is redrawn.

    Parameters
    ----------
    rng
        Source of all randomness (the environment passes its ``np_random``).
    noise
        Noise model of the scenario.
    min_obstacles, max_obstacles
        Range of the obstacle count, ``1 <= min_obstacles <= max_obstacles``.
    duration
        Encounter length and episode length, in s.

    Returns
    -------
    Scenario
        Named ``"RandomCrossing"``.
    """
    if not 0 <= min_obstacles <= max_obstacles:
        raise ScenarioError(
            f"need 0 <= min_obstacles <= max_obstacles, got {min_obstacles}, {max_obstacles}"
        )
    start = np.array([-4.5, rng.uniform(-2.5, 2.5)])
    goal = np.array([4.5, rng.uniform(-2.5, 2.5)])
    ego_speed = rng.uniform(0.0, 1.5)
    path = goal - start
    length = float(np.hypot(*path))
    direction = path / length
    count = int(rng.integers(min_obstacles, max_obstacles + 1))
    obstacles = []
    for _ in range(count):
        for _attempt in range(100):
            fraction = rng.uniform(0.25, 0.75)
            angle = rng.uniform(math.pi / 6, 5 * math.pi / 6) * rng.choice((-1.0, 1.0))
            speed = rng.uniform(0.5, 1.5)
            arrival = fraction * length / rng.uniform(1.0, 3.0)
            cos, sin = math.cos(angle), math.sin(angle)
            heading = np.array([cos * direction[0] - sin * direction[1],
                                sin * direction[0] + cos * direction[1]])
            crossing = start + fraction * path
            obstacle_start = crossing - heading * speed * arrival
            if np.hypot(*(obstacle_start - start)) >= 1.0:
                break
        obstacles.append(ObstacleSpec(start=tuple(obstacle_start), velocity=tuple(speed * heading)))
    return Scenario(
        name="RandomCrossing",
        ego_start=(start[0], start[1], ego_speed, 0.0),
        goal=tuple(goal),
        obstacles=tuple(obstacles),
        duration=duration,
        noise=noise,
    )


ScenarioFactory = Callable[[np.random.Generator], Scenario]
"""A scenario family: called with the environment's generator at each reset."""

class ScenarioNameWarning(UserWarning):
    """A scenario was named by another spelling than its canonical name."""


CUSTOM = "Custom"
"""Name of ``SafeNav/Custom-v0``: the scenario is passed as ``scenario=``."""


class _ScenarioTable(dict):
    """A dict of scenarios by canonical name that also finds the other spellings.

    ``"head_on" in SCENARIOS`` is true and ``SCENARIOS["head_on"]`` returns the
    head-on preset with a :class:`ScenarioNameWarning`; iteration, ``keys()`` and
    ``sorted(SCENARIOS)`` give the canonical names only.
    """

    def __contains__(self, name: object) -> bool:
        return dict.__contains__(self, _canonical(name))

    def __getitem__(self, name: str) -> Scenario | ScenarioFactory:
        canonical = _canonical(name)
        if not dict.__contains__(self, canonical):
            raise KeyError(name)
        if canonical != name:
            _warn_spelling(name, canonical, stacklevel=3)
        return dict.__getitem__(self, canonical)

    def get(self, name: str, default: Any = None) -> Any:
        return self[name] if name in self else default


def _canonical(name: object) -> str | None:
    """The canonical name ``name`` spells (exact, snake_case or gym id), or ``None``."""
    return _SPELLINGS.get(name) if isinstance(name, str) else None


def _warn_spelling(name: str, canonical: str, *, stacklevel: int = 2) -> None:
    warnings.warn(f"{name!r} spells the scenario {canonical!r}; use {canonical!r} (its gym id "
                  f"is {env_id(canonical)!r})", ScenarioNameWarning, stacklevel=stacklevel + 1)


SCENARIOS: dict[str, Scenario | ScenarioFactory] = _ScenarioTable({
    "HeadOn": HEAD_ON,
    "Overtaking": OVERTAKING,
    "Intersection": INTERSECTION,
    "MultiObstacle": MULTI_OBSTACLE,
    "RandomCrossing": random_crossing,
})
"""Scenarios and scenario families by canonical name, as accepted by
``SafeNavEnv(scenario=...)`` (the other spellings are found too, with a warning)."""

SCENES: dict[str, str] = {
    "Crowd": "safe_nav_env.crowd.env:CrowdEnv",
    "Pedestrians": "safe_nav_env.pedestrians.env:PedestrianEnv",
}
"""Environments with scenes of their own (no :class:`Scenario`), by name: their entry
points. ``SafeNav/<name>-v0`` makes one; its options choose the scene."""

SCENARIO_NAMES: tuple[str, ...] = (*SCENARIOS, *SCENES, CUSTOM)
"""Every canonical scenario name, one per registered gym id."""

_SPELLINGS: dict[str, str] = {
    spelling: name for name in SCENARIO_NAMES
    for spelling in (name, re.sub(r"(?<!^)(?=[A-Z])", "_", name).lower(), f"SafeNav/{name}-v0")}
"""Each accepted spelling (canonical, snake_case, gym id) and the canonical name it spells."""


def _resolve_scenario(value: Any, path: str = "scenario") -> Scenario | ScenarioFactory:
    """The scenario (or factory ``rng -> Scenario``) named or described by ``value``.

    ``value``: a :class:`Scenario`, a function ``rng -> Scenario``, a name in
    :data:`SCENARIOS`, or a mapping of :class:`Scenario` fields; ``path`` names it in
    errors. Raises :class:`ConfigError` for ``None`` (the scenario is required),
    :class:`ScenarioError` for anything else invalid.
    """
    if isinstance(value, Scenario) or (callable(value) and not isinstance(value, type)):
        return value
    if isinstance(value, str):
        return _named(SCENARIOS, value, path, "scenario")
    if isinstance(value, Mapping):
        return _from_fields(Scenario, value, path)
    if value is None:
        raise ConfigError(
            f"{path} is required: pass scenario=safe_nav_env.Scenario(...), a name in "
            f"{sorted(SCENARIOS)}, or a function rng -> Scenario, e.g. "
            "gym.make('SafeNav/Custom-v0', scenario=my_scenario)")
    raise ScenarioError(f"{path} must be a Scenario, a scenario name, a mapping or a function "
                        f"rng -> Scenario, got {value!r}")


def scenario_name(name: str, *, warn: bool = True) -> str:
    """The canonical name of a scenario spelled ``name``.

    Parameters
    ----------
    name
        ``"HeadOn"`` (canonical), ``"head_on"`` or ``"SafeNav/HeadOn-v0"``.
    warn
        Warn (:class:`ScenarioNameWarning`) when ``name`` is not the canonical spelling.

    Raises
    ------
    ScenarioError
        If ``name`` spells no scenario; the message lists the names.
    """
    canonical = _canonical(name)
    if canonical is None:
        raise ScenarioError(f"unknown scenario {name!r}; choose one of {list(SCENARIO_NAMES)} "
                            "(or their gym ids, e.g. 'SafeNav/HeadOn-v0')")
    if warn and canonical != name:
        _warn_spelling(name, canonical)
    return canonical


def env_id(name: str) -> str:
    """The Gymnasium id of a scenario: ``env_id("HeadOn") == "SafeNav/HeadOn-v0"``.

    Accepts every spelling :func:`scenario_name` does, without a warning.
    """
    return f"SafeNav/{scenario_name(name, warn=False)}-v0"

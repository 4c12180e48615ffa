"""The settings of :class:`filters.wrapper.SafetyFilterWrapper` as one value: :class:`FilterConfig`.

Every setting of the wrapper except the environment and the planner objects (``policy``,
``reference``) is a field of :class:`FilterConfig`, documented and checked here once. The
wrapper, the command line, training and the evaluation specs all build one. Checks that
need the environment (the horizon against its prediction horizon, ``stop_time`` against its
step) stay in the wrapper.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from filters._validation import finite_array, finite_scalar, integer_at_least
from filters.constants import ALPHA, DELTA, EPSILON
from filters.errors import InvalidParameterError, InvalidTypeError
from filters.risk import CHANCE_RISKS, check_alpha, check_epsilon
from filters.risk import RISKS as _METRICS

RISKS: tuple[str, ...] = ("none", *_METRICS)
"""Risk settings accepted by :class:`FilterConfig` (``"none"``: pass-through)."""

OBJECTIVES = ("first_input", "trajectory")
"""Filter objectives: the predictive safety filter's, or the paper's Problem 2."""

NORMAL_SOURCES = ("paper", "ego", "nearside", "previous_plan", "clearest")
"""Where the halfspace normals start (they end at the obstacles' sample means)."""

FALLBACKS = ("soft", "brake", "paper")
"""What the filter does when the hard QP is infeasible (see :attr:`FilterConfig.fallback`)."""

CALIBRATION_EPISODES = 5
"""Held-out episodes run at construction for ``risk="conformal"`` / ``epsilon="auto"``.

A braking episode of the 8 s (40-step) scenarios gives ``41 - k`` realised positions
per obstacle at look-ahead ``k``; five give 155-200 per look-ahead for one obstacle, so
the 200-score windows of the calibration (:class:`filters.calibration.OnlineCalibration`)
are full, or nearly, from step 0 (more episodes mostly push older scores out of the
windows, at ~0.1 s each here)."""

CALIBRATION_SEED = 1_000_000_000
"""First seed of the held-out calibration episodes (episode ``i`` uses it ``+ i``).

Far above the evaluation seeds (``--seed`` + episode index), so that the data the
filter is calibrated on is never the data it is evaluated on."""

CALIBRATION_MEMORIES = ("episode", "persistent")
"""``"episode"``: every ``reset`` restores the calibrated state; ``"persistent"``: it
carries over from episode to episode (the order of the episodes then matters)."""

_FLAGS = ("intersample", "terminal", "soft", "draw_halfspaces", "adaptive_epsilon")
_WEIGHTS = ("Q", "Q_terminal", "R")


def _frozen(name: str, value: object, ndim: int) -> np.ndarray:
    """A read-only copy of ``value`` as a finite float array of ``ndim`` dimensions."""
    array = finite_array(name, value, ndim=ndim).copy()
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class FilterConfig:
    """Every setting of :class:`filters.SafetyFilterWrapper`, checked at construction.

    Make variants with :func:`dataclasses.replace`; store one with :meth:`to_dict` (plain
    JSON: arrays as lists) and read it back with :meth:`from_dict`. Two configs are equal
    when their :meth:`to_dict` are. ``None`` in ``horizon``, ``objective``, ``normals`` and
    ``calibration_episodes`` means "the wrapper chooses"; its attributes of the same names
    hold the resolved values.

    Attributes
    ----------
    risk
        ``"none"`` (pass-through: the proposal is applied with the same bookkeeping) or a
        metric of :data:`filters.risk.RISKS` (``"mean"``, ``"cvar"``, ``"dr_cvar"``,
        ``"gaussian_cc"``, ``"moment_dr"``, ``"conformal"``). ``"conformal"`` takes its
        margin per look-ahead step from an online split-conformal calibration of the
        realised positions against the predictions
        (:class:`filters.calibration.ConformalMargin`, 1 m until enough data), at
        miscoverage ``alpha``. Default ``"dr_cvar"``.
    alpha
        CVaR tail mass, in (0, 1]; ``alpha = 1`` gives the mean. For ``"gaussian_cc"``,
        ``"moment_dr"`` and ``"conformal"`` it is a violation probability, in (0, 1).
    delta
        Risk bound on the intrusion depth, in m (>= 0); Definition 2 of the paper: the
        risk of the loss (how deep the ego would reach into an obstacle) is at most it.
    epsilon
        Wasserstein radius of DR-CVaR, in m (>= 0), or ``"auto"``; ``"auto"`` is a radius
        per look-ahead step estimated online from the realised against the predicted
        positions (:class:`filters.calibration.WassersteinRadius`, 0.05 m until enough
        data; see ``calibration_episodes``).
    horizon
        Filter horizon T in steps, >= 1 and at most the environment's prediction horizon
        (checked by the wrapper); ``None``: the prediction horizon.
    objective
        What the filter's QP minimises. ``"first_input"``: the predictive safety filter
        of Wabersich & Zeilinger,
        :math:`\\min \\|u_0 - a\\|^2_R + \\eta \\sum_{t \\ge 1} \\|u_t - u^r_t\\|^2_R`
        with no state tracking: the proposed action ``a`` changes as little as possible,
        the rest of the plan only has to exist. ``"trajectory"``: the paper's Problem 2,
        tracking the reference states and inputs with ``Q``, ``Q_terminal`` and ``R``
        (with the held action as reference it chases states far outside the arena and
        deadlocks; with a planner's roll-out it follows the planned route). ``None``:
        ``"trajectory"`` when a ``policy`` or ``reference`` gives a planned route, else
        ``"first_input"``.
    later_input_weight
        :math:`\\eta > 0` of the first-input objective (dimensionless; default 0.01).
    intersample
        Add the inter-sample rows of :mod:`filters.intersample`, so that the plan is safe
        in continuous time, between the samples too (default ``True``).
    normals
        Where the halfspace normals start (they end at the obstacles' sample means):
        ``"paper"`` (the reference positions, Definition 3), ``"ego"`` (the current ego
        position for every step: no flips when the reference runs through an obstacle,
        but no overtaking), ``"nearside"`` (the reference position while it is on the
        ego's side of the obstacle's centre, the ego's position once past it),
        ``"previous_plan"`` (the last filtered plan shifted by one step; the reference
        until there is one) or ``"clearest"`` (the first step from the ego's position,
        each later one from whichever of the reference and the last optimal plan is
        farther from the obstacle, so that the normals follow the plan where the reference
        runs through an obstacle and do not flip; ``"nearside"`` while there is no optimal
        plan: :func:`filters.normals.clearest_normals`). ``None``: ``"paper"`` with a
        ``policy`` or ``reference``, ``"clearest"`` with the held action (whose reference
        runs straight through obstacles, so that the paper's normals flip inside the
        horizon and the filter brakes in front of a head-on obstacle).
    fallback
        What the filter does when the hard QP is infeasible. ``"soft"`` (default): the
        exact-penalty recovery QP with the halfspace rows softened (the least violation,
        then the plan closest to the reference; the arena rows softened too only if they
        cannot hold: :mod:`filters.mpc.recovery`); ``"brake"``: the same, but the least
        violation, then the lowest speed; ``"paper"``: the paper's Remark, the last
        optimal plan shifted, then braking.
    terminal
        Require that the plan ends able to stop inside the arena within ``stop_time``
        (:func:`filters.mpc.terminal.stopping_terminal_set`), so that plans stay
        recursively feasible against the arena (default ``True``).
    stop_time
        The terminal set's stopping time :math:`c`, in s, > 0 and at least half the
        environment's step (checked by the wrapper); default 0.5 s.
    Q, Q_terminal, R
        Weights on the state deviation (n, n), the terminal state deviation (n, n) and
        the input deviation (m, m), finite; ``None``: the authors' effective weights
        4 I, 25 I and I (docs/design.md). The first-input objective uses ``R`` only.
    soft
        Always solve with slack variables (exact L1 penalty) on the halfspace rows; the
        slack is reported (default ``False``).
    intervention_penalty
        Reward penalty per (m/s²)² of intervention, >= 0: the reward is reduced by
        :math:`\\kappa \\|u_{safe} - u_{ref}\\|^2` (u in m/s²), :math:`\\kappa` this
        penalty, for training with the filter in the loop; 0 (default) leaves it untouched.
    support
        Optional polytope ``(V, v)``, ``V p <= v`` (p in m), bounding the obstacle
        positions (Proposition 1).
    draw_halfspaces
        Draw the halfspaces in the environment's render (default ``True``).
    calibration_episodes
        Held-out episodes (>= 0) run at construction to calibrate ``risk="conformal"``,
        ``epsilon="auto"`` and ``adaptive_epsilon`` (split conformal: calibrate on
        held-out data, then run), so that margins and radii come from data from step 0
        instead of their fallbacks (1 m, 0.05 m). The environment is reset with the seeds
        ``calibration_seed + i`` and the ego brakes (the obstacles' motion and the
        predictions do not depend on it; an episode that ends early is followed by the
        next seed); every step's predictions and realised positions feed the calibration,
        as in the loop. The environment's seed state is restored afterwards (an unseeded
        ``reset`` stays unseeded); with ``options={"scenario": ...}`` at a later reset,
        the calibration still describes the constructor's scenario. The wrapper's
        ``calibration_time`` is the wall time spent, in s. ``None`` (default):
        :data:`CALIBRATION_EPISODES` when the wrapper calibrates, else 0.
    calibration_seed
        First held-out seed, an integer >= 0 (default :data:`CALIBRATION_SEED`; keep it
        away from the seeds you evaluate on).
    calibration_memory
        ``"episode"`` (default): each ``reset`` restores (a copy of) the state calibrated
        at construction; the online updates (adaptive conformal levels, windows, radii)
        then continue within the episode only, so an episode depends on its seed alone,
        not on which episodes ran before it in this wrapper. ``"persistent"``: the
        calibration carries over between episodes.
    adaptive_epsilon
        With ``risk="dr_cvar"`` and a numeric ``epsilon``: the radius per look-ahead step
        is calibrated online (:class:`filters.calibration.AdaptiveRadius`), a conformal
        quantile, moved by adaptive conformal inference, of the radius each observed
        obstacle position needed to lie within the DR-CVaR bound of its prediction, at
        miscoverage ``alpha``; ``epsilon`` is then the smallest radius and the radius
        before any data (``epsilon=0``: the radius follows the data both ways). It widens
        when the predictions understate the noise and comes back down when they do not
        (its guarantee: the filter guide). Ignored for other risks and with
        ``epsilon="auto"``. Default ``False``.

    Raises
    ------
    InvalidParameterError
        (A ``ValueError``.) On a setting out of its range: an unknown ``risk``,
        ``objective``, ``normals``, ``fallback`` or ``calibration_memory``, ``alpha``
        outside (0, 1], a negative, NaN or infinite ``delta`` or ``epsilon``,
        ``intervention_penalty < 0`` ...
    InvalidTypeError
        (A ``TypeError``.) On a flag that is not a bool or a choice that is not a string.
    InvalidArrayError
        On weights or a support that are not finite arrays of the right dimensions.
    """

    risk: str = field(default="dr_cvar", metadata={"choices": RISKS})
    alpha: float = ALPHA
    delta: float = DELTA
    epsilon: float | str = EPSILON
    horizon: int | None = None
    objective: str | None = field(default=None, metadata={"choices": OBJECTIVES})
    later_input_weight: float = 1e-2
    intersample: bool = True
    normals: str | None = field(default=None, metadata={"choices": NORMAL_SOURCES})
    fallback: str = field(default="soft", metadata={"choices": FALLBACKS})
    terminal: bool = True
    stop_time: float = 0.5
    Q: np.ndarray | None = None
    Q_terminal: np.ndarray | None = None
    R: np.ndarray | None = None
    soft: bool = False
    intervention_penalty: float = 0.0
    support: tuple[np.ndarray, np.ndarray] | None = None
    draw_halfspaces: bool = True
    calibration_episodes: int | None = None
    calibration_seed: int = CALIBRATION_SEED
    calibration_memory: str = field(default="episode", metadata={"choices": CALIBRATION_MEMORIES})
    adaptive_epsilon: bool = False

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for f in fields(self):  # the settings with a set of choices (None: the wrapper's)
            value, choices = getattr(self, f.name), f.metadata.get("choices")
            if choices is None or (value is None and f.default is None):
                continue
            if not isinstance(value, str):
                raise InvalidTypeError(f"{f.name} must be a string, one of {choices}, got "
                                       f"{value!r}")
            if value not in choices:
                raise InvalidParameterError(f"{f.name} must be one of {choices}, got {value!r}")
        alpha = check_alpha(self.alpha)
        if self.risk in (*CHANCE_RISKS, "conformal") and alpha >= 1.0:
            raise InvalidParameterError(
                f"alpha must lie in (0, 1) for risk={self.risk!r} (a violation probability), "
                f"got {self.alpha!r}")
        set_(self, "alpha", alpha)
        set_(self, "delta", finite_scalar("delta", self.delta, low=0.0))
        if isinstance(self.epsilon, str) and self.epsilon != "auto":
            raise InvalidParameterError(
                f'epsilon must be a number or "auto" (in m, >= 0), got {self.epsilon!r}')
        set_(self, "epsilon", "auto" if self.epsilon == "auto" else check_epsilon(self.epsilon))
        if self.horizon is not None:
            set_(self, "horizon", integer_at_least("horizon", self.horizon, low=1))
        for name, positive in (("later_input_weight", True), ("stop_time", True),
                               ("intervention_penalty", False)):
            set_(self, name, finite_scalar(name, getattr(self, name), low=0.0, strict=positive))
        for name in _FLAGS:
            if not isinstance(getattr(self, name), bool | np.bool_):
                raise InvalidTypeError(f"{name} must be a bool, got {getattr(self, name)!r}")
            set_(self, name, bool(getattr(self, name)))
        for name in _WEIGHTS:
            if getattr(self, name) is not None:
                set_(self, name, _frozen(name, getattr(self, name), 2))
        if self.support is not None:
            if not isinstance(self.support, tuple | list) or len(self.support) != 2:
                raise InvalidTypeError(f"support must be a pair (V, v), got {self.support!r}")
            set_(self, "support", (_frozen("support V", self.support[0], 2),
                                   _frozen("support v", self.support[1], 1)))
        for name in ("calibration_episodes", "calibration_seed"):
            if getattr(self, name) is not None:
                set_(self, name, integer_at_least(name, getattr(self, name), low=0))

    def calibration(self) -> dict[str, Any] | None:
        """The held-out calibration a wrapper with this config runs at construction.

        ``None`` if it runs none (no conformal margin, no ``epsilon="auto"``, no
        ``adaptive_epsilon`` with ``risk="dr_cvar"``, or ``risk="none"``); else the resolved
        ``calibration_episodes``, ``calibration_seed`` and ``calibration_memory`` (defaults
        filled in), for run keys and records.
        """
        adaptive = self.adaptive_epsilon and self.risk == "dr_cvar" and self.epsilon != "auto"
        if self.risk == "none" or not (self.risk == "conformal" or self.epsilon == "auto"
                                       or adaptive):
            return None
        return {"calibration_episodes": CALIBRATION_EPISODES if self.calibration_episodes is None
                else self.calibration_episodes, "calibration_seed": self.calibration_seed,
                "calibration_memory": self.calibration_memory}

    def to_dict(self) -> dict[str, Any]:
        """The settings as plain JSON values (arrays as nested lists), by field name."""
        def plain(value: Any) -> Any:
            return [plain(v) for v in value] if isinstance(value, tuple) else (
                value.tolist() if isinstance(value, np.ndarray) else value)

        return {f.name: plain(getattr(self, f.name)) for f in fields(self)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], base: FilterConfig | None = None) -> FilterConfig:
        """The config with the settings of ``data`` (e.g. from :meth:`to_dict`), the others
        from ``base`` (default: the defaults).

        Raises
        ------
        InvalidTypeError
            If ``data`` names a setting that is not a field (the message lists them).
        """
        unknown = sorted(set(data) - set(FIELDS))
        if unknown:
            raise InvalidTypeError(f"unknown filter setting(s) {unknown}; the settings of "
                                   f"SafetyFilterWrapper are {list(FIELDS)}")
        return dataclasses.replace(base, **data) if base is not None else cls(**data)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, FilterConfig):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash(json.dumps(self.to_dict(), sort_keys=True))


FIELDS: dict[str, dataclasses.Field] = {f.name: f for f in fields(FilterConfig)}
"""The fields of :class:`FilterConfig`, by name (the wrapper's settings)."""

__all__ = ["CALIBRATION_EPISODES", "CALIBRATION_MEMORIES", "CALIBRATION_SEED", "FALLBACKS",
           "FIELDS", "NORMAL_SOURCES", "OBJECTIVES", "RISKS", "FilterConfig"]

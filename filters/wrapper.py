"""Gymnasium wrapper that passes every action through the DR-CVaR MPC safety filter.

Each step (paper, Section III):

1. the agent's action is the reference planner's proposal; a reference maker
   (:mod:`filters.references`) turns it into a reference trajectory over the horizon;
2. :func:`filters.safe_halfspaces` computes one risk-based safe halfspace per
   obstacle and predicted step from the environment's current prediction samples;
3. :class:`filters.MPCSafetyFilter` solves Problem 2, the input sequence closest to
   the reference that keeps the predicted ego positions inside every halfspace;
4. the first filtered input is applied to the environment.

``risk="none"`` skips 2-3 and applies the proposal with the same bookkeeping, so
filtered and unfiltered runs are compared through the same code path.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any

import gymnasium as gym
import numpy as np

from filters._validation import scalar_in_range
from filters.calibration import OnlineCalibration
from filters.constants import ALPHA, DELTA, EPSILON
from filters.errors import InvalidArrayError, InvalidParameterError, InvalidTypeError
from filters.geometry import Disc
from filters.halfspaces import Halfspaces, safe_halfspaces
from filters.intersample import intersample_rows
from filters.mpc import FilterResult, FilterStatus, MPCSafetyFilter
from filters.mpc.terminal import stopping_terminal_set
from filters.normals import clearest_normals as clearest_normals  # re-exported
from filters.normals import nearside_normals
from filters.protocol import FilterableEnv
from filters.references import (
    Policy,
    PolicyRolloutReference,
    ReferenceMaker,
    hold_action_reference,
)
from filters.risk import CHANCE_RISKS, check_alpha, check_epsilon, check_risk
from filters.risk import RISKS as _METRICS

RISKS: tuple[str, ...] = ("none", *_METRICS)
"""Risk settings accepted by :class:`SafetyFilterWrapper` (``"none"``: pass-through)."""

OBJECTIVES = ("first_input", "trajectory")
"""Filter objectives: the predictive safety filter's, or the paper's Problem 2."""

NORMAL_SOURCES = ("paper", "ego", "nearside", "previous_plan", "clearest")
"""Where the halfspace normals start (they end at the obstacles' sample means)."""

FALLBACKS = ("soft", "paper")
"""What the filter does when the hard QP is infeasible (see :class:`SafetyFilterWrapper`)."""

PASSTHROUGH = "passthrough"
"""Filter status reported when ``risk="none"``."""

NOMINAL_STATUSES = ("optimal", PASSTHROUGH)
"""Statuses of a step where the filter's constraints all held (or no filter ran)."""

FALLBACK_STATUSES = ("soft", "recovery", "shifted", "brake", "error")
"""Statuses of a step where some constraint could not be met: slack, a fallback, bad data."""

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

_MAX_CALIBRATION_STEPS = 10_000
"""Safety cap on the steps of one held-out episode (the environment truncates earlier)."""

_SNAPSHOTS: dict[tuple, OnlineCalibration] = {}
"""Calibrated states of this process, by environment and settings (see ``_snapshot_key``)."""

_MAX_SNAPSHOTS = 32

_PROTOCOL_ATTRIBUTES = (*FilterableEnv.__annotations__, "observe")
"""Everything :class:`filters.protocol.FilterableEnv` asks of ``env.unwrapped``."""


_TIMING_FIELDS = ("solve_time", "halfspace_time", "filter_time", "reference_time")


@dataclass(frozen=True, eq=False)
class FilterReport:
    """What the filter did in one step: ``info["filter"]``.

    Reads like a dict too (``report["status"]``), so ``info`` stays easy to log.

    Attributes
    ----------
    status
        ``"optimal"``, ``"soft"`` (solved with halfspace slack), ``"recovery"`` (arena or
        terminal slack: being brought back), ``"shifted"`` (the paper's fallback: the
        last optimal plan, shifted), ``"brake"`` (last resort), ``"error"`` (bad data:
        braking, see ``error``) or ``"passthrough"`` (``risk="none"``).
    proposed_action, applied_action
        The reference planner's action (clipped to the input box) and the filtered one,
        in m/s².
    intervention
        :math:`\\|u_{applied} - u_{proposed}\\|_2`, in m/s².
    solve_time, halfspace_time, filter_time, reference_time
        Wall times in s: the QP solver call; the halfspaces; halfspaces + QP (the
        filter step); making the reference trajectory. They vary from run to run and
        are left out of equality, so that two runs with the same seed compare equal.
    slack
        Halfspace violations (n_obstacles, T) in m when the QP had slack rows (soft
        mode or recovery; the larger of the two inter-sample rows), else ``None``.
    normals, offsets
        The halfspaces ``normals @ y <= offsets``, shapes (n_obstacles, T, d) and
        (n_obstacles, T); ``None`` when no filter ran.
    planned_states
        The filtered plan's states (T+1, n), or ``None``.
    error
        Why the filter braked on bad numbers (a NaN action, ...), else ``""``.

    Notes
    -----
    A report is immutable: its arrays are read-only and belong to it alone (the wrapper
    copies what the halfspaces and the QP hand it), so a report kept from one step is
    not changed by the next, and ``copy.deepcopy`` returns the report itself.
    """

    status: str
    proposed_action: np.ndarray
    applied_action: np.ndarray
    intervention: float = 0.0
    solve_time: float = 0.0
    halfspace_time: float = 0.0
    filter_time: float = 0.0
    reference_time: float = 0.0
    slack: np.ndarray | None = None
    normals: np.ndarray | None = None
    offsets: np.ndarray | None = None
    planned_states: np.ndarray | None = None
    error: str = ""

    def __post_init__(self) -> None:
        # Built by hand (the wrapper builds its own with read-only copies already): keep
        # the report immutable, whatever the caller does with the arrays it passed.
        for key in ("proposed_action", "applied_action", "slack", "normals", "offsets",
                    "planned_states"):
            value = getattr(self, key)
            if value is not None:
                value = np.array(value, dtype=np.float64)
                value.setflags(write=False)
                object.__setattr__(self, key, value)

    def __getitem__(self, key: str) -> Any:
        if key not in _REPORT_KEYS:
            raise KeyError(key)
        return getattr(self, key)

    def keys(self) -> tuple[str, ...]:
        return _REPORT_KEYS

    def as_dict(self) -> dict[str, Any]:
        """The report as a plain dict."""
        return {key: getattr(self, key) for key in self.keys()}

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, FilterReport):
            return NotImplemented
        for key in self.keys():
            if key in _TIMING_FIELDS:
                continue
            a, b = getattr(self, key), getattr(other, key)
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                if a is None or b is None or not np.array_equal(a, b, equal_nan=True):
                    return False
            elif a != b and not (a != a and b != b):  # NaN == NaN, as for the arrays
                return False
        return True

    __hash__ = None  # type: ignore[assignment]

    def __copy__(self) -> FilterReport:
        return self

    def __deepcopy__(self, memo: dict[int, Any]) -> FilterReport:
        """The report itself: it is immutable (frozen fields, read-only arrays that no one
        else holds), so a copy could not differ from it (SB3's ``DummyVecEnv``
        deep-copies every step's infos)."""
        return self


_REPORT_KEYS: tuple[str, ...] = tuple(f.name for f in fields(FilterReport))
"""The field names of :class:`FilterReport`, computed once (``keys`` runs every step)."""

def _report(status: str, proposed: np.ndarray, applied: np.ndarray, intervention: float,
            solve_time: float = 0.0, halfspace_time: float = 0.0, filter_time: float = 0.0,
            reference_time: float = 0.0, slack: np.ndarray | None = None,
            normals: np.ndarray | None = None, offsets: np.ndarray | None = None,
            planned_states: np.ndarray | None = None, error: str = "") -> FilterReport:
    """A :class:`FilterReport` built without the frozen ``__init__``'s per-field
    ``object.__setattr__`` and array copies (the same object; the arrays given must be
    read-only and the report's own)."""
    report = object.__new__(FilterReport)
    report.__dict__.update({
        "status": status, "proposed_action": proposed, "applied_action": applied,
        "intervention": intervention, "solve_time": solve_time,
        "halfspace_time": halfspace_time, "filter_time": filter_time,
        "reference_time": reference_time, "slack": slack, "normals": normals,
        "offsets": offsets, "planned_states": planned_states, "error": error,
    })
    return report


def _owned(array: np.ndarray | None) -> np.ndarray | None:
    """A read-only float64 copy of ``array`` that only the report holds (``None`` stays)."""
    if array is None:
        return None
    copy = array.astype(np.float64)  # always a copy
    copy.setflags(write=False)
    return copy


class SafetyFilterWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Filter the actions of any policy with the risk-based MPC safety filter.

    Parameters
    ----------
    env
        Environment whose ``unwrapped`` follows :class:`filters.protocol.FilterableEnv`
        (every ``safe_nav_env`` environment does). No wrapper between this one and the
        base environment may change actions: put ``RescaleAction`` (or any other
        ``ActionWrapper``) *outside* ``SafetyFilterWrapper``, so that the filter works
        in the environment's physical units (m/s²).
    risk
        ``"none"`` (pass-through) or a metric of :data:`filters.risk.RISKS`
        (``"mean"``, ``"cvar"``, ``"dr_cvar"``, ``"gaussian_cc"``, ``"moment_dr"``,
        ``"conformal"``). ``"conformal"`` takes its margin per look-ahead step from an
        online split-conformal calibration of the realised positions against the
        predictions (:class:`filters.calibration.ConformalMargin`, 1 m until enough
        data), at miscoverage ``alpha``.
    alpha
        CVaR tail mass in (0, 1]; alpha = 1 gives the mean.
    delta
        Risk bound on the intrusion depth, in m (Definition 2 of the paper), finite.
    epsilon
        Radius of the Wasserstein ball, in m, finite and >= 0 (DR-CVaR only), or
        ``"auto"``: a radius per look-ahead step estimated online from the realised
        against the predicted positions (:class:`filters.calibration.WassersteinRadius`,
        0.05 m until enough data; see ``calibration_episodes``).
    horizon
        Filter horizon T in steps; at most the environment's prediction horizon.
        ``None`` uses the prediction horizon.
    objective
        ``None`` (default): ``"trajectory"`` when a ``policy`` or ``reference`` gives a
        planned route, ``"first_input"`` when only the held action is known.
        ``"first_input"``: the predictive safety filter of Wabersich &
        Zeilinger, :math:`\\min \\|u_0 - a\\|^2_R + \\eta \\sum_{t \\ge 1}
        \\|u_t - u^r_t\\|^2_R` with no state tracking: the proposed action ``a`` is
        changed as little as possible, the rest of the plan only has to exist.
        ``"trajectory"``: the paper's Problem 2, tracking the reference states and inputs
        with ``Q``, ``Q_terminal`` and ``R``. With the held action as reference the
        tracking objective chases states far outside the arena and deadlocks (measured:
        no goal reached in 100 episodes of the shipped PPO); with a planner's roll-out it
        follows the planned route closely.
    later_input_weight
        :math:`\\eta > 0` of the first-input objective (default 0.01).
    intersample
        Add the inter-sample rows of :mod:`filters.intersample` (default ``True``): the
        plan is then safe in continuous time, between the samples too, not only at them.
    normals
        Where the halfspace normals start (they end at the obstacles' sample means).
        ``None`` (default): ``"paper"`` with a ``policy`` or ``reference``,
        ``"clearest"`` with the held action (whose reference runs straight through
        obstacles, so that the paper's normals flip inside the horizon and the filter
        brakes in front of a head-on obstacle). ``"paper"`` (the reference positions,
        the paper's Definition 3), ``"ego"`` (the current ego position for every step:
        they cannot flip when the reference runs through an obstacle, but block
        overtaking), ``"nearside"`` (the reference position while it is on the ego's
        side of the obstacle's centre, the ego's position once it has passed it),
        ``"previous_plan"`` (the last filtered plan shifted by one step, starting at the
        current position; the reference until there is one) or ``"clearest"`` (the
        first step from the ego's position; each later step from whichever of the
        reference and the last optimal plan is farther from the obstacle, so that the
        normals follow the plan where the reference runs through an obstacle and do not
        flip; ``"nearside"`` while there is no optimal plan; see
        :func:`filters.normals.clearest_normals`).
    fallback
        ``"soft"`` (default): when the hard QP is infeasible, the exact-penalty QP with
        halfspace and arena rows softened (it equals the hard solution whenever that is
        feasible), which brings the ego back towards safety and into the arena;
        ``"paper"``: the paper's Remark, the last optimal plan shifted, then braking.
    terminal
        Add the terminal condition that the plan ends able to stop inside the arena
        (:func:`filters.mpc.terminal.stopping_terminal_set`, ``stop_time`` in s), so
        plans stay recursively feasible against the arena (default ``True``).
    stop_time
        The terminal set's :math:`c` in s (>= dt/2; default 0.5 s).
    Q, Q_terminal, R
        Filter weights on state deviation (n, n), terminal state deviation (n, n)
        and input deviation (m, m). Defaults are the authors' effective weights
        4 I, 25 I and I (DESIGN.md); the first-input objective uses ``R`` only.
    policy
        If given, the reference is the policy rolled out over the horizon on the
        obstacles' predicted mean motion (:class:`filters.references.PolicyRolloutReference`);
        otherwise the proposed action is held over the horizon.
    compiled_rollout
        Deprecated and ignored (the roll-out has one implementation); passing it warns.
    reference
        A custom reference maker ``(env, action, horizon) -> (states, inputs)``;
        overrides ``policy``.
    soft
        Always solve with slack variables (exact L1 penalty) on the halfspace rows; the
        slack is reported.
    intervention_penalty
        Subtracted from the reward times ``||u_safe - u_ref||^2`` (for training with
        the filter in the loop); 0 leaves the reward untouched.
    support
        Optional polytope ``(V, v)`` bounding the obstacle positions (Proposition 1).
    calibration_episodes
        Held-out episodes run at construction to calibrate ``risk="conformal"`` and
        ``epsilon="auto"`` (split conformal: calibrate on held-out data, then run), so
        that the margins and radii come from data from step 0 instead of their
        fallbacks (1 m, 0.05 m). The wrapped environment is reset with the seeds
        ``calibration_seed + i``, ``i = 0..calibration_episodes-1``, and the ego brakes
        (the obstacles' motion and the predictions do not depend on the ego's actions;
        an episode that ends early is followed by the next seed); every step's
        predictions and realised positions are fed to the calibration, as in the loop.
        ``None`` (default): :data:`CALIBRATION_EPISODES` when the wrapper calibrates
        (``risk="conformal"``, or ``epsilon="auto"`` with a filtering risk), else 0;
        ``0``: no held-out data. The environment's seed state is restored afterwards
        (an unseeded ``reset`` stays unseeded); with ``options={"scenario": ...}`` at a
        later reset, the calibration still describes the constructor's scenario.
        :attr:`calibration_time` is the wall time spent, in s.
    calibration_seed
        First held-out seed, an integer ``>= 0`` (default :data:`CALIBRATION_SEED`;
        keep it away from the seeds you evaluate on).
    calibration_memory
        ``"episode"`` (default): each ``reset`` restores (a copy of) the state
        calibrated at construction; the online updates (adaptive conformal levels,
        windows, radii) then continue within the episode only, so an episode depends on
        its seed alone, not on which episodes ran before it in this wrapper.
        ``"persistent"``: the calibration carries over between episodes (the behaviour
        before ``calibration_memory`` existed, with ``calibration_episodes=0``).

    fast_path
        Deprecated, ignored: the wrapper has one per-step path (the halfspaces, the
        reference and the MPC step have one implementation each).

    Raises
    ------
    InvalidParameterError
        (A ``ValueError``.) On any setting out of its range: an unknown ``risk``,
        ``objective``, ``normals`` or ``fallback``, ``alpha`` outside (0, 1], a NaN or
        infinite ``delta``, a negative or NaN ``epsilon``, a ``horizon`` longer than the
        predictions, ``intervention_penalty < 0`` ...
    InvalidTypeError
        (A ``TypeError``.) If ``env.unwrapped`` lacks the protocol, a wrapper in between
        changes actions, or ``policy``/``reference`` cannot be called.

    Notes
    -----
    ``info["filter"]`` is a :class:`FilterReport`: the status, the proposed and the
    applied action, the intervention size, the timings, the slack and the halfspaces
    (safe side ``normals @ y <= offsets``). Statuses: ``"optimal"``; ``"soft"`` (some
    halfspace violated with slack, as little as possible); ``"recovery"`` (the arena or
    the terminal condition violated with slack: the ego is brought back);
    ``"shifted"``/``"brake"`` (``fallback="paper"``, or a recovery QP that failed);
    ``"error"`` (bad data such as a NaN action or NaN predictions: the ego brakes and
    ``error`` says why); ``"passthrough"`` (``risk="none"``). A failed or infeasible
    solve never raises.
    """

    def __init__(
        self,
        env: gym.Env,
        risk: str = "dr_cvar",
        alpha: float = ALPHA,
        delta: float = DELTA,
        epsilon: float | str = EPSILON,
        horizon: int | None = None,
        *,
        objective: str | None = None,
        later_input_weight: float = 1e-2,
        intersample: bool = True,
        normals: str | None = None,
        fallback: str = "soft",
        terminal: bool = True,
        stop_time: float = 0.5,
        Q: np.ndarray | None = None,
        Q_terminal: np.ndarray | None = None,
        R: np.ndarray | None = None,
        policy: Policy | None = None,
        reference: ReferenceMaker | None = None,
        soft: bool = False,
        intervention_penalty: float = 0.0,
        support: tuple[np.ndarray, np.ndarray] | None = None,
        draw_halfspaces: bool = True,
        calibration_episodes: int | None = None,
        calibration_seed: int = CALIBRATION_SEED,
        calibration_memory: str = "episode",
        compiled_rollout: bool | None = None,
        fast_path: bool | None = None,
    ) -> None:
        # No deep copy: policies and planners hold solver and torch state.
        gym.utils.RecordConstructorArgs.__init__(
            self, _disable_deepcopy=True, risk=risk, alpha=alpha, delta=delta,
            epsilon=epsilon, horizon=horizon, objective=objective,
            later_input_weight=later_input_weight, intersample=intersample, normals=normals,
            fallback=fallback, terminal=terminal, stop_time=stop_time, Q=Q,
            Q_terminal=Q_terminal, R=R, policy=policy, reference=reference, soft=soft,
            intervention_penalty=intervention_penalty, support=support,
            draw_halfspaces=draw_halfspaces, calibration_episodes=calibration_episodes,
            calibration_seed=calibration_seed, calibration_memory=calibration_memory,
            compiled_rollout=compiled_rollout, fast_path=fast_path,
        )
        gym.Wrapper.__init__(self, env)
        self._unwrapped: FilterableEnv = env.unwrapped  # type: ignore[assignment]
        missing = [a for a in _PROTOCOL_ATTRIBUTES if not hasattr(env.unwrapped, a)]
        if missing:
            raise InvalidTypeError(
                f"env.unwrapped ({type(env.unwrapped).__name__}) lacks {missing} of the "
                "filters.protocol.FilterableEnv protocol"
            )
        _check_no_action_wrapper(env)
        self.risk = _choice("risk", risk, RISKS)
        if self.risk != "none":
            check_risk(self.risk)
        self.alpha = check_alpha(alpha)
        if self.risk in (*CHANCE_RISKS, "conformal") and self.alpha >= 1.0:
            raise InvalidParameterError(
                f"alpha must lie in (0, 1) for risk={self.risk!r} (a violation probability), "
                f"got {alpha!r}"
            )
        self.epsilon: float | str = "auto" if epsilon == "auto" else check_epsilon(epsilon)
        self.delta = scalar_in_range("delta", delta, low=-np.inf, high=np.inf,
                                     low_inclusive=False, high_inclusive=False)
        planned = policy is not None or reference is not None
        self.objective = _choice(
            "objective", ("trajectory" if planned else "first_input") if objective is None
            else objective, OBJECTIVES,
        )
        self.normals = _choice(
            "normals", ("paper" if planned else "clearest") if normals is None else normals,
            NORMAL_SOURCES,
        )
        self.fallback = _choice("fallback", fallback, FALLBACKS)
        self.later_input_weight = scalar_in_range(
            "later_input_weight", later_input_weight, low=0.0, high=np.inf,
            low_inclusive=False, high_inclusive=False,
        )
        for name, flag in (("intersample", intersample), ("terminal", terminal),
                           ("soft", soft), ("draw_halfspaces", draw_halfspaces)):
            if not isinstance(flag, (bool, np.bool_)):
                raise InvalidTypeError(f"{name} must be a bool, got {flag!r}")
        for name, value in (("compiled_rollout", compiled_rollout), ("fast_path", fast_path)):
            if value is not None:
                warnings.warn(f"SafetyFilterWrapper({name}=...) is deprecated and ignored: the "
                              "wrapper has one per-step path", DeprecationWarning, stacklevel=2)
        self.intersample, self.terminal = bool(intersample), bool(terminal)
        self._rows = 2 if self.intersample else 1  # rows_per_obstacle, read every step
        self.soft, self.draw_halfspaces = bool(soft), bool(draw_halfspaces)
        self.intervention_penalty = scalar_in_range(
            "intervention_penalty", intervention_penalty, low=0.0, high=np.inf,
            high_inclusive=False,
        )
        self.support = support
        base = self._base
        self.stop_time = scalar_in_range(
            "stop_time", stop_time, low=0.5 * float(base.dt), high=np.inf,
            high_inclusive=False,
        )
        prediction_horizon = int(getattr(base, "horizon", np.shape(base.predictions)[2]))
        self.horizon = prediction_horizon if horizon is None else horizon
        if (isinstance(self.horizon, bool) or not isinstance(self.horizon, int | np.integer)
                or not 1 <= self.horizon <= prediction_horizon):
            raise InvalidParameterError(
                f"horizon must be an integer in [1, {prediction_horizon}] (the environment's "
                f"prediction horizon), got {horizon!r}"
            )
        self.horizon = int(self.horizon)
        if reference is not None:
            if not callable(reference):
                raise InvalidTypeError(f"reference must be callable, got {reference!r}")
            self.reference: ReferenceMaker = reference
        elif policy is not None:
            self.reference = PolicyRolloutReference(policy)
        else:
            self.reference = hold_action_reference
        A, B, _ = base.dynamics
        n, m = A.shape[0], B.shape[1]
        self._weights = (
            4.0 * np.eye(n) if Q is None else np.asarray(Q, dtype=float),
            25.0 * np.eye(n) if Q_terminal is None else np.asarray(Q_terminal, dtype=float),
            np.eye(m) if R is None else np.asarray(R, dtype=float),
        )
        self.calibration_memory = _choice("calibration_memory", calibration_memory,
                                          CALIBRATION_MEMORIES)
        self.calibration_seed = _count("calibration_seed", calibration_seed)
        episodes = None if calibration_episodes is None else _count(
            "calibration_episodes", calibration_episodes)
        self._calibration: OnlineCalibration | None = None
        self._calibrated: OnlineCalibration | None = None  # the state each episode starts from
        self.calibration_episodes = 0
        self.calibration_time = 0.0
        if self.risk == "conformal" or self.epsilon == "auto":
            # alpha is the conformal miscoverage; with epsilon="auto" alone it is unused
            self._calibration = OnlineCalibration(
                self.horizon, self.alpha if self.risk == "conformal" else 0.2
            )
            if self.risk != "none":
                self.calibration_episodes = CALIBRATION_EPISODES if episodes is None else episodes
        self._mpc: MPCSafetyFilter | None = None
        self._previous_normals: np.ndarray | None = None
        self._halfspaces_made: Halfspaces | None = None  # the last step's halfspaces
        self._last_plan: np.ndarray | None = None
        self._plan_optimal = False  # whether _last_plan met every row (status "optimal")
        self._hook: Callable[[Any], None] | None = None
        self._halfspace_lines: Any = None  # the hook's line collection, reused per frame
        self._shape_cache: tuple[tuple, Disc, list[Disc]] | None = None
        if self.risk != "none":  # builds (and so validates) the weights and bounds now
            self._mpc = self._build_filter(max(1, len(np.asarray(base.obstacle_radii))))
        if self._calibration is not None:
            self._warm_up_calibration()

    @property
    def _base(self) -> FilterableEnv:
        return self._unwrapped

    @property
    def _last_halfspaces(self) -> Halfspaces | None:
        """The last filtered step's :class:`~filters.halfspaces.Halfspaces` (for drawing)."""
        return self._halfspaces_made

    @property
    def rows_per_obstacle(self) -> int:
        """Halfspace rows per obstacle and step: 2 with the inter-sample rows, else 1."""
        return 2 if self.intersample else 1

    def _build_filter(self, n_obstacles: int) -> MPCSafetyFilter:
        base = self._base
        A, B, C = base.dynamics
        Q, Q_terminal, R = self._weights
        terminal_set = None
        if self.terminal:
            terminal_set = stopping_terminal_set(
                float(base.dt), base.input_bounds, base.position_bounds,
                stop_time=self.stop_time,
            )
        rows = max(n_obstacles, int(getattr(base, "max_obstacles", 0)))
        return MPCSafetyFilter(
            A, B, C, horizon=self.horizon, Q=Q, Q_terminal=Q_terminal, R=R,
            input_bounds=base.input_bounds, position_bounds=base.position_bounds,
            n_obstacles=self.rows_per_obstacle * rows, soft=self.soft,
            objective=self.objective, later_input_weight=self.later_input_weight,
            terminal_set=terminal_set, fallback=self.fallback,
        )

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        if self._mpc is not None:
            self._mpc.reset()
        if self._calibration is not None:
            if self.calibration_memory == "episode":
                self._calibration = self._calibrated.copy()
            self._calibration.reset()
            self._calibrate()
        self._previous_normals = None
        self._halfspaces_made = None
        self._last_plan = None
        self._plan_optimal = False
        self._install_render_hook()
        return obs, info

    def step(self, action: Any):
        """Filter ``action`` (accelerations in m/s², shape (2,)) and step the environment.

        Raises
        ------
        InvalidArrayError
            If ``action`` is not numeric or has another number of entries (a scalar is
            not broadcast to both axes).
        """
        low, high = self._unwrapped.input_bounds
        raw = _action_array(action, np.shape(low))
        # np.clip's result (NaN stays NaN) without its per-call overhead; a fresh array
        proposed = np.minimum(np.maximum(raw, low), high)
        proposed.setflags(write=False)
        if self.risk == "none":
            report = self._passthrough_report(proposed)
            applied = proposed
        else:
            finite = all(map(math.isfinite, raw.tolist()))
            applied, report = self._filter(proposed, finite=finite)
        obs, reward, terminated, truncated, info = self.env.step(applied.astype(np.float32))
        if self._calibration is not None:
            self._calibrate()
        if self.intervention_penalty:
            reward = float(reward) - self.intervention_penalty * report.intervention**2
        info["filter"] = report
        return obs, reward, terminated, truncated, info

    # ------------------------------------------------------------------ internals
    def _calibrate(self) -> None:
        """Score the realised obstacle positions against the predictions issued for now."""
        base = self._base
        predictions = np.asarray(base.predictions, dtype=float)[:, :, : self.horizon]
        if np.all(np.isfinite(predictions)):
            self._calibration.update(predictions, np.asarray(base.obstacle_positions))

    def _warm_up_calibration(self) -> None:
        """Feed ``calibration_episodes`` held-out braking episodes to the calibration.

        Sets the state every episode starts from (``calibration_memory="episode"``) and
        :attr:`calibration_time`. The base environment is driven directly (the wrappers
        in between keep no record of these episodes); its seed state and render mode
        are restored afterwards.
        """
        begin = time.perf_counter()
        key = self._snapshot_key() if self.calibration_episodes else None
        if key is not None and key in _SNAPSHOTS:
            self._calibration = _SNAPSHOTS[key].copy()
            self._calibrated = _SNAPSHOTS[key].copy()
            self.calibration_time = time.perf_counter() - begin
            return
        base = self._base
        saved = {name: getattr(base, name) for name in ("_np_random", "_np_random_seed",
                                                         "render_mode") if hasattr(base, name)}
        try:
            if "render_mode" in saved:
                base.render_mode = None  # no window or trail for held-out episodes
            for episode in range(self.calibration_episodes):
                base.reset(seed=self.calibration_seed + episode)
                self._calibration.reset()
                self._calibrate()
                for _ in range(_MAX_CALIBRATION_STEPS):
                    brake = self._mpc.braking_input(np.asarray(base.ego_state, dtype=float))
                    _, _, terminated, truncated, _ = base.step(brake.astype(np.float32))
                    self._calibrate()
                    if terminated or truncated:
                        break
        finally:
            for name, value in saved.items():
                setattr(base, name, value)
        self._calibration.reset()
        if self.epsilon == "auto" and self.calibration_episodes:
            self._calibration.radii()  # the bootstrap runs once here, not in every episode
        self._calibrated = self._calibration.copy()
        if key is not None:
            if len(_SNAPSHOTS) >= _MAX_SNAPSHOTS:
                del _SNAPSHOTS[next(iter(_SNAPSHOTS))]
            _SNAPSHOTS[key] = self._calibration.copy()
        self.calibration_time = time.perf_counter() - begin

    def _snapshot_key(self) -> tuple | None:
        """What determines the held-out calibration, or ``None`` if it cannot be told.

        The held-out episodes depend only on the environment's construction (its
        ``gym.make`` id and keywords: the scenario, noise, predictor, samples ...; the
        ego's braking follows from its dynamics and bounds), the seeds, the horizon and
        the calibration's settings. When the keywords are plain values (numbers, strings,
        frozen dataclasses of them, as the scenarios, noise models and stress cases are),
        the calibrated state is computed once per process and copied to every wrapper
        of the same environment and settings (the evaluation builds one wrapper per
        episode). Anything else (a callable predictor, an environment not made by
        ``gym.make``) gives ``None``: no sharing.
        """
        base = self._base
        spec = getattr(base, "spec", None)
        kwargs = _plain_settings(dict(spec.kwargs)) if spec is not None else None
        if kwargs is None:
            return None
        return (type(base).__module__, type(base).__qualname__, spec.id, kwargs,
                _plain_settings(spec.max_episode_steps), self.horizon,
                self._calibration.conformal.alpha, self.epsilon == "auto",
                self.calibration_episodes, self.calibration_seed)

    def _risk_options(self) -> dict[str, Any]:
        """Risk settings of this step (the calibrated ones per look-ahead step)."""
        options: dict[str, Any] = dict(risk=self.risk, alpha=self.alpha, delta=self.delta,
                                       epsilon=self.epsilon)
        if self.epsilon == "auto":
            options["epsilon"] = self._calibration.radii()
        if self.risk == "conformal":
            options["conformal_margins"] = self._calibration.margins()
        return options

    @staticmethod
    def _passthrough_report(proposed: np.ndarray) -> FilterReport:
        return _report(PASSTHROUGH, proposed, proposed, 0.0)

    def _filter(self, proposed: np.ndarray, *, finite: bool) -> tuple[np.ndarray, FilterReport]:
        base = self._unwrapped
        x0 = np.asarray(base.ego_state, dtype=float)
        radii = np.asarray(base.obstacle_radii, dtype=float)
        mpc = self._mpc
        if mpc is None or self._rows * radii.shape[0] > mpc.n_obstacles:
            mpc = self._mpc = self._build_filter(len(radii))
        begin = time.perf_counter()
        try:
            if not finite:
                raise InvalidParameterError(f"the proposed action is not finite: {proposed}")
            ref_states, ref_inputs = self.reference(base, proposed, self.horizon)
            start = time.perf_counter()
            normals, offsets, rows = self._halfspaces(base, x0, ref_states, radii)
            middle = time.perf_counter()
            result: FilterResult = mpc.solve(x0, ref_states, rows, reference_inputs=ref_inputs)
        except (ValueError, TypeError, FloatingPointError) as exc:
            # Bad numbers from the policy or the predictions (NaN, inf): brake, say why.
            applied = np.clip(mpc.braking_input(x0), *base.input_bounds)
            applied.setflags(write=False)
            self._last_plan = None
            self._plan_optimal = False
            report = _report(
                FilterStatus.ERROR.value, proposed, applied,
                intervention=_distance(applied, proposed),
                reference_time=time.perf_counter() - begin,
                error=f"{type(exc).__name__}: {exc}",
            )
            return applied, report
        end = time.perf_counter()
        states = result.states
        applied = _owned(result.inputs[0])
        self._previous_normals = normals
        self._last_plan = states
        self._plan_optimal = result.status is FilterStatus.OPTIMAL
        slack = result.slack
        if slack is not None:
            k = normals.shape[0]
            # per obstacle and step (the larger of the two inter-sample rows)
            slack = _owned(np.maximum(slack[:k], slack[k : 2 * k]) if self.intersample
                           else slack[:k])
        report = _report(
            result.status.value, proposed, applied, _distance(applied, proposed),
            float(result.solve_time), middle - start, end - start, start - begin, slack,
            _owned(normals), _owned(offsets), _owned(states),
        )
        return applied, report

    def _normal_origins(self, y0: np.ndarray, ref_positions: np.ndarray) -> np.ndarray:
        """Positions ``(T, d)`` the normals start from (see ``normals``); ``y0 = C x0``."""
        if self.normals == "ego":
            return np.broadcast_to(y0, ref_positions.shape)
        plan = self._last_plan
        if self.normals == "previous_plan" and plan is not None:
            # (T+1, d) planned at the last step, shifted and re-anchored
            return _shifted_positions(plan @ self._base.dynamics[2].T, y0)
        return ref_positions

    def _clearest_plan(self, y0: np.ndarray) -> np.ndarray | None:
        """The last plan's positions shifted to start at ``y0`` ``(T, d)``, if that step
        was optimal, else ``None`` (the plan of ``normals="clearest"``)."""
        if self._last_plan is None or not self._plan_optimal:
            return None
        return _shifted_positions(self._last_plan @ self._base.dynamics[2].T, y0)

    def _halfspaces(
        self, base: FilterableEnv, x0: np.ndarray, ref_states: np.ndarray, radii: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """The step's halfspaces ``(normals, offsets)`` and the QP's rows (with the
        inter-sample rows, if set); the halfspaces are kept for :attr:`_last_halfspaces`.

        The normals start at :meth:`_normal_origins` (``"nearside"``, ``"clearest"``: the
        rules of :mod:`filters.normals`); :func:`filters.safe_halfspaces` gives the
        offsets, :func:`filters.intersample_rows` the inter-sample rows.
        """
        predictions = np.asarray(base.predictions, dtype=float)
        if predictions.ndim != 4 or predictions.shape[2] < self.horizon:
            raise InvalidParameterError(
                f"the filter horizon {self.horizon} exceeds the prediction horizon "
                f"of the environment (predictions of shape {predictions.shape}, expected "
                "(n_obstacles, n_samples, T, d))"
            )
        samples = predictions[:, :, :self.horizon]
        previous = self._previous_normals
        if previous is not None and previous.shape[0] == len(radii):
            # Last step's normals, shifted by one step to line up with this horizon.
            previous = np.concatenate([previous[:, 1:], previous[:, -1:]], axis=1)
        else:
            previous = None
        ego_shape, obstacle_shapes = self._shapes(float(base.ego_radius), radii)
        C = base.dynamics[2]
        y0 = C @ x0
        origins = self._normal_origins(y0, ref_states[1:, :] @ C.T)
        given = None
        if len(radii) and self.normals in ("nearside", "clearest"):
            if not np.isfinite(samples).all():
                raise InvalidArrayError(
                    "the prediction samples hold NaN or infinite values (at indices "
                    f"{np.argwhere(~np.isfinite(samples))[0].tolist()})")
            given = (nearside_normals(samples, origins, y0) if self.normals == "nearside"
                     else clearest_normals(samples, origins, y0, self._clearest_plan(y0)))
        options = self._risk_options()
        halfspaces = safe_halfspaces(
            origins, samples, ego_shape=ego_shape, obstacle_shapes=obstacle_shapes,
            support=self.support, previous_normals=previous, ego_velocity=x0[2:],
            normals=given, **options)
        self._halfspaces_made = halfspaces
        if not self.intersample:
            return halfspaces.normals, halfspaces.offsets, (halfspaces.normals,
                                                            halfspaces.offsets)
        rows = intersample_rows(
            halfspaces, samples, ego_shape=ego_shape, obstacle_shapes=obstacle_shapes,
            input_bounds=base.input_bounds, dt=float(base.dt), support=self.support, **options)
        return halfspaces.normals, halfspaces.offsets, (rows.normals, rows.offsets)

    def _shapes(self, ego_radius: float, radii: np.ndarray) -> tuple[Disc, list[Disc]]:
        """The ego and obstacle discs, built once per set of radii (not every step)."""
        key = (ego_radius, tuple(radii.tolist()))
        if self._shape_cache is None or self._shape_cache[0] != key:
            self._shape_cache = (key, Disc(ego_radius), [Disc(r) for r in key[1]])
        return self._shape_cache[1], self._shape_cache[2]

    def _install_render_hook(self) -> None:
        hooks = self._base.render_hooks
        if self._hook is not None and self._hook in hooks:
            hooks.remove(self._hook)
        self._hook = None
        if self.draw_halfspaces and self.risk != "none":
            self._hook = self._draw_halfspaces
            hooks.append(self._hook)

    def _draw_halfspaces(self, ax: Any) -> None:
        """Draw the first-step halfspace boundary of every obstacle (one line collection)."""
        halfspaces = self._last_halfspaces
        if halfspaces is None or halfspaces.normals.shape[0] == 0:
            return
        from filters.plotting import draw_halfspaces

        drawn = draw_halfspaces(ax, halfspaces.normals[:, 0], halfspaces.offsets[:, 0],
                                reuse=self._halfspace_lines)
        if drawn is not None:
            self._halfspace_lines = drawn


def _shifted_positions(positions: np.ndarray, y0: np.ndarray) -> np.ndarray:
    """The last plan's positions ``(T+1, d)`` shifted one step: ``(T, d)``, starting at ``y0``.

    Row ``t`` is :math:`y^{prev}_{t+1} - y^{prev}_1 + y_0` (the last row repeated at the
    end): the plan as it continues from the current position.
    """
    shifted = np.concatenate([positions[2:], positions[-1:]], axis=0)
    return shifted - positions[1] + y0


def _choice(name: str, value: object, choices: tuple[str, ...]) -> str:
    """``value`` if it is one of ``choices``, else a clear error naming both."""
    if not isinstance(value, str):
        raise InvalidTypeError(f"{name} must be a string, one of {choices}, got {value!r}")
    if value not in choices:
        raise InvalidParameterError(f"{name} must be one of {choices}, got {value!r}")
    return value


def calibration_settings(
    risk: str,
    epsilon: float | str = EPSILON,
    *,
    calibration_episodes: int | None = None,
    calibration_seed: int = CALIBRATION_SEED,
    calibration_memory: str = "episode",
    **_other: Any,
) -> dict[str, Any] | None:
    """The held-out calibration a :class:`SafetyFilterWrapper` with these keywords runs.

    ``None`` if it runs none (no conformal margin, no ``epsilon="auto"``, or
    ``risk="none"``); else the resolved ``calibration_episodes``, ``calibration_seed``
    and ``calibration_memory`` (defaults filled in), for run keys and records. Other
    wrapper keywords are accepted and ignored, so ``calibration_settings(**kwargs)``
    works on a wrapper's keyword dict. Values are not validated here (the wrapper does).
    """
    if risk == "none" or not (risk == "conformal" or epsilon == "auto"):
        return None
    episodes = CALIBRATION_EPISODES if calibration_episodes is None else calibration_episodes
    return {"calibration_episodes": episodes, "calibration_seed": calibration_seed,
            "calibration_memory": calibration_memory}


def _plain_settings(value: object) -> tuple | None:
    """A hashable canonical form of plain settings, or ``None`` if ``value`` holds others.

    Plain: ``None``, bools, numbers, strings, and tuples, lists, string-keyed dicts and
    frozen dataclasses of plain values (types included, so ``1`` and ``1.0`` differ). A
    dataclass is read through the fields that define its equality (``compare=True``):
    derived caches such as the noise laws' scaled mean array are left out.
    """
    if value is None or isinstance(value, bool | int | float | str):
        return (type(value).__qualname__, value)
    if isinstance(value, tuple | list):
        items = tuple(_plain_settings(item) for item in value)
        return None if any(item is None for item in items) else (type(value).__qualname__, items)
    if isinstance(value, dict):
        if not all(isinstance(name, str) for name in value):
            return None
        items = tuple((name, _plain_settings(value[name])) for name in sorted(value))
        return None if any(item is None for _, item in items) else ("dict", items)
    if (dataclasses.is_dataclass(value) and not isinstance(value, type)
            and value.__dataclass_params__.frozen):
        cls = type(value)
        items = tuple((f.name, _plain_settings(getattr(value, f.name)))
                      for f in dataclasses.fields(value) if f.compare)
        return None if any(item is None for _, item in items) else (
            f"{cls.__module__}.{cls.__qualname__}", items)
    return None


def _count(name: str, value: object) -> int:
    """``value`` as an int if it is an integer ``>= 0`` (not a bool), else a clear error."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
        raise InvalidParameterError(f"{name} must be an integer >= 0, got {value!r}")
    return int(value)


def _action_array(action: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``action`` as a flat float array of ``prod(shape)`` entries, else a clear error.

    A scalar is not broadcast to every axis, and an action of another size is refused,
    as the base environment's ``step`` does (NaN and infinite entries pass: the filter
    answers them with its fallback).

    Raises
    ------
    InvalidArrayError
        If ``action`` is not numeric or does not have ``prod(shape)`` entries.
    """
    try:
        raw = np.asarray(action, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise InvalidArrayError(
            f"action must be a numeric array of shape {shape} (accelerations in m/s²), "
            f"got {action!r}") from exc
    if raw.size != math.prod(shape):
        raise InvalidArrayError(
            f"action must have shape {shape} (one acceleration per axis, in m/s²), got shape "
            f"{np.shape(action)}: {action!r}")
    return raw


def _check_no_action_wrapper(env: gym.Env) -> None:
    """Raise if a wrapper between ``env`` and its base environment changes actions.

    The filter computes the applied action in the base environment's units; a
    ``RescaleAction`` (or any ``ActionWrapper``) in between would transform it again.
    The message says which order works: the action wrapper outside the filter.
    """
    base = env.unwrapped
    layer = env
    while layer is not base:
        changes_space = getattr(layer, "action_space", None) != base.action_space
        if isinstance(layer, gym.ActionWrapper) or changes_space:
            name = type(layer).__name__
            example = {"RescaleAction": "RescaleAction(SafetyFilterWrapper(env), -1.0, 1.0)",
                       "ClipAction": "ClipAction(SafetyFilterWrapper(env))"}.get(
                           name, f"{name}(SafetyFilterWrapper(env), ...)")
            raise InvalidTypeError(
                f"{name} sits between SafetyFilterWrapper and the base environment: put it "
                f"outside the filter instead, {example}. Why: the filter checks and applies "
                "its action in the base environment's physical units (m/s², clipped to the "
                f"input bounds), so a wrapper below it would transform the checked action "
                "again and the applied action would not be the one proved safe; above it, the "
                "wrapper maps the policy's action to m/s² before the filter sees it"
                + (" (SafetyFilterWrapper already clips to the input bounds, so ClipAction "
                   "is not needed at all)" if name == "ClipAction" else ""))
        layer = layer.env


def _distance(a: np.ndarray, b: np.ndarray) -> float:
    """Euclidean distance between two actions (the intervention size, m/s²).

    :math:`\\sqrt{\\sum_i (a_i - b_i)^2}`, summed in index order on floats: the value of
    ``numpy.linalg.norm(a - b)`` without its per-call overhead (to the last bit, or within
    two ulps where numpy's BLAS fuses the multiply-adds of its dot product).
    """
    xs, ys = np.asarray(a, dtype=float).tolist(), np.asarray(b, dtype=float).tolist()
    if len(xs) == 2 == len(ys):  # the usual planar action, the loop below unrolled
        dx, dy = xs[0] - ys[0], xs[1] - ys[1]
        return math.sqrt(dx * dx + dy * dy)
    total = 0.0
    for x, y in zip(xs, ys, strict=True):
        difference = x - y
        total += difference * difference
    return math.sqrt(total)

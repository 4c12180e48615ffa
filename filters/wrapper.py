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

The parts around the wrapper class live in their own modules: its settings and their
checks (:mod:`filters.wrapper_settings`), the report (:mod:`filters.report`), the
per-step halfspace rows (:mod:`filters.halfspace_rows`), the calibration glue
(:mod:`filters.wrapper_calibration`) and the render hook (:mod:`filters.render_hook`).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np

from filters._validation import scalar_in_range
from filters.calibration import OnlineCalibration
from filters.constants import ALPHA, DELTA, EPSILON
from filters.errors import InvalidParameterError, InvalidTypeError
from filters.geometry import Disc
from filters.halfspace_rows import HalfspaceRowsMixin
from filters.halfspaces import Halfspaces
from filters.mpc import FilterResult, FilterStatus, MPCSafetyFilter
from filters.mpc.terminal import stopping_terminal_set
from filters.normals import clearest_normals as clearest_normals  # re-exported
from filters.protocol import FilterableEnv
from filters.references import (
    Policy,
    PolicyRolloutReference,
    ReferenceMaker,
    hold_action_reference,
)
from filters.render_hook import RenderHookMixin
from filters.report import FALLBACK_STATUSES as FALLBACK_STATUSES  # re-exported
from filters.report import NOMINAL_STATUSES as NOMINAL_STATUSES  # re-exported
from filters.report import PASSTHROUGH, FilterReport, _distance, _owned, _report
from filters.risk import CHANCE_RISKS, check_alpha, check_epsilon, check_risk
from filters.wrapper_calibration import _SNAPSHOTS as _SNAPSHOTS  # re-exported
from filters.wrapper_calibration import (
    CALIBRATION_EPISODES,
    CALIBRATION_MEMORIES,
    CALIBRATION_SEED,
    CalibrationMixin,
)
from filters.wrapper_calibration import _plain_settings as _plain_settings  # re-exported
from filters.wrapper_calibration import (  # re-exported
    calibration_settings as calibration_settings,
)
from filters.wrapper_settings import (
    _PROTOCOL_ATTRIBUTES,
    FALLBACKS,
    NORMAL_SOURCES,
    OBJECTIVES,
    RISKS,
    _action_array,
    _check_no_action_wrapper,
    _choice,
    _count,
)


class SafetyFilterWrapper(CalibrationMixin, HalfspaceRowsMixin, RenderHookMixin,
                          gym.Wrapper, gym.utils.RecordConstructorArgs):
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
    adaptive_epsilon
        With ``risk="dr_cvar"`` and a numeric ``epsilon``: the radius per look-ahead step
        is calibrated online (:class:`filters.calibration.AdaptiveRadius`): a conformal
        quantile, moved by adaptive conformal inference, of the radius each observed
        obstacle position needed to lie within the DR-CVaR bound of its prediction for
        every normal, at miscoverage ``alpha``; ``epsilon`` is then the smallest radius
        and the radius before any data (``epsilon=0``: the radius follows the data both
        ways). It widens when the predictions understate the noise and comes back down
        when they do not (its guarantee: the filter guide). Ignored for other risks and
        with ``epsilon="auto"``. Default ``False``.
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
        ``"soft"`` (default): when the hard QP is infeasible, the exact-penalty recovery
        QP with the halfspace rows softened: the least violation, then the plan closest
        to the reference (arena rows softened too only if they cannot hold, which brings
        the ego back into the arena; :mod:`filters.mpc.recovery`); ``"brake"``: the
        same, but the least violation, then the lowest speed;
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
        4 I, 25 I and I (docs/design.md); the first-input objective uses ``R`` only.
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
    The speed limit is ``env.unwrapped.max_speed`` (m/s; ``inf`` or absent: none): every
    QP keeps the plan's velocities in the polygon inscribed in the speed disc
    (:class:`filters.mpc.MPCProblem`), so the environment's own limit never has to
    change the filtered action.

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
        adaptive_epsilon: bool = False,
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
            adaptive_epsilon=adaptive_epsilon, compiled_rollout=compiled_rollout,
            fast_path=fast_path,
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
                           ("soft", soft), ("draw_halfspaces", draw_halfspaces),
                           ("adaptive_epsilon", adaptive_epsilon)):
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
        self.adaptive_epsilon = (bool(adaptive_epsilon) and self.risk == "dr_cvar"
                                 and self.epsilon != "auto")
        if self.risk == "conformal" or self.epsilon == "auto" or self.adaptive_epsilon:
            # alpha is the conformal miscoverage; with epsilon="auto" alone it is unused
            self._calibration = OnlineCalibration(
                self.horizon, self.alpha if self.risk == "conformal" else 0.2,
                **({"adaptive_alpha": self.alpha, "radius_fallback": self.epsilon,
                    "adaptive": {"floor": self.epsilon}} if self.adaptive_epsilon else {}),
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
            max_speed=float(getattr(base, "max_speed", np.inf)),
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

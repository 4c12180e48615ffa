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
checks (:class:`filters.config.FilterConfig`), the checks that need the environment
(:mod:`filters.wrapper_settings`), the report (:mod:`filters.report`), the
per-step halfspace rows (:mod:`filters.halfspace_rows`), the calibration glue
(:mod:`filters.wrapper_calibration`) and the render hook (:mod:`filters.render_hook`).
"""

from __future__ import annotations

import math
import time
import warnings
from typing import Any

import gymnasium as gym
import numpy as np

from filters._validation import scalar_in_range
from filters.calibration import OnlineCalibration
from filters.config import FIELDS, FilterConfig
from filters.config import RISKS as RISKS  # re-exported
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
from filters.wrapper_calibration import _SNAPSHOTS as _SNAPSHOTS  # re-exported
from filters.wrapper_calibration import CalibrationMixin
from filters.wrapper_calibration import _plain_settings as _plain_settings  # re-exported
from filters.wrapper_calibration import (  # re-exported
    calibration_settings as calibration_settings,
)
from filters.wrapper_settings import _PROTOCOL_ATTRIBUTES, _action_array, _check_no_action_wrapper


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
    config
        The filter's settings (:class:`filters.FilterConfig`, which documents each one);
        ``None``: the defaults.
    policy
        If given, the reference is the policy rolled out over the horizon on the
        obstacles' predicted mean motion (:class:`filters.references.PolicyRolloutReference`);
        otherwise the proposed action is held over the horizon.
    reference
        A custom reference maker ``(env, action, horizon) -> (states, inputs)``;
        overrides ``policy``.
    compiled_rollout, fast_path
        Deprecated and ignored (the wrapper has one per-step path); passing them warns.
    **settings
        Fields of :class:`filters.FilterConfig` as keywords (``risk="cvar"``,
        ``alpha=0.1``, ...). They override the same fields of ``config``:
        ``SafetyFilterWrapper(env, config, risk="cvar")`` is
        ``SafetyFilterWrapper(env, dataclasses.replace(config, risk="cvar"))``.

    Attributes
    ----------
    config
        The :class:`filters.FilterConfig` the wrapper was built with (``None`` fields as
        given). Each of its fields is also an attribute of the wrapper, with the ``None``
        ones resolved: ``horizon`` (the prediction horizon), ``objective`` and ``normals``
        (by whether a ``policy`` or ``reference`` gives a planned route),
        ``calibration_episodes`` (0 when the wrapper does not calibrate).

    Raises
    ------
    InvalidParameterError
        (A ``ValueError``.) On any setting out of its range (:class:`filters.FilterConfig`),
        a ``horizon`` longer than the environment's predictions or a ``stop_time`` below
        half its step.
    InvalidTypeError
        (A ``TypeError``.) On an unknown setting, a ``config`` that is not a
        :class:`filters.FilterConfig`, if ``env.unwrapped`` lacks the protocol, a wrapper
        in between changes actions, or ``reference`` cannot be called.

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
        config: FilterConfig | None = None,
        *,
        policy: Policy | None = None,
        reference: ReferenceMaker | None = None,
        compiled_rollout: bool | None = None,
        fast_path: bool | None = None,
        **settings: Any,
    ) -> None:
        if isinstance(config, str):  # the 0.x signature SafetyFilterWrapper(env, "dr_cvar")
            warnings.warn("SafetyFilterWrapper(env, risk) is deprecated: pass risk=... or a "
                          "FilterConfig", DeprecationWarning, stacklevel=2)
            config, settings = None, {"risk": config, **settings}
        if config is not None and not isinstance(config, FilterConfig):
            raise InvalidTypeError(
                f"config must be a FilterConfig or None, got {config!r}: pass the settings as "
                "FilterConfig(risk=..., ...) or as keywords (risk=..., alpha=...)")
        config = FilterConfig.from_dict(settings, base=config)
        for name, value in (("compiled_rollout", compiled_rollout), ("fast_path", fast_path)):
            if value is not None:
                warnings.warn(f"SafetyFilterWrapper({name}=...) is deprecated and ignored: the "
                              "wrapper has one per-step path", DeprecationWarning, stacklevel=2)
        # Enough to make it again; no deep copy: policies and planners hold solver state.
        gym.utils.RecordConstructorArgs.__init__(
            self, _disable_deepcopy=True, config=config, policy=policy, reference=reference)
        gym.Wrapper.__init__(self, env)
        self._unwrapped: FilterableEnv = env.unwrapped  # type: ignore[assignment]
        missing = [a for a in _PROTOCOL_ATTRIBUTES if not hasattr(env.unwrapped, a)]
        if missing:
            raise InvalidTypeError(
                f"env.unwrapped ({type(env.unwrapped).__name__}) lacks {missing} of the "
                "filters.protocol.FilterableEnv protocol"
            )
        _check_no_action_wrapper(env)
        self.config = config
        for name in FIELDS:  # every setting is an attribute; the None ones resolved below
            setattr(self, name, getattr(config, name))
        planned = policy is not None or reference is not None
        if config.objective is None:
            self.objective = "trajectory" if planned else "first_input"
        if config.normals is None:
            self.normals = "paper" if planned else "clearest"
        self.rows_per_obstacle = 2 if self.intersample else 1  # halfspace rows per obstacle
        base = self._unwrapped
        scalar_in_range("stop_time", config.stop_time, low=0.5 * float(base.dt), high=np.inf,
                        high_inclusive=False)
        prediction_horizon = int(getattr(base, "horizon", np.shape(base.predictions)[2]))
        self.horizon = prediction_horizon if config.horizon is None else config.horizon
        if self.horizon > prediction_horizon:
            raise InvalidParameterError(
                f"horizon must be an integer in [1, {prediction_horizon}] (the environment's "
                f"prediction horizon), got {config.horizon!r}"
            )
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
            4.0 * np.eye(n) if config.Q is None else config.Q,
            25.0 * np.eye(n) if config.Q_terminal is None else config.Q_terminal,
            np.eye(m) if config.R is None else config.R,
        )
        self._calibration: OnlineCalibration | None = None
        self._calibrated: OnlineCalibration | None = None  # the state each episode starts from
        held_out = config.calibration()  # None: no held-out episodes
        self.calibration_episodes = 0 if held_out is None else held_out["calibration_episodes"]
        self.calibration_time = 0.0
        self.adaptive_epsilon = (config.adaptive_epsilon and self.risk == "dr_cvar"
                                 and self.epsilon != "auto")
        if self.risk == "conformal" or self.epsilon == "auto" or self.adaptive_epsilon:
            # alpha is the conformal miscoverage; with epsilon="auto" alone it is unused
            self._calibration = OnlineCalibration(
                self.horizon, self.alpha if self.risk == "conformal" else 0.2,
                **({"adaptive_alpha": self.alpha, "radius_fallback": self.epsilon,
                    "adaptive": {"floor": self.epsilon}} if self.adaptive_epsilon else {}),
            )
        self._mpc: MPCSafetyFilter | None = None
        self._previous_normals: np.ndarray | None = None
        self._halfspaces_made: Halfspaces | None = None  # the last step's halfspaces
        self._last_plan: np.ndarray | None = None
        self._plan_optimal = False  # whether _last_plan met every row (status "optimal")
        self._halfspace_lines: Any = None  # the hook's line collection, reused per frame
        self._shape_cache: tuple[tuple, Disc, list[Disc]] | None = None
        if self.risk != "none":  # builds (and so validates) the weights and bounds now
            self._mpc = self._build_filter(max(1, len(np.asarray(base.obstacle_radii))))
        if self._calibration is not None:
            self._warm_up_calibration()

    def _build_filter(self, n_obstacles: int) -> MPCSafetyFilter:
        base = self._unwrapped
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
            report = _report(PASSTHROUGH, proposed, proposed, 0.0)
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
    def _filter(self, proposed: np.ndarray, *, finite: bool) -> tuple[np.ndarray, FilterReport]:
        base = self._unwrapped
        x0 = np.asarray(base.ego_state, dtype=float)
        radii = np.asarray(base.obstacle_radii, dtype=float)
        mpc = self._mpc
        if mpc is None or self.rows_per_obstacle * radii.shape[0] > mpc.n_obstacles:
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

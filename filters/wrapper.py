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

import time
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any

import gymnasium as gym
import numpy as np

from filters.errors import InvalidParameterError, InvalidTypeError
from filters.geometry import Disc
from filters.halfspaces import Halfspaces, safe_halfspaces
from filters.mpc import FilterResult, FilterStatus, MPCSafetyFilter
from filters.mpc.filter import FALLBACKS
from filters.protocol import FilterableEnv
from filters.references import (
    Policy,
    PolicyRolloutReference,
    ReferenceMaker,
    hold_action_reference,
)

RISKS = ("none", "mean", "cvar", "dr_cvar")
"""Risk settings accepted by :class:`SafetyFilterWrapper`."""

PASSTHROUGH = "passthrough"
"""Filter status reported when ``risk="none"``."""

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
        ``"optimal"``, ``"soft"`` (solved with slack), ``"shifted"`` (the paper's
        fallback: the last optimal plan, shifted), ``"brake"`` (last resort) or
        ``"passthrough"`` (``risk="none"``).
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
        Soft mode: halfspace violations (n_obstacles, T) in m; else ``None``.
    normals, offsets
        The halfspaces ``normals @ y <= offsets``, shapes (n_obstacles, T, d) and
        (n_obstacles, T); ``None`` when no filter ran.
    planned_states
        The filtered plan's states (T+1, n), or ``None``.
    error
        Why the filter braked on bad numbers (a NaN action, ...), else ``""``.
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

    def __getitem__(self, key: str) -> Any:
        if key not in self.keys():
            raise KeyError(key)
        return getattr(self, key)

    def keys(self) -> tuple[str, ...]:
        return tuple(f.name for f in fields(self))

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
            elif a != b:
                return False
        return True

    __hash__ = None  # type: ignore[assignment]


class SafetyFilterWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Filter the actions of any policy with the risk-based MPC safety filter.

    Parameters
    ----------
    env
        Environment whose ``unwrapped`` follows :class:`filters.protocol.FilterableEnv`
        (every ``safe_nav_env`` environment does).
    risk
        ``"none"`` (pass-through), ``"mean"``, ``"cvar"`` or ``"dr_cvar"``.
    alpha
        CVaR tail mass in (0, 1]; alpha = 1 gives the mean.
    delta
        Risk bound on the intrusion depth, in m (Definition 2 of the paper).
    epsilon
        Radius of the Wasserstein ball, in m (DR-CVaR only).
    horizon
        Filter horizon T in steps; at most the environment's prediction horizon.
        ``None`` uses the prediction horizon.
    Q, Q_terminal, R
        Filter weights on state deviation (n, n), terminal state deviation (n, n)
        and input deviation (m, m). Defaults are the authors' effective weights
        4 I, 25 I and I (DESIGN.md).
    policy
        If given, the reference is the policy rolled out over the horizon on the
        obstacles' predicted mean motion (:class:`filters.references.PolicyRolloutReference`);
        otherwise the proposed action is held over the horizon.
    reference
        A custom reference maker ``(env, action, horizon) -> (states, inputs)``;
        overrides ``policy``.
    soft
        Use slack variables with an exact L1 penalty on the halfspace rows, so the
        filter is always feasible; the slack is reported.
    intervention_penalty
        Subtracted from the reward times ``||u_safe - u_ref||^2`` (for training with
        the filter in the loop); 0 leaves the reward untouched.
    support
        Optional polytope ``(V, v)`` bounding the obstacle positions (Proposition 1).
    fallback
        When the hard QP fails: ``"soft"`` (the recovery QP, then braking) or
        ``"paper"`` (the last plan shifted, then braking: the paper's Remark); see
        :class:`filters.MPCSafetyFilter`.

    Notes
    -----
    ``info["filter"]`` is a :class:`FilterReport`: the status (``"optimal"``,
    ``"soft"``, ``"shifted"``, ``"brake"`` or ``"passthrough"``), the proposed and the
    applied action, the intervention size, the timings, the slack and the halfspaces
    (safe side ``normals @ y <= offsets``). A failed or infeasible solve never
    raises: the status names the fallback that produced the applied action.
    """

    def __init__(
        self,
        env: gym.Env,
        risk: str = "dr_cvar",
        alpha: float = 0.2,
        delta: float = 0.1,
        epsilon: float = 0.05,
        horizon: int | None = None,
        *,
        Q: np.ndarray | None = None,
        Q_terminal: np.ndarray | None = None,
        R: np.ndarray | None = None,
        policy: Policy | None = None,
        reference: ReferenceMaker | None = None,
        soft: bool = False,
        intervention_penalty: float = 0.0,
        support: tuple[np.ndarray, np.ndarray] | None = None,
        draw_halfspaces: bool = True,
        fallback: str = "soft",
    ) -> None:
        # No deep copy: policies and planners hold solver and torch state.
        gym.utils.RecordConstructorArgs.__init__(
            self, _disable_deepcopy=True, risk=risk, alpha=alpha, delta=delta,
            epsilon=epsilon, horizon=horizon, Q=Q,
            Q_terminal=Q_terminal, R=R, policy=policy, reference=reference, soft=soft,
            intervention_penalty=intervention_penalty, support=support,
            draw_halfspaces=draw_halfspaces, fallback=fallback,
        )
        gym.Wrapper.__init__(self, env)
        missing = [a for a in _PROTOCOL_ATTRIBUTES if not hasattr(env.unwrapped, a)]
        if missing:
            raise InvalidTypeError(
                f"env.unwrapped ({type(env.unwrapped).__name__}) lacks {missing} of the "
                "filters.protocol.FilterableEnv protocol"
            )
        if risk not in RISKS:
            raise InvalidParameterError(f"risk must be one of {RISKS}, got {risk!r}")
        if fallback not in FALLBACKS:
            raise InvalidParameterError(f"fallback must be one of {FALLBACKS}, got {fallback!r}")
        self.fallback = fallback
        if intervention_penalty < 0 or not np.isfinite(intervention_penalty):
            raise InvalidParameterError(
                f"intervention_penalty must be finite and >= 0, got {intervention_penalty!r}"
            )
        self.risk = risk
        self.alpha, self.delta, self.epsilon = alpha, delta, epsilon
        self.support = support
        self.soft = soft
        self.intervention_penalty = float(intervention_penalty)
        self.draw_halfspaces = draw_halfspaces
        base = self._base
        prediction_horizon = int(getattr(base, "horizon", np.shape(base.predictions)[2]))
        self.horizon = int(prediction_horizon if horizon is None else horizon)
        if not 1 <= self.horizon <= prediction_horizon:
            raise InvalidParameterError(
                f"horizon must be in [1, {prediction_horizon}] (the environment's prediction "
                f"horizon), got {horizon!r}"
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
            4.0 * np.eye(n) if Q is None else np.asarray(Q, dtype=float),
            25.0 * np.eye(n) if Q_terminal is None else np.asarray(Q_terminal, dtype=float),
            np.eye(m) if R is None else np.asarray(R, dtype=float),
        )
        self._mpc: MPCSafetyFilter | None = None
        self._previous_normals: np.ndarray | None = None
        self._last_halfspaces: Halfspaces | None = None
        self._hook: Callable[[Any], None] | None = None
        self._shape_cache: tuple[tuple, Disc, list[Disc]] | None = None
        if risk != "none":
            self._mpc = self._build_filter(max(1, len(np.asarray(base.obstacle_radii))))

    @property
    def _base(self) -> FilterableEnv:
        return self.env.unwrapped  # type: ignore[return-value]

    def _build_filter(self, n_obstacles: int) -> MPCSafetyFilter:
        base = self._base
        A, B, C = base.dynamics
        Q, Q_terminal, R = self._weights
        return MPCSafetyFilter(
            A, B, C, horizon=self.horizon, Q=Q, Q_terminal=Q_terminal, R=R,
            input_bounds=base.input_bounds, position_bounds=base.position_bounds,
            n_obstacles=max(n_obstacles, int(getattr(base, "max_obstacles", 0))),
            soft=self.soft, fallback=self.fallback,
        )

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        if self._mpc is not None:
            self._mpc.reset()
        self._previous_normals = None
        self._last_halfspaces = None
        self._install_render_hook()
        return obs, info

    def step(self, action: Any):
        base = self._base
        low, high = base.input_bounds
        proposed = np.clip(np.asarray(action, dtype=float).reshape(-1), low, high)
        if self.risk == "none":
            report = self._passthrough_report(proposed)
            applied = proposed
        else:
            applied, report = self._filter(proposed)
        obs, reward, terminated, truncated, info = self.env.step(applied.astype(np.float32))
        if self.intervention_penalty:
            reward = float(reward) - self.intervention_penalty * report.intervention**2
        info["filter"] = report
        return obs, reward, terminated, truncated, info

    # ------------------------------------------------------------------ internals
    @staticmethod
    def _passthrough_report(proposed: np.ndarray) -> FilterReport:
        return FilterReport(PASSTHROUGH, proposed, proposed)

    def _filter(self, proposed: np.ndarray) -> tuple[np.ndarray, FilterReport]:
        base = self._base
        x0 = np.asarray(base.ego_state, dtype=float)
        radii = np.asarray(base.obstacle_radii, dtype=float)
        if self._mpc is None or len(radii) > self._mpc.n_obstacles:
            self._mpc = self._build_filter(len(radii))
        begin = time.perf_counter()
        try:
            ref_states, ref_inputs = self.reference(base, proposed, self.horizon)
            start = time.perf_counter()
            halfspaces = self._halfspaces(base, x0, ref_states, radii)
            middle = time.perf_counter()
            result: FilterResult = self._mpc.solve(
                x0, ref_states, halfspaces, reference_inputs=ref_inputs
            )
        except (ValueError, TypeError, FloatingPointError) as exc:
            # Bad numbers from the policy or the predictions (NaN, inf): brake, say why.
            applied = np.clip(self._mpc.braking_input(x0), *base.input_bounds)
            report = FilterReport(
                FilterStatus.BRAKE.value, proposed, applied,
                intervention=_distance(applied, proposed),
                reference_time=time.perf_counter() - begin,
                error=f"{type(exc).__name__}: {exc}",
            )
            return applied, report
        end = time.perf_counter()
        applied = np.asarray(result.inputs[0], dtype=float)
        self._previous_normals = halfspaces.normals
        self._last_halfspaces = halfspaces
        report = FilterReport(
            str(result.status.value), proposed, applied,
            intervention=_distance(applied, proposed),
            solve_time=float(result.solve_time),
            halfspace_time=middle - start,
            filter_time=end - start,
            reference_time=start - begin,
            slack=result.slack,
            normals=halfspaces.normals,
            offsets=halfspaces.offsets,
            planned_states=result.states,
        )
        return applied, report

    def _halfspaces(
        self, base: FilterableEnv, x0: np.ndarray, ref_states: np.ndarray, radii: np.ndarray
    ) -> Halfspaces:
        predictions = np.asarray(base.predictions, dtype=float)
        if predictions.shape[2] < self.horizon:
            raise InvalidParameterError(
                f"the filter horizon {self.horizon} exceeds the prediction horizon "
                f"{predictions.shape[2]} of the environment"
            )
        previous = self._previous_normals
        if previous is not None and previous.shape[0] == len(radii):
            # Last step's normals, shifted by one step to line up with this horizon.
            previous = np.concatenate([previous[:, 1:], previous[:, -1:]], axis=1)
        else:
            previous = None
        ego_shape, obstacle_shapes = self._shapes(float(base.ego_radius), radii)
        return safe_halfspaces(
            ref_states[1:, :] @ base.dynamics[2].T,
            predictions[:, :, : self.horizon],
            ego_shape=ego_shape,
            obstacle_shapes=obstacle_shapes,
            risk=self.risk, alpha=self.alpha, delta=self.delta, epsilon=self.epsilon,
            support=self.support, previous_normals=previous, ego_velocity=x0[2:],
        )

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
        """Draw the first-step halfspace of every obstacle as a line, safe side shaded."""
        halfspaces = self._last_halfspaces
        if halfspaces is None or halfspaces.normals.shape[0] == 0:
            return
        from filters.plotting import draw_halfspace

        for normal, offset in zip(halfspaces.normals[:, 0], halfspaces.offsets[:, 0], strict=True):
            draw_halfspace(ax, normal, offset)


def _distance(a: np.ndarray, b: np.ndarray) -> float:
    """Euclidean distance between two actions (the intervention size, m/s²)."""
    return float(np.linalg.norm(np.asarray(a, dtype=float) - np.asarray(b, dtype=float)))

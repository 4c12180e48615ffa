"""Reference trajectories for the safety filter, made from a planner's proposal.

The safety filter (Problem 2 of the paper) needs a reference trajectory
``x^r(t), ..., x^r(t+T)`` to stay close to. A learned policy only proposes one
action per step, so this module turns that proposal into a trajectory:

* :func:`hold_action_reference` holds the proposed action over the horizon.
  Policy-agnostic and cheap; it is what the wrapper uses without a policy.
* :class:`PolicyRolloutReference` rolls the policy itself out over the horizon
  against the obstacles' predicted mean motion (the learned reference planner of
  the paper), without touching the environment's state.

Any callable ``reference(env, action) -> (states (T+1, n), inputs (T, m))`` can be
passed to :class:`filters.SafetyFilterWrapper` instead; ``env`` is the
:class:`filters.protocol.FilterableEnv` behind the wrapper.
"""

from __future__ import annotations

import math
import operator
import warnings
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from filters.errors import InvalidArrayError, InvalidTypeError
from filters.protocol import FilterableEnv

ReferenceMaker = Callable[[FilterableEnv, np.ndarray, int], tuple[np.ndarray, np.ndarray]]
"""Signature of a reference maker: ``(env, proposed_action, horizon) -> (states, inputs)``."""


class Policy(Protocol):
    """Anything with Stable-Baselines3's ``predict``.

    A PPO model, or :class:`agents.MPCReferencePlanner`.
    """

    def predict(
        self, observation: np.ndarray, state: Any = None, episode_start: Any = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, Any]: ...


def hold_action_reference(
    env: FilterableEnv, action: np.ndarray, horizon: int
) -> tuple[np.ndarray, np.ndarray]:
    """Hold ``action`` (clipped to the input box) for ``horizon`` steps from the current state.

    .. math:: u^r_k = \\operatorname{clip}(a, u_{min}, u_{max}),\\quad
              x^r_{k+1} = A x^r_k + B u^r_k,\\quad x^r_0 = x_t.

    With an environment that has ``applied_input`` (a speed limit), :math:`u^r_k` is the
    input the environment would apply for the clipped action at :math:`x^r_k`; it is
    asked only from the first step whose held-action velocity leaves ``env.max_speed``
    (before it the environment applies the clipped action itself), with the state and
    the action as lists of Python floats (indexable like the arrays: the arithmetic on
    floats is what makes this loop cheap).

    A NaN entry of ``action`` stays NaN (``np.clip``'s result).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        States ``(horizon + 1, n)`` (row 0 the current state) and inputs ``(horizon, m)``.

    Raises
    ------
    InvalidArrayError
        If ``action`` does not have one entry per input, ``horizon < 0``, or the
        environment's state, dynamics and input bounds do not fit together.
    """
    A, B, _ = env.dynamics
    A, B = np.asarray(A, dtype=np.float64), np.asarray(B, dtype=np.float64)
    low, high = env.input_bounds
    low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    x0 = np.asarray(env.ego_state, dtype=np.float64)
    u = np.asarray(action, dtype=np.float64).reshape(-1)
    n, m = B.shape if B.ndim == 2 else (-1, -1)
    if u.shape[0] != m or horizon < 0:
        raise InvalidArrayError(
            f"action must have {m} entries and horizon be >= 0, got shape "
            f"{np.shape(action)} and horizon {horizon!r}"
        )
    if A.shape != (n, n) or x0.shape != (n,) or low.shape != (m,) or high.shape != (m,):
        raise InvalidArrayError(
            f"the environment's A {A.shape}, B {B.shape}, state {x0.shape} and input bounds "
            f"{low.shape}, {high.shape} do not fit together"
        )
    u = np.minimum(np.maximum(u, low), high)  # np.clip's result (NaN stays NaN), cheaper
    inputs = np.empty((int(horizon), m))
    inputs[:] = u
    powers, sums, dynamics = _held_maps(A, B, int(horizon))
    states = (powers @ x0 + sums @ u).reshape(int(horizon) + 1, n)
    apply = getattr(env, "applied_input", None)  # the speed limit, if the env has one
    action = u.tolist()
    if apply is None or not all(map(math.isfinite, action)):
        return states, inputs
    rows = states.tolist()  # the held roll-out on floats: x^r_0 .. x^r_T
    first = _first_over_speed_limit(env, rows)
    if first is None:
        return states, inputs  # the env applies u at every step: the held roll-out is it
    # Steps before ``first`` keep the held roll-out (the env applies u there); from it
    # on, the env's applied input at each state, rolled out on Python floats with the
    # rows [A_i | B_i] of x' = [A B] [x; u].
    x = rows[first]
    applied_inputs: list[float] = []  # flat: the entries of u^r_first .. u^r_{T-1}
    rolled: list[float] = []  # flat: the entries of x^r_{first+1} .. x^r_T
    for _ in range(first, int(horizon)):
        applied = np.asarray(apply(x, action), dtype=np.float64).tolist()
        applied_inputs += applied
        xu = x + applied
        x = [sum(map(operator.mul, row, xu)) for row in dynamics]
        rolled += x
    inputs.reshape(-1)[first * m:] = applied_inputs  # (a wrong length raises ValueError)
    states.reshape(-1)[(first + 1) * n:] = rolled
    return states, inputs


def _first_over_speed_limit(env: FilterableEnv, rows: list[list[float]]) -> int | None:
    """The first step ``k`` whose held-action velocity ``v_{k+1}`` (the second half of the
    state ``rows[k + 1]``, :math:`\\|v_{k+1}\\|_2^2 > v_{max}^2`) leaves ``env.max_speed``, or
    ``None`` if every planned velocity keeps it (``inf``: no limit). Before ``k``
    ``applied_input`` returns the clipped action (the protocol's definition), so only the
    steps from ``k`` on need it. Without a ``max_speed`` to check against, 0 (every step
    asks ``applied_input``). ``rows`` are the held roll-out's states ``x^r_0 .. x^r_T`` as
    lists of floats (the first step over the limit is usually among the first few: a
    loop on floats stops there)."""
    limit = getattr(env, "max_speed", None)
    if limit is None:
        return 0
    max_speed = float(limit)
    if math.isinf(max_speed):
        return None
    bound, half = max_speed * max_speed, len(rows[0]) // 2
    for k, state in enumerate(rows[1:]):
        velocity = state[half:]
        if sum(map(operator.mul, velocity, velocity)) > bound:
            return k
    return None


_HELD_MAPS: dict[tuple, tuple[np.ndarray, np.ndarray, list[list[float]]]] = {}
""":func:`_held_maps` by model and horizon (a few entries: one per environment model)."""


def _held_maps(A: np.ndarray, B: np.ndarray,
               horizon: int) -> tuple[np.ndarray, np.ndarray, list[list[float]]]:
    r"""``(P, S, D)``: with rows ``k = 0..T``, :math:`A^k` and :math:`\sum_{j<k} A^j B`, stacked
    ``((T+1) n, n)`` and ``((T+1) n, m)``, so that the held-input roll-out is
    :math:`x_k = A^k x_0 + (\sum_{j<k} A^j B) u` (two products instead of a loop of T); and
    the rows of ``[A B]`` as lists of floats, for the roll-out on floats."""
    key = (A.tobytes(), B.tobytes(), A.shape, B.shape, horizon)
    maps = _HELD_MAPS.get(key)
    if maps is None:
        n, m = B.shape
        powers, sums = np.empty((horizon + 1, n, n)), np.empty((horizon + 1, n, m))
        powers[0], sums[0] = np.eye(n), 0.0
        for k in range(horizon):
            powers[k + 1] = A @ powers[k]
            sums[k + 1] = A @ sums[k] + B
        if len(_HELD_MAPS) >= 16:
            _HELD_MAPS.clear()
        maps = _HELD_MAPS[key] = (powers.reshape(-1, n), sums.reshape(-1, m),
                                  np.hstack([A, B]).tolist())
    return maps


class PolicyRolloutReference:
    """Roll ``policy`` out over the horizon on the obstacles' predicted mean motion.

    .. math::

        u_0 = \\operatorname{clip}(a), \\qquad
        u_k = \\operatorname{clip}\\big(\\pi(\\operatorname{observe}(x_k, \\bar p_{k}, v))\\big)
        \\ (k \\ge 1), \\qquad x_{k+1} = A x_k + B u_k,

    where :math:`a` is the action the agent proposed, :math:`\\pi` the policy's
    deterministic ``predict``, :math:`\\bar p_k` the mean of each obstacle's prediction
    samples for look-ahead step :math:`k` (m), :math:`v` the obstacles' current
    velocities (m/s), ``observe`` the environment's own observation
    (:meth:`filters.protocol.FilterableEnv.observe`: the one definition) and ``clip``
    the input box (m/s², a NaN stays NaN), then, if the environment has
    ``applied_input``, its speed limit. The environment is not stepped.

    Parameters
    ----------
    policy
        Object with a Stable-Baselines3 style ``predict(obs, deterministic=True)``: an SB3
        model, :class:`agents.NumpyPolicy` (the same actor in numpy, several times faster
        per call) or :class:`agents.MPCReferencePlanner`.
    compiled
        Deprecated and ignored (there is one roll-out, this loop); passing it warns.
    """

    def __init__(self, policy: Policy, *, compiled: bool | None = None) -> None:
        if not callable(getattr(policy, "predict", None)):
            raise InvalidTypeError(
                f"policy must have a predict(observation, deterministic=...) method, got {policy!r}"
            )
        if compiled is not None:
            warnings.warn(
                "PolicyRolloutReference(compiled=...) is deprecated and ignored: the roll-out "
                "has one implementation, the predict loop", DeprecationWarning, stacklevel=2)
        self.policy = policy

    def __call__(
        self, env: FilterableEnv, action: np.ndarray, horizon: int
    ) -> tuple[np.ndarray, np.ndarray]:
        A, B, _ = env.dynamics
        low, high = env.input_bounds
        predicted_means = np.asarray(env.predictions).mean(axis=1)  # (n_obstacles, T, d)
        velocities = np.asarray(env.obstacle_velocities)
        states = np.empty((horizon + 1, A.shape[0]))
        inputs = np.empty((horizon, B.shape[1]))
        states[0] = env.ego_state
        inputs[0] = np.clip(action, low, high)
        observe, predict = env.observe, self.policy.predict
        apply = getattr(env, "applied_input", None)  # the speed limit, if the env has one
        for k in range(horizon):
            if k > 0:
                proposal, _ = predict(observe(states[k], predicted_means[:, k - 1], velocities),
                                      deterministic=True)
                inputs[k] = np.clip(np.asarray(proposal, dtype=float).reshape(-1), low, high)
            if apply is not None and np.isfinite(inputs[k]).all():
                inputs[k] = apply(states[k], inputs[k])
            states[k + 1] = A @ states[k] + B @ inputs[k]
        return states, inputs

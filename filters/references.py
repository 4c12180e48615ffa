"""Reference trajectories for the safety filter, made from a planner's proposal.

The safety filter (Problem 2 of the paper) needs a reference trajectory
``x^r(t), ..., x^r(t+T)`` to stay close to. A learned policy only proposes one
action per step, so this module turns that proposal into a trajectory:

* :func:`hold_action_reference` holds the proposed action over the horizon.
  Policy-agnostic and cheap; it is what the wrapper uses during training.
* :class:`PolicyRolloutReference` rolls the policy itself out over the horizon
  against the obstacles' predicted mean motion (the learned reference planner of
  the paper), without touching the environment's state.

Any callable ``reference(env, action) -> (states (T+1, n), inputs (T, m))`` can be
passed to :class:`filters.SafetyFilterWrapper` instead; ``env`` is the
:class:`filters.protocol.FilterableEnv` behind the wrapper.
"""

from __future__ import annotations

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


def rollout(A: np.ndarray, B: np.ndarray, x0: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    """States of ``x_{k+1} = A x_k + B u_k`` from ``x0`` under ``inputs`` (T, m).

    Returns
    -------
    numpy.ndarray
        Shape ``(T+1, n)``, row 0 is ``x0``.
    """
    states = np.empty((inputs.shape[0] + 1, x0.shape[0]))
    states[0] = x0
    for k, u in enumerate(inputs):
        states[k + 1] = A @ states[k] + B @ u
    return states


def hold_action_reference(
    env: FilterableEnv, action: np.ndarray, horizon: int
) -> tuple[np.ndarray, np.ndarray]:
    """Hold ``action`` (clipped to the input box) for ``horizon`` steps from the current state.

    .. math:: u^r_k = \\operatorname{clip}(a, u_{min}, u_{max}),\\quad
              x^r_{k+1} = A x^r_k + B u^r_k,\\quad x^r_0 = x_t.

    One compiled call; the shapes are checked first (the kernel does not check indices).

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
    from filters._reference_kernels import hold  # numba is imported on first use only

    return hold(x0, u, low, high, A, B, int(horizon))


class PolicyRolloutReference:
    """Roll ``policy`` out over the horizon on the obstacles' predicted mean motion.

    Step 0 uses the action the agent proposed; step k >= 1 asks the policy (deterministic)
    for the action it would take at the predicted state, where each obstacle sits at the
    mean of its prediction samples for that step. The environment is not stepped.

    Parameters
    ----------
    policy
        Object with a Stable-Baselines3 style ``predict(obs, deterministic=True)``.
    compiled
        If true (default) and ``policy`` has a method ``rollout_reference(env, action,
        horizon)``, ask it first: it returns the same roll-out computed its own way
        (``agents.NumpyPolicy`` and ``agents.TorchActorPolicy`` run it in one compiled
        kernel, equal to this loop to about 1e-6 m/s² per action), or ``None`` for an
        environment it does not know, and then the loop below runs. ``False``: always
        the loop, calling ``predict`` ``T - 1`` times.
    """

    def __init__(self, policy: Policy, *, compiled: bool = True) -> None:
        if not callable(getattr(policy, "predict", None)):
            raise InvalidTypeError(
                f"policy must have a predict(observation, deterministic=...) method, got {policy!r}"
            )
        if not isinstance(compiled, bool | np.bool_):
            raise InvalidTypeError(f"compiled must be a bool, got {compiled!r}")
        self.policy = policy
        self.compiled = bool(compiled)
        fast = getattr(policy, "rollout_reference", None) if compiled else None
        self._fast = fast if callable(fast) else None

    def __call__(
        self, env: FilterableEnv, action: np.ndarray, horizon: int
    ) -> tuple[np.ndarray, np.ndarray]:
        if self._fast is not None:
            made = self._fast(env, action, horizon)
            if made is not None:
                return made
        A, B, _ = env.dynamics
        low, high = env.input_bounds
        predicted_means = np.asarray(env.predictions).mean(axis=1)  # (n_obstacles, T, d)
        velocities = np.asarray(env.obstacle_velocities)
        states = np.empty((horizon + 1, A.shape[0]))
        inputs = np.empty((horizon, B.shape[1]))
        states[0] = env.ego_state
        inputs[0] = np.clip(action, low, high)
        observe, predict = env.observe, self.policy.predict
        minimum, maximum = np.minimum, np.maximum
        for k in range(horizon):
            if k > 0:
                proposal, _ = predict(observe(states[k], predicted_means[:, k - 1], velocities),
                                      deterministic=True)
                # np.clip's result (NaN stays NaN) at a fraction of its per-call cost
                minimum(maximum(np.asarray(proposal, dtype=float).reshape(-1), low), high,
                        out=inputs[k])
            states[k + 1] = A @ states[k] + B @ inputs[k]
        return states, inputs

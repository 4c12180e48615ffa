"""The policy roll-out reference in one compiled call: observations, actor and dynamics.

:class:`filters.references.PolicyRolloutReference` asks the policy for ``T - 1``
actions at every control step, one after the other: the action at look-ahead ``k``
depends on the state that the action at ``k - 1`` produced, so the calls cannot be
batched. Through Python each call builds an observation, runs the network and steps
the dynamics with a dozen small array operations. :class:`CompiledRollout` does the
whole roll-out in one numba kernel, with the actor's weights exported once:

.. math::

    \\bar p_{i,k} = \\frac{1}{N_s} \\sum_{j=1}^{N_s} \\hat p^{(j)}_{i,k}, \\qquad
    o_k = \\operatorname{observe}(x_k, \\bar p_{\\cdot,k}, v), \\qquad
    u_k = \\operatorname{clip}\\big(c + w \\odot \\pi(o_k), u_{min}, u_{max}\\big), \\qquad
    x_{k+1} = A x_k + B u_k,

for ``k = 1 .. T-1`` (``u_0`` is the proposed action, clipped), where ``\\pi`` is the
deterministic actor (the mean of SB3's Gaussian, clipped to its action box, or the
un-squashed ``tanh``), ``c + w \\odot a`` the map of a policy trained on normalised
actions back to m/s² (:class:`agents.training.wrappers.PhysicalUnitsPolicy`; ``c = 0, w = 1``
otherwise) and ``observe`` the observation of :class:`safe_nav_env.SafeNavEnv` (its
``observe`` method, nearest obstacles first).

Precision. The network runs in float64 from the float32 observation and its mean is
rounded once to float32: the arithmetic of :class:`agents.NumpyPolicy`, up to two
details. Each layer sums its products in input order (numpy's ``@`` may order them
otherwise), and ``tanh`` is :func:`agents.policies.vector_tanh.tanh`, within 2 units in the
last place (2.2e-16) of ``np.tanh``. Both move the float64 mean by a few 1e-15 (the
``tanh`` alone: at most 2.7e-15 on 200,000 random observations of the shipped policy),
far below float32's rounding step (6e-8 relative): the float32 action is the same (all
400,000 there), unless the float64 mean falls that close to a float32 rounding
boundary, and then it differs by one float32 step. The roll-out therefore equals the
Python roll-out with :class:`~agents.NumpyPolicy` to rounding (to 1e-12 m/s² on the
test states), and the one with Stable-Baselines3's ``predict`` (or
:class:`~agents.TorchActorPolicy`), whose float32 arithmetic differs from the exact
float32 network by a few float32 rounding steps, to about 1e-6 m/s² per action. Pass
``compiled=False`` to :class:`~filters.references.PolicyRolloutReference` (or
``compiled_rollout=False`` to the wrapper) for the policy's own ``predict`` at every
step.

Which policies and environments. Actors of SB3's ``MlpPolicy`` (``Linear`` layers with
``Tanh``, ``ReLU``, ``LeakyReLU`` or ``ELU``, a ``FlattenExtractor``, a ``Box`` action
space), exported by :class:`~agents.NumpyPolicy` or read live from the torch
parameters (:class:`~agents.TorchActorPolicy`, an SB3 model); environments whose
``unwrapped`` is a :class:`~safe_nav_env.SafeNavEnv` that does not override its
observation. Anything else makes :func:`compile_rollout` return ``None`` and the
caller falls back to the Python roll-out.

Determinism. The kernel keeps no state between calls (its work arrays are allocated
per call and written before they are read) and sums in a fixed order: the same inputs
give the same bits, whatever ran before; one instance may serve several environments.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit
from numba.core.errors import TypingError

from agents.policies.vector_tanh import tanh
from filters.errors import InvalidArrayError, InvalidParameterError

__all__ = ["ActorNetwork", "CompiledRollout", "compile_rollout", "rollout_reference",
           "supports_env"]

IDENTITY, TANH, RELU, LEAKY_RELU, ELU = 0, 1, 2, 3, 4
"""Activation codes of :class:`ActorNetwork` (``parameters`` holds the slope or alpha)."""

_ACTIVATION_CODES = {"identity": IDENTITY, "tanh": TANH, "relu": RELU,
                     "leaky_relu": LEAKY_RELU, "elu": ELU}


@dataclass(frozen=True, eq=False)
class ActorNetwork:
    """A deterministic MLP actor in the kernel's layout.

    Attributes
    ----------
    weights
        Per affine layer, :math:`W_l^\\top` as float64 ``(inputs, outputs)`` C arrays.
    biases
        Per layer, float64 ``(outputs,)``.
    activations, parameters
        Per layer, the activation code (:data:`IDENTITY`, :data:`TANH`, :data:`RELU`,
        :data:`LEAKY_RELU`, :data:`ELU`; int64) and its parameter (float64: the leaky
        slope or the ELU alpha, else 0).
    squash
        Whether the mean goes through ``tanh`` and is stretched to the action box.
    action_low, action_high
        The policy's action box, float32 ``(m,)``.
    """

    weights: tuple[np.ndarray, ...]
    biases: tuple[np.ndarray, ...]
    activations: np.ndarray
    parameters: np.ndarray
    squash: bool
    action_low: np.ndarray
    action_high: np.ndarray

    @classmethod
    def from_layers(cls, layers: list[tuple[np.ndarray, np.ndarray, str, float]], *,
                    squash: bool, action_low: Any, action_high: Any) -> ActorNetwork:
        """Build from ``(W^T (in, out), b, activation name, parameter)`` per layer.

        Activation names: ``"identity"``, ``"tanh"``, ``"relu"``, ``"leaky_relu"``,
        ``"elu"``. The arrays are copied to float64 (read-only).

        Raises
        ------
        InvalidArrayError
            If the layers do not chain (each layer's outputs the next one's inputs, a
            bias per output) or the action box does not have one entry per output: the
            kernel does not check indices, so the shapes are checked here.
        InvalidParameterError
            For an unknown activation name, or no layer.
        """
        if not layers:
            raise InvalidParameterError("an ActorNetwork needs at least one layer, got none")
        weights, biases = [], []
        for index, (weight, bias, name, _) in enumerate(layers):
            w = np.array(weight, dtype=np.float64, order="C")
            b = np.array(bias, dtype=np.float64)
            inputs = weights[-1].shape[1] if weights else None
            if w.ndim != 2 or b.shape != (w.shape[1],) or inputs not in (None, w.shape[0]):
                raise InvalidArrayError(
                    f"layer {index}: W^T {w.shape} and b {b.shape} must be (inputs, outputs) "
                    f"and (outputs,), with inputs = {inputs} (the previous layer's outputs)")
            if name not in _ACTIVATION_CODES:
                raise InvalidParameterError(
                    f"layer {index}: activation must be one of {sorted(_ACTIVATION_CODES)}, "
                    f"got {name!r}")
            w.setflags(write=False)
            b.setflags(write=False)
            weights.append(w)
            biases.append(b)
        codes = np.array([_ACTIVATION_CODES[name] for _, _, name, _ in layers], dtype=np.int64)
        parameters = np.array([float(p) for _, _, _, p in layers], dtype=np.float64)
        low = np.asarray(action_low, dtype=np.float32).reshape(-1).copy()
        high = np.asarray(action_high, dtype=np.float32).reshape(-1).copy()
        if low.shape != high.shape or low.shape != (weights[-1].shape[1],):
            raise InvalidArrayError(
                f"the action box ({low.shape}, {high.shape}) must have one entry per network "
                f"output ({weights[-1].shape[1]})")
        for array in (codes, parameters, low, high):
            array.setflags(write=False)
        return cls(tuple(weights), tuple(biases), codes, parameters, bool(squash), low, high)

    def __post_init__(self) -> None:
        # The kernel does not check indices: direct construction is checked as
        # from_layers checks (the layers chain, one box entry per output).
        if not (len(self.weights) == len(self.biases) == len(self.activations)
                == len(self.parameters) >= 1):
            raise InvalidArrayError(
                f"an ActorNetwork needs as many weights, biases, activations and parameters "
                f"(at least one layer), got {len(self.weights)}, {len(self.biases)}, "
                f"{len(self.activations)} and {len(self.parameters)}")
        inputs = self.weights[0].shape[0]
        for index, (weight, bias) in enumerate(zip(self.weights, self.biases, strict=True)):
            if weight.ndim != 2 or weight.shape[0] != inputs or bias.shape != weight.shape[1:]:
                raise InvalidArrayError(
                    f"layer {index}: W^T {weight.shape} and b {bias.shape} do not chain "
                    f"(inputs {inputs})")
            inputs = weight.shape[1]
        if np.shape(self.action_low) != (inputs,) or np.shape(self.action_high) != (inputs,):
            raise InvalidArrayError(
                f"the action box ({np.shape(self.action_low)}, {np.shape(self.action_high)}) "
                f"must have one entry per network output ({inputs})")

    @property
    def n_inputs(self) -> int:
        return int(self.weights[0].shape[0])

    @property
    def n_outputs(self) -> int:
        return int(self.weights[-1].shape[1])


# --------------------------------------------------------------------------- the kernel
@njit(error_model="numpy", cache=True)
def _affine(src, weight, dst):
    """``dst[i] = Σ_j src[j] weight[j, i]`` for ``i < outputs``, each sum in input order.

    ``((0 + z_0 w_0i) + z_1 w_1i) + ...``: the loop of a matrix product's definition,
    evaluated four inputs at a time for all outputs (the outputs are the vectorised
    inner loop, so no sum is reordered), or output by output for fewer than 8 outputs.
    """
    n_in, n_out = weight.shape
    if n_out < 8:
        for i in range(n_out):
            a = 0.0
            for j in range(n_in):
                a += src[j] * weight[j, i]
            dst[i] = a
        return
    for i in range(n_out):
        dst[i] = 0.0
    j = 0
    while j + 4 <= n_in:
        z0, z1, z2, z3 = src[j], src[j + 1], src[j + 2], src[j + 3]
        w0, w1, w2, w3 = weight[j], weight[j + 1], weight[j + 2], weight[j + 3]
        for i in range(n_out):
            dst[i] = (((dst[i] + z0 * w0[i]) + z1 * w1[i]) + z2 * w2[i]) + z3 * w3[i]
        j += 4
    while j < n_in:
        zj = src[j]
        wj = weight[j]
        for i in range(n_out):
            dst[i] += zj * wj[i]
        j += 1


@njit(error_model="numpy", cache=True)
def _activate(dst, bias, code, parameter):
    """``dst[i] = σ(dst[i] + b_i)`` for ``i < len(bias)``, ``σ`` by its activation code.

    A function of its own: inlined in the loop over layers, whose arrays change from
    one layer to the next, the ``tanh`` loop does not vectorise.
    """
    n_out = bias.shape[0]
    if code == 1:
        for i in range(n_out):
            dst[i] = tanh(dst[i] + bias[i])
    elif code == 2:
        for i in range(n_out):
            v = dst[i] + bias[i]
            dst[i] = v if v > 0.0 else 0.0
    elif code == 3:
        for i in range(n_out):
            v = dst[i] + bias[i]
            dst[i] = v if v >= 0.0 else parameter * v
    elif code == 4:
        for i in range(n_out):
            v = dst[i] + bias[i]
            dst[i] = v if v > 0.0 else parameter * math.expm1(v)
    else:
        for i in range(n_out):
            dst[i] = dst[i] + bias[i]


@njit(error_model="numpy", cache=True)
def _mlp(obs, values, layout, out, z, work):
    """``out[:] = π(obs)``: float64 network on a float32 observation, float32 box output.

    ``z_{l+1} = σ_l(z_l W_l^T + b_l)`` (the layers as :func:`_pack` packs them in
    ``values`` and ``layout``): each output sums its products in input order (as a
    matrix product's definition; the loop over outputs is the inner one, so it
    vectorises without reordering a sum), then adds the bias; ``tanh`` is the
    vectorisable :func:`agents.policies.vector_tanh.tanh`. ``z`` and ``work`` are float64 work
    arrays at least as long as the widest layer (inputs included), overwritten here
    before they are read.
    """
    for j in range(obs.shape[0]):
        z[j] = np.float64(obs[j])
    src, dst = z, work
    n_layers, squash, parameters_at, box_at = layout[0, 0], layout[0, 1], layout[0, 2], layout[0, 3]
    for layer in range(n_layers):
        n_in, n_out = layout[1 + layer, 0], layout[1 + layer, 1]
        w_at, b_at = layout[1 + layer, 2], layout[1 + layer, 3]
        _affine(src, values[w_at:w_at + n_in * n_out].reshape((n_in, n_out)), dst)
        _activate(dst, values[b_at:b_at + n_out], layout[1 + layer, 4],
                  values[parameters_at + layer])
        src, dst = dst, src
    half, one = np.float32(0.5), np.float32(1.0)
    m = out.shape[0]
    for i in range(m):
        low, high = np.float32(values[box_at + i]), np.float32(values[box_at + m + i])
        if squash:
            # float32(tanh(mean)), then low + 0.5 (s + 1) (high - low) in float32
            s = np.float32(tanh(src[i]))
            out[i] = low + half * (s + one) * (high - low)
        else:
            a = np.float32(src[i])
            if a < low:
                a = low
            if a > high:
                a = high
            out[i] = a


@njit(cache=True)
def _observe(x, positions, velocities, goal, max_obstacles, obs, order, centre):
    """:meth:`safe_nav_env.SafeNavEnv.observe` into ``obs`` (float32, zeroed here).

    Layout ``[p, v, g - p]`` then, nearest obstacle first (stable order on the centre
    distance ``hypot(p_i - p)``), ``[p_i - p, v_i - v, 1]`` per slot.
    """
    px, py, vx, vy = x[0], x[1], x[2], x[3]
    obs[:] = 0.0
    obs[0] = px
    obs[1] = py
    obs[2] = vx
    obs[3] = vy
    obs[4] = goal[0] - px
    obs[5] = goal[1] - py
    n = positions.shape[0]
    if n == 0 or max_obstacles == 0:
        return
    for i in range(n):  # stable insertion sort of the indices by centre distance
        centre[i] = math.hypot(positions[i, 0] - px, positions[i, 1] - py)
        order[i] = i
        k = i
        while k > 0 and centre[order[k - 1]] > centre[i]:
            order[k] = order[k - 1]
            k -= 1
        order[k] = i
    for slot in range(min(n, max_obstacles)):
        i = order[slot]
        base = 6 + 5 * slot
        obs[base] = positions[i, 0] - px
        obs[base + 1] = positions[i, 1] - py
        obs[base + 2] = velocities[i, 0] - vx
        obs[base + 3] = velocities[i, 1] - vy
        obs[base + 4] = 1.0


@njit(error_model="numpy", cache=True)
def _sample_means(predictions, means):
    """``means[i, k] = (1/N_s) Σ_j predictions[i, j, k]`` for ``k < means.shape[1]``.

    ``predictions`` is C-contiguous ``(n, N_s, T, 2)``: each sample's ``(step,
    coordinate)`` row is contiguous, so the sums run over whole rows (vectorised), four
    samples at a time; each mean still adds its samples in sample order,
    ``((0 + p_0) + p_1) + ...``, then divides by ``N_s``.
    """
    n_obstacles, n_samples, horizon = predictions.shape[:3]
    rows = predictions.reshape((n_obstacles, n_samples, 2 * horizon))
    sums = means.reshape((n_obstacles, 2 * means.shape[1]))
    width = sums.shape[1]
    for i in range(n_obstacles):
        total = sums[i]
        for q in range(width):
            total[q] = 0.0
        j = 0
        while j + 4 <= n_samples:
            r0, r1, r2, r3 = rows[i, j], rows[i, j + 1], rows[i, j + 2], rows[i, j + 3]
            for q in range(width):
                total[q] = (((total[q] + r0[q]) + r1[q]) + r2[q]) + r3[q]
            j += 4
        while j < n_samples:
            r0 = rows[i, j]
            for q in range(width):
                total[q] += r0[q]
            j += 1
        for q in range(width):
            total[q] /= n_samples


@njit(error_model="numpy", cache=True)
def _rollout(x0, u0, predictions, velocities, goal, max_obstacles, A, B, low, high, values,
             layout, states, inputs):
    """Fill ``states`` ``(T+1, n)`` and ``inputs`` ``(T, m)``; return a status: ``0``;
    ``k > 0``: the observation at look-ahead ``k`` was not finite (then the arrays are
    partly filled); ``-1``: the shapes do not fit together; ``-2``: the horizon ``T`` is
    above ``T_pred + 1`` (then nothing is written). Indices are not checked in numba, so
    every shape is checked here before any is used.

    The sample means of all look-ahead steps are summed first, sample by sample over
    the contiguous ``(step, coordinate)`` rows of ``predictions``: each mean still adds
    its samples in sample order, as a loop per step would. The network, its box and the
    map of its actions to m/s² are ``values`` and ``layout`` (see :func:`_pack`).
    """
    n_state, m = B.shape
    horizon = inputs.shape[0]
    n_obs = 6 + 5 * max_obstacles  # the SafeNavEnv layout _observe writes
    n_layers = layout[0, 0]
    n_obstacles = predictions.shape[0]
    if (n_state != 4 or A.shape[0] != 4 or A.shape[1] != 4 or x0.shape[0] != 4
            or u0.shape[0] != m or low.shape[0] != m or high.shape[0] != m or n_layers < 1
            or layout.shape[0] != n_layers + 1 or layout[1, 0] != n_obs
            or layout[n_layers, 1] != m or layout[0, 5] != m or inputs.shape[1] != m
            or states.shape[0] != horizon + 1 or states.shape[1] != n_state
            or velocities.shape[0] != n_obstacles or velocities.shape[1] != 2
            or predictions.shape[3] != 2 or goal.shape[0] != 2):
        return -1
    if horizon < 1 or horizon > predictions.shape[2] + 1:
        return -2
    map_at = layout[0, 4]
    means = np.empty((n_obstacles, horizon - 1, 2))  # the sample mean at look-ahead k + 1
    _sample_means(predictions, means)
    width = n_obs
    for layer in range(n_layers):
        width = max(width, layout[1 + layer, 1])
    z = np.empty(width)
    work = np.empty(width)
    obs = np.empty(n_obs, dtype=np.float32)
    action = np.empty(m, dtype=np.float32)
    order = np.empty(n_obstacles, dtype=np.int64)
    distance = np.empty(n_obstacles)
    for i in range(n_state):
        states[0, i] = x0[i]
    for k in range(horizon):
        if k == 0:
            for i in range(m):
                u = np.float64(u0[i])
                if u < low[i]:
                    u = low[i]
                if u > high[i]:
                    u = high[i]
                inputs[0, i] = u
        else:
            _observe(states[k], means[:, k - 1], velocities, goal, max_obstacles, obs, order,
                     distance)
            for i in range(n_obs):
                if not math.isfinite(obs[i]):
                    return k
            _mlp(obs, values, layout, action, z, work)
            for i in range(m):
                u = values[map_at + i] + values[map_at + m + i] * np.float64(action[i])
                if u < low[i]:
                    u = low[i]
                if u > high[i]:
                    u = high[i]
                inputs[k, i] = u
        for i in range(n_state):  # x_{k+1} = A x_k + B u_k
            ax = 0.0
            for j in range(n_state):
                ax += A[i, j] * states[k, j]
            bu = 0.0
            for j in range(m):
                bu += B[i, j] * inputs[k, j]
            states[k + 1, i] = ax + bu
    return 0


# --------------------------------------------------------------------------- the maker
def supports_env(env: Any) -> bool:
    """Whether the kernel knows ``env``'s observation: a :class:`safe_nav_env.SafeNavEnv`
    (or a subclass that keeps its ``observe`` and ``_observe``)."""
    from safe_nav_env.env import SafeNavEnv

    kind = type(env)
    return (issubclass(kind, SafeNavEnv) and kind.observe is SafeNavEnv.observe
            and kind._observe is SafeNavEnv._observe)


class CompiledRollout:
    """A reference maker ``(env, action, horizon) -> (states, inputs)``: the policy roll-out
    of :class:`filters.references.PolicyRolloutReference` in one compiled call.

    Parameters
    ----------
    network
        The actor (:class:`ActorNetwork`), or a callable returning the current one (for
        live torch parameters that training changes).
    centre, half_width
        The map ``c + w * a`` of the actor's actions to physical units (m/s²), shape
        ``(m,)``; default ``0`` and ``1`` (the actor acts in physical units).

    Raises
    ------
    InvalidArrayError
        From :meth:`__call__`, when an observation of the roll-out is not finite (NaN
        predictions, say), as the policy's ``predict`` would.
    """

    def __init__(self, network: ActorNetwork | Any, *, centre: Any = None,
                 half_width: Any = None) -> None:
        self._network = network
        self._static = network if isinstance(network, ActorNetwork) else None
        current = self._current()
        self._obs_shape = (current.n_inputs,)
        m = current.n_outputs
        self.centre = _vector(0.0 if centre is None else centre, m)
        self.half_width = _vector(1.0 if half_width is None else half_width, m)
        self._env_types: dict[type, bool] = {}
        self._packed: tuple[ActorNetwork | None, Any, Any] = (None, None, None)

    def _current(self) -> ActorNetwork:
        return self._static if self._static is not None else self._network()

    def supports(self, env: Any) -> bool:
        """Whether this roll-out can run on ``env`` (see :func:`supports_env`) and its
        observation has the size the network takes."""
        known = self._env_types.get(type(env))
        if known is None:
            known = self._env_types[type(env)] = supports_env(env)
        return known and env.observation_space.shape == self._obs_shape

    def reference(self, env: Any, action: Any,
                  horizon: int) -> tuple[np.ndarray, np.ndarray] | None:
        """``self(env, action, horizon)`` if :meth:`supports` ``env``, else ``None``."""
        return self(env, action, horizon) if self.supports(env) else None

    def __call__(self, env: Any, action: Any, horizon: int) -> tuple[np.ndarray, np.ndarray]:
        """The roll-out from ``env``'s current state (``env`` a supported ``SafeNavEnv``).

        The kernel checks the shapes itself (a status, then the error here): only what
        it cannot take as an argument is checked before.

        Raises
        ------
        InvalidArrayError
            If an observation is not finite, or the shapes do not fit together (the
            action, the network's inputs and outputs, the predictions).
        InvalidParameterError
            If ``horizon`` exceeds the predictions by more than one step.
        """
        net = self._current()
        packed_net, values, layout = self._packed
        if net is not packed_net:  # a new export of live parameters, or the first call
            values, layout = _pack(net, self.centre, self.half_width)
            self._packed = (net, values, layout)
        A, B, _ = env.dynamics
        low, high = env.input_bounds
        predictions = env.predictions
        u0 = action
        if type(u0) is not np.ndarray or u0.dtype.char not in "fd":  # float32 as it is
            u0 = np.asarray(action, dtype=np.float64)
        if u0.shape != low.shape:
            if u0.size != low.size:
                raise InvalidArrayError(
                    f"action must have {low.size} entries, got shape {u0.shape}")
            u0 = u0.reshape(low.shape)
        steps = int(horizon)
        if steps < 1:
            self._raise(-2, env, net, horizon)
        if not predictions.flags.c_contiguous:  # the kernel reads whole sample rows
            predictions = np.ascontiguousarray(predictions)
        states = np.empty((steps + 1, 4))  # fresh each call: a kept result never changes
        inputs = np.empty((steps, low.shape[0]))
        try:
            status = _rollout(env.ego_state, u0, predictions, env.obstacle_velocities,
                              env.goal, env.max_obstacles, A, B, low, high, values, layout,
                              states, inputs)
        except TypingError as error:  # an array of another dimension or dtype
            raise InvalidArrayError(
                f"the environment's arrays do not fit the compiled roll-out: {error}"
            ) from error
        if status:
            self._raise(status, env, net, horizon)
        return states, inputs

    @staticmethod
    def _raise(status: int, env: Any, net: ActorNetwork, horizon: Any) -> None:
        """The error of a kernel status (see :func:`_rollout`)."""
        if status == -1:
            predictions, velocities = env.predictions, env.obstacle_velocities
            raise InvalidArrayError(
                f"the network takes {net.n_inputs} inputs and gives {net.n_outputs} actions; "
                f"the environment observes {6 + 5 * env.max_obstacles} entries and takes "
                f"{env.input_bounds[0].size} inputs, with predictions {predictions.shape} "
                f"and velocities {velocities.shape} for the obstacles, the state "
                f"{env.ego_state.shape}, the goal {env.goal.shape} and dynamics "
                f"{env.dynamics[0].shape}, {env.dynamics[1].shape}")
        if status == -2:
            raise InvalidParameterError(
                f"horizon must be an integer in [1, {env.predictions.shape[2] + 1}] (one "
                f"more than the prediction horizon), got {horizon!r}")
        raise InvalidArrayError(
            f"the policy roll-out's observation at look-ahead step {status} is not "
            "finite (NaN or infinite predictions or states)")


def _vector(value: Any, m: int) -> np.ndarray:
    array = np.array(np.broadcast_to(np.asarray(value, dtype=np.float64), (m,)))
    array.setflags(write=False)
    return array


def _pack(net: ActorNetwork, centre: np.ndarray,
          half_width: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The kernel's two network arguments (arrays: numba types tuples of arrays slowly
    at every call, and each argument costs).

    ``values`` (float64): per layer ``W_l^T`` row by row then ``b_l``; then the
    activation parameters, the action box (float32 values, exact in float64), the
    centre and the half-width of the map to m/s². ``layout`` (int64): row 0 the header
    ``(layers, squash, parameters at, box at, map at, m)``, row ``1 + l`` layer ``l``'s
    ``(inputs, outputs, W_l^T at, b_l at, activation code, 0)``.
    """
    parts, rows, start = [], [], 0
    for weight, bias, code in zip(net.weights, net.biases, net.activations, strict=True):
        n_in, n_out = weight.shape
        rows.append((n_in, n_out, start, start + n_in * n_out, int(code), 0))
        parts += [np.asarray(weight, dtype=np.float64).reshape(-1),
                  np.asarray(bias, dtype=np.float64)]
        start += n_in * n_out + n_out
    m = net.n_outputs
    header = (len(rows), int(net.squash), start, start + len(rows), start + len(rows) + 2 * m, m)
    parts += [np.asarray(net.parameters, dtype=np.float64),
              np.asarray(net.action_low, dtype=np.float32).astype(np.float64),
              np.asarray(net.action_high, dtype=np.float32).astype(np.float64),
              centre, half_width]
    values = np.concatenate(parts)
    layout = np.array([header, *rows], dtype=np.int64)
    values.setflags(write=False)
    layout.setflags(write=False)
    return values, layout


# --------------------------------------------------------------------------- exports
class _TorchNetwork:
    """The :class:`ActorNetwork` of live torch parameters, rebuilt when any changes.

    A parameter changes in place during training (its version counter, torch's
    ``Tensor._version``, moves) or is replaced (its data pointer moves); either triggers
    a new export. Without version counters every call exports again.
    """

    def __init__(self, linears: list[tuple[Any, str]], squash: bool, low: Any, high: Any):
        self._linears = linears
        self._params = [p for module, _ in linears for p in (module.weight, module.bias)]
        self._squash, self._low, self._high = squash, low, high
        self._versions: list[int] | None = None
        self._pointers: list[int] | None = None
        self._network: ActorNetwork | None = None

    def __call__(self) -> ActorNetwork:
        params = self._params
        try:  # two list comprehensions: the cheapest way to read them (called every step)
            versions = [p._version for p in params]
        except AttributeError:  # pragma: no cover - a torch without version counters
            versions = None
        pointers = [p.data_ptr() for p in params]
        if versions is None or versions != self._versions or pointers != self._pointers:
            layers = [(module.weight.detach().cpu().numpy().T, module.bias.detach().cpu().numpy(),
                       name, 0.0) for module, name in self._linears]
            self._network = ActorNetwork.from_layers(
                layers, squash=self._squash, action_low=self._low, action_high=self._high)
            self._versions, self._pointers = versions, pointers
        return self._network


def _torch_network(policy: Any) -> _TorchNetwork | None:
    """Live network of an SB3 ``ActorCriticPolicy`` whose actor is plain, else ``None``.

    Plain: ``mlp_extractor.policy_net`` an ``nn.Sequential`` of float32 CPU ``Linear``
    layers with biases, each followed by at most one ``Tanh`` or ``ReLU``, and an
    ``nn.Linear`` action net.
    """
    import torch
    from torch import nn

    net, head = policy.mlp_extractor.policy_net, policy.action_net
    if not isinstance(net, nn.Sequential) or type(head) is not nn.Linear:
        return None
    linears: list[list[Any]] = []
    for module in [*net, head]:
        if type(module) is nn.Linear:
            if (module.bias is None or module.weight.dtype != torch.float32
                    or module.weight.device.type != "cpu"):
                return None
            linears.append([module, "identity"])
        elif type(module) in (nn.Tanh, nn.ReLU) and linears and linears[-1][1] == "identity":
            linears[-1][1] = "tanh" if type(module) is nn.Tanh else "relu"
        else:
            return None
    if linears[-1][1] != "identity":
        return None
    space = policy.action_space
    return _TorchNetwork([(module, name) for module, name in linears],
                         bool(policy.squash_output), space.low, space.high)


def compile_rollout(policy: Any, *, centre: Any = None,
                    half_width: Any = None) -> CompiledRollout | None:
    """The :class:`CompiledRollout` of ``policy``, or ``None`` if it has no plain MLP actor.

    ``policy``: a :class:`~agents.NumpyPolicy` (its exported weights), a
    :class:`~agents.TorchActorPolicy`, an SB3 ``PPO``/``A2C`` model or its
    ``ActorCriticPolicy`` (the live torch parameters: training updates them), a
    :class:`~agents.training.wrappers.PhysicalUnitsPolicy` around one of these (its map to m/s²
    is folded into the roll-out), or the :class:`~agents.training.ppo.TrainingPolicy` bound
    to one. ``centre``, ``half_width``: see :class:`CompiledRollout`.
    """
    from agents.policies.numpy_policy import NumpyPolicy, TorchActorPolicy
    from agents.training.ppo import TrainingPolicy
    from agents.training.wrappers import PhysicalUnitsPolicy

    if isinstance(policy, TrainingPolicy):  # the model it is bound to (None before)
        if policy._physical is None:
            return None
        return compile_rollout(policy._physical, centre=centre, half_width=half_width)
    if isinstance(policy, PhysicalUnitsPolicy):
        if centre is not None or half_width is not None:
            return None  # two maps: not worth folding
        return compile_rollout(policy.policy, centre=policy.centre,
                               half_width=policy.half_width)
    if isinstance(policy, NumpyPolicy):
        layers = [(w, b, getattr(f, "name", "identity") if f is not None else "identity",
                   getattr(f, "parameter", 0.0)) for w, b, f in policy.layers]
        if any(f is not None and not hasattr(f, "name") for _, _, f in policy.layers):
            return None
        network: Any = ActorNetwork.from_layers(
            layers, squash=policy.squash_output, action_low=policy._low,
            action_high=policy._high)
        return CompiledRollout(network, centre=centre, half_width=half_width)
    if isinstance(policy, TorchActorPolicy):
        sb3_policy = policy._policy
    elif "stable_baselines3" in sys.modules:  # else it cannot be an SB3 object
        from agents.policies.numpy_policy import UnsupportedPolicyError, _checked_actor_critic

        try:
            sb3_policy = _checked_actor_critic(policy)
        except UnsupportedPolicyError:
            return None
    else:
        return None
    live = _torch_network(sb3_policy)
    if live is None:
        return None
    return CompiledRollout(live, centre=centre, half_width=half_width)


def rollout_reference(
    policy: Any, env: Any, action: Any, horizon: int
) -> tuple[np.ndarray, np.ndarray] | None:
    """``policy``'s roll-out by its :class:`CompiledRollout`, or ``None`` if it has none or
    ``env`` is not supported: the body of the policies' ``rollout_reference`` methods.

    The compiled roll-out is made on first use and kept in ``policy._compiled_rollout``
    (``False`` when the policy cannot be compiled).
    """
    compiled = policy._compiled_rollout
    if compiled is None:
        compiled = policy._compiled_rollout = compile_rollout(policy) or False
    if compiled is False:
        return None
    return compiled.reference(env, action, horizon)

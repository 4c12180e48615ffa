"""The PPO actor in numpy: weights exported once, a forward pass in a few microseconds.

The roll-out reference (:class:`filters.references.PolicyRolloutReference`) asks
the policy for ``T - 1`` actions at every control step, one after the other (each
depends on the state the previous one produced), so it cannot be batched. Through
Stable-Baselines3 most of one ``model.predict`` call is overhead (tensor
conversion, ``no_grad``, distribution objects; :func:`benchmarks.policy.benchmark_numpy_policy`
times it). :class:`NumpyPolicy` evaluates the same network with numpy:

.. math::

    z_0 = \\operatorname{flatten}(o), \\qquad
    z_{l+1} = \\sigma_l(z_l W_l^\\top + b_l) \\ (\\text{policy\\_net}), \\qquad
    \\mu = z_L W_a^\\top + b_a \\ (\\text{action\\_net}),

    a = \\operatorname{clip}(\\mu, a_{low}, a_{high})
    \\quad\\text{or, with } \\texttt{squash\\_output},\\quad
    a = a_{low} + \\tfrac12(\\tanh\\mu + 1)(a_{high} - a_{low}),

which is what ``model.predict(obs, deterministic=True)`` returns for a ``Box``
action space (the mode of the Gaussian is its mean; SB3 clips it to the box, or
un-squashes it when the policy squashes). Only the deterministic action exists
here: ``deterministic=False`` raises.

Precision. The weights are the float32 tensors of the model, evaluated in float64
from the float32 observation (SB3 casts observations to float32 first), and the
action is rounded once to float32. That is the exact value of the float32 network;
torch's own float32 arithmetic differs from it by a few float32 rounding steps (its
batched and single-observation calls differ from each other by as much). The tests
check ``|a_numpy - a_torch| <= 1e-6 max(1, |a_torch|)`` (m/s²) against
``model.predict(obs, deterministic=True)``, the reference.

Loading. :func:`load_numpy_policy` loads a PPO ``.zip`` with
:func:`agents.load_ppo` (so torch and SB3 are still needed, once) and exports it;
``load_ppo`` itself keeps returning the SB3 model (training, saving and
stochastic actions need it). A :class:`NumpyPolicy` has SB3's ``predict``
signature, so it can be passed wherever a policy is expected, e.g.
``SafetyFilterWrapper(env, policy=load_numpy_policy())`` or
``run_episode(spec, policy=...)``.
"""

from __future__ import annotations

import os
import warnings
import zipfile
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from filters._validation import finite_array
from filters.errors import InvalidArrayError, InvalidParameterError, InvalidTypeError

__all__ = ["NumpyPolicy", "UnsupportedPolicyError", "load_numpy_policy"]


class UnsupportedPolicyError(InvalidTypeError):
    """The SB3 policy has a part that :class:`NumpyPolicy` cannot export."""


def _tanh(z: np.ndarray, parameter: float) -> np.ndarray:
    return np.tanh(z)


def _relu(z: np.ndarray, parameter: float) -> np.ndarray:
    return np.maximum(z, 0.0)


def _leaky_relu(z: np.ndarray, parameter: float) -> np.ndarray:
    return np.where(z >= 0.0, z, parameter * z)


def _elu(z: np.ndarray, parameter: float) -> np.ndarray:
    return np.where(z > 0.0, z, parameter * np.expm1(np.minimum(z, 0.0)))


_ACTIVATIONS = {"tanh": _tanh, "relu": _relu, "leaky_relu": _leaky_relu, "elu": _elu}
"""The numpy activations ``σ(z, parameter)`` by name (``parameter``: the leaky slope or the
ELU alpha, unused by the others)."""


EXPORT_FORMAT = 1
"""Version of the file layout of :meth:`NumpyPolicy.save` (files of another are refused)."""


class _Activation(NamedTuple):
    """The numpy activation ``z -> σ(z)`` called ``name`` in :data:`_ACTIVATIONS`, with its
    ``parameter`` (picklable; :meth:`NumpyPolicy.save` writes the two fields)."""

    name: str
    parameter: float = 0.0

    def __call__(self, z: np.ndarray) -> np.ndarray:
        return _ACTIVATIONS[self.name](z, self.parameter)


def _activation(module: Any) -> _Activation | None:
    """The :class:`_Activation` of a torch activation module, or ``None``."""
    from torch import nn

    kind = {nn.Tanh: ("tanh", 0.0), nn.ReLU: ("relu", 0.0),
            nn.LeakyReLU: ("leaky_relu", getattr(module, "negative_slope", 0.0)),
            nn.ELU: ("elu", getattr(module, "alpha", 0.0))}.get(type(module))
    return None if kind is None else _Activation(kind[0], float(kind[1]))


def _read_only(values: Any) -> np.ndarray:
    """A read-only C-ordered float64 copy of ``values``."""
    array = np.array(values, dtype=np.float64, order="C")
    array.setflags(write=False)
    return array


def _linear(module: Any) -> tuple[np.ndarray, np.ndarray]:
    """``(W^T, b)`` of a torch ``Linear`` as read-only float64 arrays (``b = 0`` if absent)."""
    weight = _read_only(module.weight.detach().cpu().numpy().T)
    bias = (np.zeros(weight.shape[1]) if module.bias is None
            else module.bias.detach().cpu().numpy())
    return weight, _read_only(bias)


Layer = tuple[np.ndarray, np.ndarray, _Activation | None]

def _checked_actor_critic(model: Any) -> Any:
    """The ``ActorCriticPolicy`` of ``model`` if its actor can be exported, else raise.

    Raises
    ------
    UnsupportedPolicyError
        Unless it is an ``ActorCriticPolicy`` with a flat ``Box`` observation space (not
        an image), a ``FlattenExtractor`` and a ``Box`` action space.
    """
    from gymnasium import spaces
    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.common.preprocessing import is_image_space
    from stable_baselines3.common.torch_layers import FlattenExtractor

    policy = getattr(model, "policy", model)
    if not isinstance(policy, ActorCriticPolicy):
        raise UnsupportedPolicyError("exporting a policy needs an SB3 ActorCriticPolicy (PPO or "
                                     f"A2C with MlpPolicy) or a model holding one, got "
                                     f"{type(policy).__name__}")
    obs_space, action_space = policy.observation_space, policy.action_space
    if not isinstance(obs_space, spaces.Box) or is_image_space(obs_space):
        raise UnsupportedPolicyError(
            f"only flat Box observation spaces (not images) are supported, got {obs_space}")
    if not isinstance(action_space, spaces.Box):
        raise UnsupportedPolicyError(f"only Box action spaces are supported, got {action_space}")
    if type(policy.pi_features_extractor) is not FlattenExtractor:
        raise UnsupportedPolicyError("only the FlattenExtractor of MlpPolicy is supported, got "
                                     f"{type(policy.pi_features_extractor).__name__}")
    return policy



class NumpyPolicy:
    """Deterministic actor of a Stable-Baselines3 ``MlpPolicy`` (PPO/A2C), in numpy.

    Build it with :meth:`from_sb3`. It holds no mutable state (the weights are
    read-only arrays), so one instance can serve several environments or threads.

    Attributes
    ----------
    observation_space, action_space
        The model's Gymnasium spaces (``Box``).
    layers
        ``(W^T, b, activation)`` per affine layer, policy net then action net
        (``activation`` is ``None`` for the action net).
    squash_output
        Whether the mean is squashed by ``tanh`` and rescaled to the box (gSDE) instead
        of clipped.
    """

    def __init__(self, layers: list[Layer], observation_space: Any, action_space: Any, *,
                 squash_output: bool = False) -> None:
        if not layers:
            raise InvalidParameterError("a NumpyPolicy needs at least one affine layer, got none")
        self.observation_space = observation_space
        self.action_space = action_space
        self.squash_output = bool(squash_output)
        self._obs_shape = tuple(observation_space.shape)
        self._n_inputs = int(np.prod(self._obs_shape, dtype=np.int64))
        self._action_shape = tuple(action_space.shape)
        self._low = np.asarray(action_space.low, dtype=np.float32).reshape(-1)
        self._high = np.asarray(action_space.high, dtype=np.float32).reshape(-1)
        self.layers = tuple(layers)
        if layers[0][0].shape[0] != self._n_inputs:
            raise InvalidArrayError(f"the first layer takes {layers[0][0].shape[0]} inputs, but "
                                    f"observations have {self._n_inputs} entries (shape "
                                    f"{self._obs_shape})")
        if layers[-1][0].shape[1] != self._low.size:
            raise InvalidArrayError(f"the action net gives {layers[-1][0].shape[1]} outputs, but "
                                    f"the action space has {self._low.size} entries (shape "
                                    f"{self._action_shape})")

    def _to_box(self, mean_or_squashed: np.ndarray) -> np.ndarray:
        """SB3's last step on float32 network outputs: clip, or rescale ``tanh`` outputs."""
        if self.squash_output:
            return self._low + 0.5 * (mean_or_squashed + 1.0) * (self._high - self._low)
        # np.clip's semantics on finite numbers at a third of its per-call cost
        return np.minimum(np.maximum(mean_or_squashed, self._low), self._high)

    def _inputs(self, observation: object) -> tuple[np.ndarray, bool]:
        """Observation(s) as rows ``(B, n)`` of float32 values (as SB3 casts them) in float64,
        and whether batched."""
        try:
            obs = np.asarray(observation, dtype=np.float32)
        except (TypeError, ValueError) as exc:
            raise InvalidArrayError(f"observation must be numeric, got "
                                    f"{type(observation).__name__}") from exc
        batched = obs.shape != self._obs_shape
        if batched and obs.shape[1:] != self._obs_shape:
            raise InvalidArrayError(f"observation must have shape {self._obs_shape} or (batch, "
                                    f"{', '.join(map(str, self._obs_shape))}), got {obs.shape}")
        return finite_array("observation", obs).reshape(-1, self._n_inputs), batched

    def predict(self, observation: object, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        """Stable-Baselines3's ``predict``, deterministic only.

        Parameters
        ----------
        observation
            One observation (the observation space's shape) or a batch ``(B, ...)``.
        state, episode_start
            Ignored (no recurrent state); ``state`` is returned as given, as SB3 does.
        deterministic
            Must be true (the default here; SB3's default is ``False``).

        Returns
        -------
        (numpy.ndarray, Any)
            Float32 actions, shape of the action space (or ``(B, ...)`` for a batch),
            clipped to the action box; and ``state``.

        Raises
        ------
        InvalidParameterError
            If ``deterministic`` is false.
        InvalidArrayError
            If the observation has the wrong shape or is not finite.
        """
        if not deterministic:
            raise InvalidParameterError(
                "NumpyPolicy computes the deterministic action only (the Gaussian's mean); got "
                "deterministic=False: use the SB3 model for stochastic actions")
        rows, batched = self._inputs(observation)
        return self._actions(rows).reshape(((-1,) if batched else ()) + self._action_shape), state

    def predict_batch(self, observations: object) -> np.ndarray:
        """Deterministic actions of a batch ``(B, ...)`` of observations, shape ``(B, ...)``.

        Raises
        ------
        InvalidArrayError
            If ``observations`` is not a finite batch of observations.
        """
        rows, batched = self._inputs(observations)
        if not batched:
            raise InvalidArrayError(
                f"observations must have shape (batch, {', '.join(map(str, self._obs_shape))}), "
                f"got a single observation of shape {self._obs_shape}: use predict")
        return self._actions(rows).reshape((-1, *self._action_shape))

    @classmethod
    def from_sb3(cls, model: Any) -> NumpyPolicy:
        """Export the actor of an SB3 ``ActorCriticPolicy`` (or of a model holding one).

        Parameters
        ----------
        model
            A ``PPO``/``A2C`` model or its ``.policy``: an ``ActorCriticPolicy`` with a
            ``FlattenExtractor`` (the ``MlpPolicy`` default), ``mlp_extractor.policy_net``
            made of ``Linear`` layers and ``Tanh``/``ReLU``/``LeakyReLU``/``ELU``
            activations, and a ``Box`` action space.

        Raises
        ------
        UnsupportedPolicyError
            For any other policy: an image or ``Dict`` observation space, another
            features extractor, a non-``Box`` action space, an unknown layer.
        """
        from torch import nn

        policy = _checked_actor_critic(model)
        net = policy.mlp_extractor.policy_net
        if not isinstance(net, nn.Sequential):
            raise UnsupportedPolicyError(
                f"mlp_extractor.policy_net must be an nn.Sequential, got {type(net).__name__}")
        layers: list[Layer] = []
        for index, module in enumerate(net):
            if isinstance(module, nn.Linear):
                layers.append((*_linear(module), None))
                continue
            activation = _activation(module)
            if activation is None or not layers or layers[-1][2] is not None:
                raise UnsupportedPolicyError(
                    f"policy_net[{index}] = {module!r} is not supported: expected Linear "
                    "layers, each followed by at most one Tanh, ReLU, LeakyReLU or ELU")
            weight, bias, _ = layers[-1]
            layers[-1] = (weight, bias, activation)
        if not isinstance(policy.action_net, nn.Linear):
            raise UnsupportedPolicyError(
                f"action_net must be an nn.Linear, got {type(policy.action_net).__name__}")
        layers.append((*_linear(policy.action_net), None))
        return cls(layers, policy.observation_space, policy.action_space,
                   squash_output=bool(policy.squash_output))

    def save(self, path: str | Path) -> None:
        """Write the weights and spaces to ``path`` (``.npz``, no pickled objects), atomically.

        :meth:`load` reads the file back without torch or Stable-Baselines3 (the
        evaluation's cache of exports, :func:`agents.evaluation.policy_files.load_policy`).
        """
        names = [a or ("", 0.0) for _, _, a in self.layers]
        arrays: dict[str, np.ndarray] = {
            "format": np.array(EXPORT_FORMAT), "squash_output": np.array(self.squash_output),
            "activations": np.array([name for name, _ in names]),
            "activation_parameters": np.array([parameter for _, parameter in names])}
        for name, space in (("observation", self.observation_space),
                            ("action", self.action_space)):
            arrays[f"{name}_low"], arrays[f"{name}_high"] = space.low, space.high
        for index, (weight, bias, _) in enumerate(self.layers):
            arrays[f"weight_{index}"], arrays[f"bias_{index}"] = weight, bias
        path = Path(path)
        partial_path = path.with_name(f".{path.name}.{os.getpid()}.partial")
        with open(partial_path, "wb") as handle:
            np.savez(handle, **arrays)
        os.replace(partial_path, path)  # readers see the whole file or none

    @classmethod
    def load(cls, path: str | Path) -> NumpyPolicy:
        """A policy written by :meth:`save`.

        Raises
        ------
        OSError
            If the file cannot be read.
        UnsupportedPolicyError
            If it is not a :meth:`save` file of this export format.
        """
        from gymnasium import spaces

        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {key: data[key] for key in data.files}
            if int(arrays["format"]) != EXPORT_FORMAT:
                raise ValueError(f"export format {int(arrays['format'])}")
            box = {name: spaces.Box(arrays[f"{name}_low"], arrays[f"{name}_high"],
                                    dtype=arrays[f"{name}_low"].dtype)
                   for name in ("observation", "action")}
            layers: list[Layer] = []
            for index, (name, parameter) in enumerate(zip(
                    arrays["activations"].tolist(), arrays["activation_parameters"].tolist(),
                    strict=True)):
                layers.append((_read_only(arrays[f"weight_{index}"]),
                               _read_only(arrays[f"bias_{index}"]),
                               _Activation(name, float(parameter)) if name else None))
        except (KeyError, ValueError, TypeError, zipfile.BadZipFile) as exc:
            raise UnsupportedPolicyError(
                f"{path} is not a NumpyPolicy file of export format {EXPORT_FORMAT} "
                f"({type(exc).__name__}: {exc})") from None
        return cls(layers, box["observation"], box["action"],
                   squash_output=bool(arrays["squash_output"]))

    def _actions(self, z: np.ndarray) -> np.ndarray:
        """Float32 actions ``(B, m)`` of observation rows ``z`` ``(B, n)`` (float64 inside)."""
        for weight, bias, activation in self.layers:
            z = z @ weight
            z += bias
            if activation is not None:
                z = activation(z)
        return self._to_box((np.tanh(z) if self.squash_output else z).astype(np.float32))


def load_numpy_policy(path: str | Path | None = None) -> NumpyPolicy:
    """Load a PPO ``.zip`` (default: the shipped policy) and export its actor to numpy.

    Raises
    ------
    FileNotFoundError
        If ``path`` (or the shipped policy) does not exist.
    UnsupportedPolicyError
        If the policy cannot be exported (see :meth:`NumpyPolicy.from_sb3`).
    """
    from agents.policies.loading import load_ppo

    return NumpyPolicy.from_sb3(load_ppo(path))


def __getattr__(name: str) -> Any:
    """``TorchActorPolicy``: a deprecated alias of :class:`NumpyPolicy` (with a warning)."""
    if name == "TorchActorPolicy":
        warnings.warn(
            "TorchActorPolicy is deprecated: it is now an alias of NumpyPolicy (the one fast "
            "form of the actor; its actions equal SB3's to float32 rounding, not bit for bit). "
            "Use NumpyPolicy.from_sb3(model), or the SB3 model itself for SB3's exact actions",
            DeprecationWarning, stacklevel=2)
        return NumpyPolicy
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

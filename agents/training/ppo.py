"""Train and load the PPO reference planner (Stable-Baselines3, PyTorch on the CPU).

The PPO policy is trained to reach its goal, not to be safe: the environment's
collision penalty is small by default. That is the point of the project: the
learned planner proposes, the safety filter disposes. Three ways to train:

* plain PPO (the shipped policy);
* PPO with the safety filter in the loop: ``filter_kwargs=FilterConfig(risk="dr_cvar",
  alpha=0.2, delta=0.1, epsilon=0.05)`` (or the same as a dict of the wrapper's keywords)
  wraps every training environment in :class:`filters.SafetyFilterWrapper`. The agent then learns
  on the filtered system; ``intervention_penalty`` :math:`\\kappa` subtracts
  :math:`\\kappa \\|u_{safe} - u_{ref}\\|^2` (m/s² squared) from each reward, so the
  agent pays for the corrections and learns to propose safe actions itself;
* PPO-Lagrangian (``lagrangian=True, cost_limit=0.0``), the constrained-RL
  baseline of :mod:`agents.training.lagrangian`.

Learners see actions normalised to ``[-1, 1]`` (:class:`agents.training.wrappers.NormalisedActions`,
outside the filter, so the filter works in m/s²). Every run logs the safety
metrics of :class:`agents.training.callbacks.SafetyMetricsCallback` per rollout to SB3's
logger: a stdout table with ``print_metrics``, a CSV next to the model
(``<model>.metrics.csv``) and TensorBoard with ``tensorboard_log``.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import gymnasium as gym

import safe_nav_env  # noqa: F401  (registers the ids)
from agents.policies.loading import (  # noqa: F401  (re-exported)
    PRETRAINED_POLICY,
    load_ppo,
    pretrained_policy_path,
    set_torch_threads,
)
from agents.training.wrappers import (
    EPISODE_INFO_KEYS,
    EpisodeCostInfo,
    NormalisedActions,
    in_physical_units,
)
from filters import SafetyFilterWrapper
from filters._validation import finite_scalar, integer_at_least
from filters.config import FilterConfig
from filters.errors import InvalidParameterError, InvalidTypeError
from safe_nav_env.errors import SafeNavEnvError

DEFAULT_ENV_ID = "SafeNav/RandomCrossing-v0"
"""The randomised training scenario family."""

DEFAULT_PPO_KWARGS: dict[str, Any] = {
    "n_steps": 256,
    "batch_size": 256,
    "n_epochs": 10,
    "learning_rate": 3e-4,
    "gamma": 0.99,
    "gae_lambda": 0.95,
    "ent_coef": 0.0,
    "clip_range": 0.2,
    "policy_kwargs": {"net_arch": [64, 64]},
}
"""PPO settings: short rollouts over several in-process environments (fast on 2 cores)."""

EVAL_SEED_OFFSET = 10_000
"""Evaluation episodes use seeds from ``seed + EVAL_SEED_OFFSET`` on (held out)."""

VEC_ENVS = ("dummy", "subproc")
"""Vector environments: in-process (``DummyVecEnv``) or one process each (``SubprocVecEnv``)."""

FILTER_REFERENCES = ("default", "rollout")
"""With the filter in the loop: the wrapper's own reference, or the policy being trained
rolled out over the horizon (:class:`filters.references.PolicyRolloutReference`)."""


@dataclass(frozen=True)
class TrainingReport:
    """What :func:`train_ppo` measured.

    Attributes
    ----------
    total_timesteps
        Environment steps taken.
    wall_time
        Training time in s.
    steps_per_second
        ``total_timesteps / wall_time``.
    save_path
        Where the model was saved, or ``None``.
    metrics_path
        The per-rollout metrics CSV (SB3's logger), or ``None``.
    best_model_path
        The best model by evaluation return (with ``eval_freq``), or ``None``.
    safety
        The last rollout's safety metrics (keys of :mod:`agents.training.callbacks`, no prefix).
    lagrange_multiplier
        The final multiplier of PPO-Lagrangian, else ``None``.
    """

    total_timesteps: int
    wall_time: float
    steps_per_second: float
    save_path: Path | None
    metrics_path: Path | None = None
    best_model_path: Path | None = None
    safety: dict[str, float] = field(default_factory=dict)
    lagrange_multiplier: float | None = None


def metrics_path_for(save_path: str | Path) -> Path:
    """The metrics CSV next to a model: ``runs/ppo.zip`` -> ``runs/ppo.metrics.csv``."""
    path = Path(save_path)
    return path.with_name(path.stem + ".metrics.csv")


class TrainingPolicy:
    """The policy being trained, in physical units, for the filter's roll-out reference.

    The training environments are built before the model, so this stands in for it
    until :meth:`bind` is called. In-process environments only (``vec_env="dummy"``).
    Deterministic actions come from :class:`agents.NumpyPolicy` (SB3's to float32
    rounding), exported again by :meth:`refresh` at the start of every rollout (the
    parameters change only in the updates between rollouts); others from the SB3 model.
    """

    def __init__(self) -> None:
        self.model: Any = None
        self._space: Any = None
        self._physical: Any = None  # the SB3 model, in physical units
        self._fast: Any = None  # its numpy export, in physical units (None: not exportable)

    def bind(self, model: Any, physical_space: Any) -> None:
        """Answer with ``model`` from now on (its actions mapped to ``physical_space``)."""
        self.model, self._space = model, physical_space
        self._physical = in_physical_units(model, physical_space)
        self.refresh()

    def refresh(self) -> None:
        """Export the bound model's actor to numpy again (after its parameters changed)."""
        from agents.policies.numpy_policy import NumpyPolicy, UnsupportedPolicyError

        try:
            self._fast = in_physical_units(NumpyPolicy.from_sb3(self.model), self._space)
        except UnsupportedPolicyError:
            self._fast = None

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = False):
        if self._physical is None:
            raise InvalidTypeError("TrainingPolicy.predict called before bind(model)")
        policy = self._fast if deterministic and self._fast is not None else self._physical
        return policy.predict(observation, state=state, episode_start=episode_start,
                              deterministic=deterministic)

    def __deepcopy__(self, memo: dict) -> TrainingPolicy:  # the wrapper records its args
        return self


def _make_env(env_id: str, env_kwargs: dict[str, Any], filter_kwargs: dict[str, Any] | None):
    """One training environment: gym.make -> [filter] -> EpisodeCostInfo."""
    env = gym.make(env_id, **env_kwargs)
    if filter_kwargs is not None:
        env = SafetyFilterWrapper(env, **filter_kwargs)
    return EpisodeCostInfo(env)


def make_training_env(
    env_id: str = DEFAULT_ENV_ID,
    *,
    n_envs: int = 8,
    seed: int = 0,
    env_kwargs: dict[str, Any] | None = None,
    filter_kwargs: dict[str, Any] | None = None,
    normalise_actions: bool = True,
    vec_env: str = "dummy",
):
    """Vector environment of ``n_envs`` monitored copies, as learners see it.

    Each copy is, inside out: ``gym.make(env_id, **env_kwargs)``; with
    ``filter_kwargs``, :class:`filters.SafetyFilterWrapper` (physical units);
    :class:`agents.training.wrappers.EpisodeCostInfo`; ``Monitor`` logging
    :data:`agents.training.wrappers.EPISODE_INFO_KEYS` into the episode's ``info["episode"]``;
    with ``normalise_actions``, :class:`agents.training.wrappers.NormalisedActions`
    (actions in [-1, 1]). Copy ``k`` is seeded with ``seed + k``.

    ``vec_env="dummy"`` (default) runs the copies in this process, which beats
    subprocesses on 2 cores with and without the filter in the loop (2 and 8
    copies); ``"subproc"`` gives each one its own process.
    """
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    if vec_env not in VEC_ENVS:
        raise InvalidParameterError(f"vec_env must be one of {VEC_ENVS}, got {vec_env!r}")
    return make_vec_env(
        partial(_make_env, env_id, dict(env_kwargs or {}),
                None if filter_kwargs is None else dict(filter_kwargs)),
        n_envs=n_envs, seed=seed, monitor_kwargs={"info_keywords": EPISODE_INFO_KEYS},
        wrapper_class=NormalisedActions if normalise_actions else None,
        vec_env_cls=DummyVecEnv if vec_env == "dummy" else SubprocVecEnv,
    )


def check_filter_kwargs(env_id: str, env_kwargs: dict[str, Any] | None,
                        filter_kwargs: FilterConfig | dict[str, Any],
                        **extra: Any) -> dict[str, Any]:
    """Validate the filter options once, before any training; return them as keywords.

    Builds :class:`filters.SafetyFilterWrapper` once on ``gym.make(env_id, **env_kwargs)``
    with ``filter_kwargs`` (a :class:`filters.FilterConfig`, passed as ``config``, or the
    wrapper's keywords: ``config``, the fields of :class:`filters.FilterConfig`,
    ``policy``, ``reference``) and the ``extra`` keywords, so that every setting is
    checked by :class:`filters.FilterConfig` and the wrapper themselves.

    Returns
    -------
    dict
        A new dict of the wrapper's keywords: ``filter_kwargs`` updated with ``extra``.

    Raises
    ------
    InvalidParameterError, InvalidTypeError
        If an option is out of range or unknown to the wrapper.
    """
    if isinstance(filter_kwargs, FilterConfig):
        filter_kwargs = {"config": filter_kwargs}
    if not isinstance(filter_kwargs, dict):
        raise InvalidTypeError(f"filter_kwargs must be a FilterConfig or a dict, got "
                               f"{filter_kwargs!r}")
    filter_kwargs = {**filter_kwargs, **extra}
    env = gym.make(env_id, **(env_kwargs or {}))
    try:
        SafetyFilterWrapper(env, **filter_kwargs)
    finally:
        env.close()
    return filter_kwargs


def check_env_kwargs(env_id: str, env_kwargs: dict[str, Any] | None) -> None:
    """Build ``gym.make(env_id, **env_kwargs)`` once, so that bad keywords fail before training.

    Raises
    ------
    InvalidParameterError
        If the environment rejects a value (the message is the environment's).
    InvalidTypeError
        If ``env_kwargs`` is not a dict or holds a keyword the environment does not take.
    """
    if env_kwargs is None:
        return
    if not isinstance(env_kwargs, dict):
        raise InvalidTypeError(f"env_kwargs must be a dict, got {env_kwargs!r}")
    try:
        env = gym.make(env_id, **env_kwargs)
    except SafeNavEnvError as exc:
        raise InvalidParameterError(f"env_kwargs: {exc}") from exc
    except TypeError as exc:
        raise InvalidTypeError(f"env_kwargs {sorted(env_kwargs)}: {exc}") from exc
    env.close()


def _model_file(path: str | Path) -> Path:
    """``path`` as the model file to write, exactly as named (its folders are made later);
    :class:`InvalidParameterError` if it is a folder or one of its parents is a file."""
    path = Path(path)
    if path.is_dir():
        raise InvalidParameterError(f"the model file {path} is a folder; name a file in it, "
                                    f"e.g. {path / 'ppo.zip'}")
    for folder in path.parents:
        if folder.exists() and not folder.is_dir():
            raise InvalidParameterError(f"the model file {path} cannot be made: {folder} is "
                                        "a file")
    return path


def train_ppo(
    env_id: str = DEFAULT_ENV_ID,
    total_timesteps: int = 400_000,
    seed: int = 0,
    *,
    n_envs: int = 8,
    env_kwargs: dict[str, Any] | None = None,
    filter_kwargs: FilterConfig | dict[str, Any] | None = None,
    intervention_penalty: float = 0.0,
    filter_reference: str = "default",
    lagrangian: bool = False,
    cost_limit: float = 0.0,
    lambda_lr: float = 0.05,
    eval_freq: int = 0,
    eval_episodes: int = 20,
    tensorboard_log: str | Path | None = None,
    print_metrics: bool = False,
    progress_bar: bool = True,
    save_path: str | Path | None = None,
    metrics_path: str | Path | None = None,
    normalise_actions: bool = True,
    vec_env: str = "dummy",
    ppo_kwargs: dict[str, Any] | None = None,
    torch_threads: int = 1,
    verbose: int = 0,
):
    """Train a PPO reference planner (or PPO-Lagrangian) with Stable-Baselines3.

    Every option is validated before the first step.

    Parameters
    ----------
    env_id
        A registered ``SafeNav/...`` id (default: the randomised crossings).
    total_timesteps
        Environment steps (>= 1), summed over the vector environments.
    seed
        Seeds PPO (torch) and the environments (copy ``k``: ``seed + k``).
    n_envs
        Number of environments (>= 1).
    env_kwargs
        Passed to ``gym.make`` (e.g. ``n_samples``, ``collision_penalty``, or
        ``random_start`` to start a share of the training episodes at random ego states:
        :class:`safe_nav_env.starts.RandomStart`).
    filter_kwargs
        If given, train with :class:`filters.SafetyFilterWrapper` in the loop: its
        :class:`filters.FilterConfig`, e.g. ``FilterConfig(risk="dr_cvar", alpha=0.2)``,
        or its keywords, e.g. ``{"risk": "dr_cvar", "alpha": 0.2, "delta": 0.1}``.
    intervention_penalty
        :math:`\\kappa \\ge 0`, in reward per (m/s²)², with the filter in the loop
        only: the learner is rewarded :math:`r_t - \\kappa \\|u^{safe}_t - a_t\\|^2`,
        where :math:`a_t` is its action in m/s² (mapped from [-1, 1], clipped to the
        box) and :math:`u^{safe}_t` the action the filter applied; the norm is
        ``info["filter"].intervention``. The same as
        ``filter_kwargs["intervention_penalty"]`` (the wrapper subtracts it, so
        ``rollout/ep_rew_mean`` and the Monitor returns include it). With 0 (default)
        the learner sees the filter only through the motion it gets, not through
        the reward. Scale: the task reward is about 1 per m of progress (about 0.8
        per 0.2 s step for these policies) plus 10 on arrival, about 19 per
        episode; an intervention of 1-3 m/s² costs :math:`\\kappa` (1-9) per step.
        The square weighs the rare large corrections most: a random policy's
        :math:`E\\|u^{safe} - a\\|^2` is about 50 (m/s²)² at a mean intervention of
        3.8 m/s². What 0, 0.01 and 0.05 gave in training runs: README, "The
        intervention penalty".
    filter_reference
        ``"default"``: the wrapper's reference; ``"rollout"``: the policy being
        trained, rolled out over the horizon (in-process environments only; about
        ``horizon - 1`` extra forward passes per step).
    lagrangian
        Train :class:`agents.training.lagrangian.PPOLagrangian` instead of PPO.
    cost_limit
        PPO-Lagrangian's limit on the mean episode cost (>= 0; 0: no collision).
    lambda_lr
        PPO-Lagrangian's dual step size (> 0).
    eval_freq
        Evaluate every ``eval_freq`` steps (summed over envs, >= 0; 0 disables) on
        held-out seeds (from ``seed + EVAL_SEED_OFFSET``), logging the safety metrics
        under ``eval/`` and saving the best model next to ``save_path``.
    eval_episodes
        Episodes per evaluation (>= 1).
    tensorboard_log
        Folder for TensorBoard event files (needs ``tensorboard``), or ``None``.
    print_metrics
        Print SB3's table (rollout, safety and training numbers) after every rollout.
    progress_bar
        Show a tqdm/rich progress bar.
    save_path
        The model file to write, exactly as named (a Stable-Baselines3 zip archive,
        whatever the suffix; its folders are made), or ``None``.
    metrics_path
        The per-rollout metrics CSV; default :func:`metrics_path_for` ``(save_path)``,
        none without ``save_path``.
    normalise_actions
        Let the learner act in ``[-1, 1]`` (default) instead of the ±10 m/s² box.
    vec_env
        ``"dummy"`` or ``"subproc"`` (see :func:`make_training_env`).
    ppo_kwargs
        Overrides of :data:`DEFAULT_PPO_KWARGS`.
    torch_threads
        ``torch.set_num_threads``; 1 is about 10x faster than torch's default here.
    verbose
        SB3 verbosity.

    Returns
    -------
    (stable_baselines3.PPO, TrainingReport)

    Raises
    ------
    InvalidParameterError, InvalidTypeError
        If an option is out of range, unknown or inconsistent.
    """
    for name, low in (("total_timesteps", 1), ("n_envs", 1), ("seed", 0), ("eval_freq", 0),
                      ("eval_episodes", 1), ("torch_threads", 1)):
        integer_at_least(name, locals()[name], low=low)
    finite_scalar("cost_limit", cost_limit, low=0.0)
    finite_scalar("lambda_lr", lambda_lr, low=0.0, strict=True)
    if vec_env not in VEC_ENVS:
        raise InvalidParameterError(f"vec_env must be one of {VEC_ENVS}, got {vec_env!r}")
    if filter_reference not in FILTER_REFERENCES:
        raise InvalidParameterError(
            f"filter_reference must be one of {FILTER_REFERENCES}, got {filter_reference!r}")
    if not lagrangian and (cost_limit != 0.0 or lambda_lr != 0.05):
        raise InvalidParameterError("cost_limit and lambda_lr need lagrangian=True")
    check_env_kwargs(env_id, env_kwargs)
    if filter_kwargs is None:
        if intervention_penalty:
            raise InvalidParameterError(
                "intervention_penalty needs the filter in the loop: pass filter_kwargs too")
        if filter_reference != "default":
            raise InvalidParameterError("filter_reference needs the filter: pass filter_kwargs")
    else:
        filter_kwargs = check_filter_kwargs(
            env_id, env_kwargs, filter_kwargs,
            **({"intervention_penalty": intervention_penalty} if intervention_penalty else {}))
        if filter_reference == "rollout":
            if vec_env != "dummy":
                raise InvalidParameterError(
                    "filter_reference='rollout' needs in-process environments (vec_env='dummy')")
            if "policy" in filter_kwargs or "reference" in filter_kwargs:
                raise InvalidParameterError(
                    "filter_reference='rollout' conflicts with filter_kwargs policy/reference")
    clash = sorted({"seed", "device", "verbose"} & set(ppo_kwargs or {}))
    if clash:  # they would be silently replaced by this function's own
        raise InvalidParameterError(f"ppo_kwargs must not set {clash}: pass seed= and "
                                    f"verbose= to train_ppo (device is cpu), got {ppo_kwargs}")
    if save_path is not None:
        save_path = _model_file(save_path)
        metrics_path = metrics_path_for(save_path) if metrics_path is None else metrics_path

    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.logger import CSVOutputFormat, HumanOutputFormat, Logger
    from stable_baselines3.common.utils import configure_logger

    from agents.training.callbacks import RefreshActor, SafetyEvalCallback, SafetyMetricsCallback
    from agents.training.lagrangian import CostPenaltyVecEnv, PPOLagrangian

    formats = [] if tensorboard_log is None else configure_logger(  # into <folder>/<name>_<k>
        0, str(tensorboard_log), "PPOLagrangian" if lagrangian else "PPO").output_formats
    set_torch_threads(torch_threads)
    training_policy = None
    if filter_kwargs is not None and filter_reference == "rollout":
        training_policy = TrainingPolicy()
        filter_kwargs["policy"] = training_policy
    vec_env_instance = make_training_env(
        env_id, n_envs=n_envs, seed=seed, env_kwargs=env_kwargs, filter_kwargs=filter_kwargs,
        normalise_actions=normalise_actions, vec_env=vec_env)
    kwargs = {**DEFAULT_PPO_KWARGS, **(ppo_kwargs or {}), "seed": seed, "device": "cpu",
              "verbose": verbose}
    model = (PPOLagrangian("MlpPolicy", vec_env_instance, cost_limit=cost_limit,
                           lambda_lr=lambda_lr, **kwargs) if lagrangian
             else PPO("MlpPolicy", vec_env_instance, **kwargs))
    if training_policy is not None:  # in-process copies: the physical box of the first
        training_policy.bind(model, vec_env_instance.envs[0].unwrapped.action_space)

    if print_metrics:
        formats.append(HumanOutputFormat(sys.stdout))
    if metrics_path is not None:
        metrics_path = Path(metrics_path)
        metrics_path.parent.mkdir(parents=True, exist_ok=True)
        formats.append(CSVOutputFormat(str(metrics_path)))
    model.set_logger(Logger(folder=None, output_formats=formats))

    safety = SafetyMetricsCallback()
    callbacks: list[Any] = [safety]
    if training_policy is not None:
        callbacks.append(RefreshActor(training_policy))
    best_model_path = None
    if eval_freq:
        eval_env = make_training_env(
            env_id, n_envs=1, seed=seed + EVAL_SEED_OFFSET, env_kwargs=env_kwargs,
            filter_kwargs=filter_kwargs, normalise_actions=normalise_actions, vec_env=vec_env)
        if lagrangian:  # same wrapper type as the training env (EvalCallback checks it);
            eval_env = CostPenaltyVecEnv(eval_env)  # multiplier 0: the task reward
        best_dir = None if save_path is None else save_path.with_name(save_path.stem + "_best")
        best_model_path = None if best_dir is None else best_dir / "best_model.zip"
        callbacks.append(SafetyEvalCallback(
            eval_env, eval_seed=seed + EVAL_SEED_OFFSET, n_eval_episodes=eval_episodes,
            eval_freq=max(1, eval_freq // n_envs), deterministic=True,
            best_model_save_path=best_dir and str(best_dir), log_path=best_dir and str(best_dir),
            verbose=verbose))
    start = time.perf_counter()
    try:
        model.learn(total_timesteps=total_timesteps, callback=CallbackList(callbacks),
                    progress_bar=progress_bar)
    finally:
        model.logger.close()
    wall_time = time.perf_counter() - start
    if save_path is not None:  # through a handle: SB3 would append ".zip" to a bare name
        save_path.parent.mkdir(parents=True, exist_ok=True)
        with save_path.open("wb") as handle:
            model.save(handle)
    steps = int(model.num_timesteps)
    report = TrainingReport(
        steps, wall_time, steps / max(wall_time, 1e-9), save_path,
        metrics_path=metrics_path,
        best_model_path=best_model_path if best_model_path and best_model_path.exists() else None,
        safety=dict(safety.rollout_metrics[-1]) if safety.rollout_metrics else {},
        lagrange_multiplier=getattr(model, "lagrange_multiplier", None),
    )
    return model, report


__all__ = [
    "DEFAULT_ENV_ID", "DEFAULT_PPO_KWARGS", "EVAL_SEED_OFFSET", "FILTER_REFERENCES", "VEC_ENVS",
    "TrainingPolicy", "TrainingReport", "check_env_kwargs", "check_filter_kwargs", "load_ppo",
    "make_training_env", "metrics_path_for", "pretrained_policy_path", "set_torch_threads",
    "train_ppo",
]

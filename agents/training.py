"""Train and load the PPO reference planner (Stable-Baselines3, PyTorch on the CPU).

The PPO policy is trained to reach its goal, not to be safe: the environment's
collision penalty is small by default. That is the point of the project: the
learned planner proposes, the safety filter disposes.

Training with the filter in the loop (safe exploration) is one argument away:
``filter_kwargs=dict(risk="dr_cvar")`` wraps every training environment in
:class:`filters.SafetyFilterWrapper`, and ``intervention_penalty`` makes the
agent pay for the filter's corrections.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from filters.errors import InvalidParameterError

DEFAULT_ENV_ID = "SafeNav/RandomCrossing-v0"
"""The randomised training scenario family."""

PRETRAINED_POLICY = "ppo_random_crossing.zip"
"""File name of the policy shipped in ``agents/pretrained``."""

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
    """

    total_timesteps: int
    wall_time: float
    steps_per_second: float
    save_path: Path | None


def pretrained_policy_path() -> Path:
    """Path of the PPO policy shipped with the package."""
    return Path(str(resources.files("agents") / "pretrained" / PRETRAINED_POLICY))


def make_training_env(
    env_id: str = DEFAULT_ENV_ID,
    *,
    n_envs: int = 8,
    seed: int = 0,
    env_kwargs: dict[str, Any] | None = None,
    filter_kwargs: dict[str, Any] | None = None,
):
    """In-process vector environment (``DummyVecEnv``) of ``n_envs`` copies, each monitored.

    With ``filter_kwargs`` every copy is wrapped in :class:`filters.SafetyFilterWrapper`.
    In-process environments beat subprocesses for a cheap simulator on 2 cores.
    """
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv

    import safe_nav_env  # noqa: F401  (registers the ids)

    wrapper_class = None
    wrapper_kwargs = None
    if filter_kwargs is not None:
        from filters import SafetyFilterWrapper

        wrapper_class, wrapper_kwargs = SafetyFilterWrapper, dict(filter_kwargs)
    return make_vec_env(
        env_id, n_envs=n_envs, seed=seed, env_kwargs=env_kwargs or {},
        wrapper_class=wrapper_class, wrapper_kwargs=wrapper_kwargs, vec_env_cls=DummyVecEnv,
    )


def train_ppo(
    env_id: str = DEFAULT_ENV_ID,
    total_timesteps: int = 400_000,
    seed: int = 0,
    *,
    n_envs: int = 8,
    env_kwargs: dict[str, Any] | None = None,
    filter_kwargs: dict[str, Any] | None = None,
    intervention_penalty: float = 0.0,
    eval_freq: int = 0,
    eval_episodes: int = 20,
    tensorboard_log: str | None = None,
    progress_bar: bool = True,
    save_path: str | Path | None = None,
    ppo_kwargs: dict[str, Any] | None = None,
    torch_threads: int = 1,
    verbose: int = 0,
):
    """Train a PPO reference planner with Stable-Baselines3.

    Parameters
    ----------
    env_id
        A registered ``SafeNav/...`` id (default: the randomised crossings).
    total_timesteps
        Environment steps, summed over the vector environments.
    seed
        Seeds PPO (torch and its action noise) and the environments.
    n_envs
        Number of in-process environments.
    env_kwargs
        Passed to ``gym.make`` (e.g. ``n_samples``, ``collision_penalty``).
    filter_kwargs
        If given, train with :class:`filters.SafetyFilterWrapper` in the loop,
        e.g. ``{"risk": "dr_cvar"}`` (safe exploration).
    intervention_penalty
        With the filter in the loop: reward penalty per ``||u_safe - u_ref||²``.
    eval_freq
        Evaluate every ``eval_freq`` steps (summed over envs) on separate seeds; 0 disables.
    eval_episodes
        Episodes per evaluation.
    tensorboard_log
        Folder for TensorBoard logs (needs ``tensorboard`` installed), or ``None``.
    progress_bar
        Show a tqdm/rich progress bar.
    save_path
        Where to save the model (``.zip``), or ``None``.
    ppo_kwargs
        Overrides of :data:`DEFAULT_PPO_KWARGS`.
    torch_threads
        ``torch.set_num_threads``; 1 is about 10x faster than torch's default here.

    Returns
    -------
    (stable_baselines3.PPO, TrainingReport)
    """
    if total_timesteps <= 0:
        raise InvalidParameterError(f"total_timesteps must be > 0, got {total_timesteps!r}")
    if n_envs < 1:
        raise InvalidParameterError(f"n_envs must be >= 1, got {n_envs!r}")
    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(torch_threads)
    if filter_kwargs is not None and intervention_penalty:
        filter_kwargs = {**filter_kwargs, "intervention_penalty": intervention_penalty}
    elif intervention_penalty:
        raise InvalidParameterError(
            "intervention_penalty needs the filter in the loop: pass filter_kwargs too"
        )
    vec_env = make_training_env(env_id, n_envs=n_envs, seed=seed, env_kwargs=env_kwargs,
                                filter_kwargs=filter_kwargs)
    kwargs = {**DEFAULT_PPO_KWARGS, **(ppo_kwargs or {})}
    model = PPO("MlpPolicy", vec_env, seed=seed, device="cpu", verbose=verbose,
                tensorboard_log=tensorboard_log, **kwargs)
    callback = None
    if eval_freq:
        from stable_baselines3.common.callbacks import EvalCallback

        eval_env = make_training_env(env_id, n_envs=1, seed=seed + 10_000,
                                     env_kwargs=env_kwargs, filter_kwargs=filter_kwargs)
        callback = EvalCallback(eval_env, n_eval_episodes=eval_episodes,
                                eval_freq=max(1, eval_freq // n_envs), deterministic=True,
                                verbose=verbose)
    start = time.perf_counter()
    model.learn(total_timesteps=total_timesteps, callback=callback, progress_bar=progress_bar)
    wall_time = time.perf_counter() - start
    path = None
    if save_path is not None:
        path = Path(save_path)
        path.parent.mkdir(parents=True, exist_ok=True)
        model.save(path)
    steps = int(model.num_timesteps)
    return model, TrainingReport(steps, wall_time, steps / max(wall_time, 1e-9), path)


def load_ppo(path: str | Path | None = None):
    """Load a PPO policy; with no argument, the one shipped with the package.

    Raises
    ------
    FileNotFoundError
        If ``path`` (or the shipped policy) does not exist.
    """
    from stable_baselines3 import PPO

    path = pretrained_policy_path() if path is None else Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no PPO policy at {path}")
    return PPO.load(path, device="cpu")


def set_torch_threads(n: int = 1) -> None:
    """Use ``n`` torch threads (1 is fastest for small MLPs on this machine)."""
    import torch

    torch.set_num_threads(n)


__all__ = [
    "DEFAULT_ENV_ID", "DEFAULT_PPO_KWARGS", "TrainingReport", "load_ppo", "make_training_env",
    "pretrained_policy_path", "set_torch_threads", "train_ppo",
]

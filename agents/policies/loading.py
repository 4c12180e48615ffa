"""Load a trained PPO policy: the one shipped with the package, or a saved ``.zip``."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["PRETRAINED_POLICY", "load_ppo", "pretrained_policy_path", "set_torch_threads"]

PRETRAINED_POLICY = "ppo_random_crossing.zip"
"""File name of the policy shipped in ``agents/pretrained``."""


def pretrained_policy_path(name: str = PRETRAINED_POLICY) -> Path:
    """Path of a PPO policy shipped with the package (default: the RandomCrossing one)."""
    return Path(str(resources.files("agents") / "pretrained" / name))


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

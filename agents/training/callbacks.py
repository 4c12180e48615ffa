"""Safety metrics while training: Stable-Baselines3 callbacks.

:class:`SafetyMetricsCallback` counts, over the episodes that end during each
rollout (from the vector environment's ``infos`` and ``dones``; DummyVecEnv and
SubprocVecEnv alike), and logs to SB3's logger (so to the stdout table, the
CSV and TensorBoard, whichever the logger writes):

=============================  ===================================================
``safety/collision_rate``      share of episodes with a collision at any step
                               (``info["collision"]``: continuous time)
``safety/episode_cost``        mean over episodes of :math:`\\sum_t` ``info["cost"]``
``safety/goal_rate``           share of episodes ending with ``info["is_success"]``
``safety/episodes``            episodes that ended in the rollout
``safety/intervention``        mean ``info["filter"].intervention`` (m/s²) over the
                               rollout's filtered steps (logged when a filter runs)
``safety/status_<name>``       share of the rollout's filtered steps with that
                               filter status (``optimal``, ``soft``, ...)
=============================  ===================================================

:class:`SafetyEvalCallback` is SB3's ``EvalCallback`` (it saves the best model)
with the same numbers under ``eval/``, on held-out seeds that are the same at
every evaluation.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback, EvalCallback

from agents.training.wrappers import EpisodeSafety, SafetyTally


def record_metrics(logger: Any, prefix: str, metrics: dict[str, float]) -> None:
    """``logger.record(f"{prefix}/{key}", value)`` for every metric."""
    for key, value in metrics.items():
        logger.record(f"{prefix}/{key}", value)


class SafetyMetricsCallback(BaseCallback):
    """Log the safety of the training episodes at the end of every rollout.

    Each rollout's numbers cover the episodes that *ended* in it (an episode that
    spans two rollouts counts in the second) and the steps taken in it; see the
    module docstring for the keys (prefix ``safety/``).

    Parameters
    ----------
    verbose
        SB3 verbosity (0: silent).

    Attributes
    ----------
    history
        Every finished episode, in order of completion (all rollouts).
    rollout_metrics
        One dict of metrics per rollout, as logged.
    """

    def __init__(self, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.history: list[EpisodeSafety] = []
        self.rollout_metrics: list[dict[str, float]] = []
        self._tally = SafetyTally(0)  # sized by _on_training_start

    def _on_training_start(self) -> None:
        self._tally = SafetyTally(self.training_env.num_envs)

    def _on_rollout_start(self) -> None:
        self._tally.clear_window()

    def _on_step(self) -> bool:
        infos: Sequence[dict[str, Any]] = self.locals["infos"]
        for index, (info, done) in enumerate(zip(infos, self.locals["dones"], strict=True)):
            episode = self._tally.step(index, info, bool(done))
            if episode is not None:
                self.history.append(episode)
        return True

    def _on_rollout_end(self) -> None:
        metrics = self._tally.metrics()
        self.rollout_metrics.append(metrics)
        record_metrics(self.logger, "safety", metrics)


class SafetyEvalCallback(EvalCallback):
    """SB3's ``EvalCallback`` that also logs the safety metrics (prefix ``eval/``).

    Every evaluation reseeds the evaluation environment with ``eval_seed`` first, so
    that every evaluation runs the same held-out episodes (up to the policy's
    actions). The best model by mean return is saved to ``best_model_save_path``.

    Parameters
    ----------
    eval_env
        The evaluation vector environment (same wrappers as the training one).
    eval_seed
        Seed of the evaluation episodes (keep it apart from the training seeds).
    **kwargs
        Passed to ``EvalCallback`` (``n_eval_episodes``, ``eval_freq`` in calls, ...).

    Attributes
    ----------
    evaluations_safety
        One dict of metrics per evaluation.
    """

    def __init__(self, eval_env: Any, *, eval_seed: int, **kwargs: Any) -> None:
        super().__init__(eval_env, **kwargs)
        self.eval_seed = int(eval_seed)
        self.evaluations_safety: list[dict[str, float]] = []
        self._eval_tally = SafetyTally(0)  # a new one per evaluation

    def _log_success_callback(self, locals_: dict[str, Any], globals_: dict[str, Any]) -> None:
        super()._log_success_callback(locals_, globals_)
        tally = self._eval_tally  # recorded as episodes end: the values stand when it dumps
        if tally.step(int(locals_["i"]), locals_["info"], bool(locals_["done"])) is not None:
            record_metrics(self.logger, "eval", tally.metrics())

    def _on_step(self) -> bool:
        evaluating = self.eval_freq > 0 and self.n_calls % self.eval_freq == 0
        if evaluating:
            self.eval_env.seed(self.eval_seed)
            self._eval_tally = SafetyTally(self.eval_env.num_envs)
        keep_going = super()._on_step()
        if evaluating:
            self.evaluations_safety.append(self._eval_tally.metrics())
        return keep_going


class RefreshActor(BaseCallback):
    """Call ``policy.refresh()`` at the start of every rollout: the policy being trained
    (:class:`agents.training.ppo.TrainingPolicy`) exported again for the roll-out reference."""

    def __init__(self, policy: Any) -> None:
        super().__init__()
        self.policy = policy

    def _on_rollout_start(self) -> None:
        self.policy.refresh()

    def _on_step(self) -> bool:
        return True


__all__ = ["RefreshActor", "SafetyEvalCallback", "SafetyMetricsCallback", "record_metrics"]

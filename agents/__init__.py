"""Reference planners and their evaluation with and without the safety filter.

* :func:`train_ppo`, :func:`load_ppo` — the PPO reference planner (Stable-Baselines3);
  ``load_ppo()`` loads the policy shipped with the package.
* :func:`load_numpy_policy`, :class:`NumpyPolicy` — the same actor exported once to
  numpy (a faster deterministic ``predict``, for the filter's roll-out reference);
  ``agents.TorchActorPolicy`` is a deprecated alias of :class:`NumpyPolicy` (it warns;
  not in ``__all__``).
* :class:`MPCReferencePlanner` — the paper's obstacle-agnostic goal-tracking MPC.
* :func:`evaluate` — Monte Carlo comparison of risk settings, one record per episode
  (:mod:`agents.evaluation.records`: specs, records, CSV;
  :mod:`agents.evaluation.runner`: one episode;
  :mod:`agents.evaluation.executors`: process pool, Ray).
* :class:`SafetyMetricsCallback` (SB3 callback: safety metrics per rollout) and
  :class:`PPOLagrangian` (the constrained-RL baseline), imported on first use.

torch and Stable-Baselines3 are imported only when a PPO policy is trained or loaded.
"""

from agents.errors import AgentsError, PolicyFileError, RunMismatchError
from agents.evaluation.evaluate import evaluate
from agents.evaluation.records import EpisodeRecord, EpisodeSpec
from agents.evaluation.runner import run_episode
from agents.evaluation.summary import summarise
from agents.planners import MPCReferencePlanner
from agents.policies.numpy_policy import NumpyPolicy, load_numpy_policy
from agents.training.ppo import load_ppo, train_ppo

_LAZY = {
    "SafetyMetricsCallback": "agents.training.callbacks",
    "SafetyEvalCallback": "agents.training.callbacks",
    "PPOLagrangian": "agents.training.lagrangian",
    "TorchActorPolicy": "agents.policies.numpy_policy",  # deprecated alias: warns
}
"""Names loaded on first access: modules that import Stable-Baselines3 (and torch), and
the deprecated alias ``TorchActorPolicy`` of :class:`NumpyPolicy` (its access warns)."""


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'agents' has no attribute {name!r}")


__all__ = ["AgentsError", "EpisodeRecord", "EpisodeSpec", "MPCReferencePlanner", "NumpyPolicy",
           "PPOLagrangian", "PolicyFileError", "RunMismatchError", "SafetyEvalCallback",
           "SafetyMetricsCallback", "evaluate", "load_numpy_policy", "load_ppo", "run_episode",
           "summarise", "train_ppo"]

"""PPO-Lagrangian: the constrained-RL baseline, built on Stable-Baselines3's PPO.

The constrained problem (a CMDP) and its Lagrangian relaxation:

.. math::

    \\max_\\pi J_r(\\pi) \\;\\text{s.t.}\\; J_c(\\pi) \\le d
    \\quad\\leadsto\\quad
    \\min_{\\lambda \\ge 0} \\max_\\pi \\; J_r(\\pi) - \\lambda\\,(J_c(\\pi) - d),

with :math:`J_c` the expected episode cost, :math:`c_t` = ``info["cost"]``, the
environment's continuous-time collision indicator (1 for a step whose exact
minimum clearance is <= 0, else 0), and :math:`d` = ``cost_limit``.

**Policy step (the primal).** PPO is run, unchanged, on the penalised reward
:math:`r_t - \\lambda c_t` (the *reward-penalty* form of PPO-Lagrangian). This is
the same as combining the advantages, :math:`A_r - \\lambda A_c`, when both are
estimated by GAE with one value function of the penalised return; we learn that
one value head (SB3's), not a separate cost value head. So the critic estimates
the penalised return under the current :math:`\\lambda`, and lags behind it for a
few updates when :math:`\\lambda` moves.

**Multiplier step (the dual).** After each rollout, projected dual (gradient)
ascent on the Monte Carlo estimate of :math:`J_c`, the mean episode cost of the
episodes that ended in that rollout (no update if none ended):

.. math:: \\lambda \\leftarrow \\max\\bigl(0,\\; \\lambda + \\eta_\\lambda (\\hat J_c - d)\\bigr),
          \\qquad \\eta_\\lambda = ``lambda_lr``.

:math:`\\lambda` rises while the episodes cost more than the limit and falls
(to 0, where the projection holds it) while they cost less. It is logged as
``lagrangian/lambda`` with ``lagrangian/episode_cost`` and saved with the model.

Why not OmniSafe (the usual home of PPO-Lagrangian): it pulls in
safety-gymnasium, which pins Gymnasium 0.28 and cannot live with Gymnasium 1.x,
which this project needs. The few lines here keep everything on SB3.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3 import PPO
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecEnvWrapper

from filters._validation import finite_array, finite_scalar
from filters.errors import InvalidTypeError


def dual_ascent_step(
    multiplier: float, episode_cost: float, *, cost_limit: float, lr: float
) -> float:
    """One projected dual-ascent step of the Lagrange multiplier.

    .. math:: \\lambda' = \\max(0, \\lambda + \\eta (\\hat J_c - d))

    Parameters
    ----------
    multiplier
        Current :math:`\\lambda >= 0`.
    episode_cost
        Mean episode cost :math:`\\hat J_c` of the rollout (>= 0).
    cost_limit
        :math:`d >= 0`.
    lr
        Step size :math:`\\eta > 0`.

    Raises
    ------
    InvalidParameterError
        If a value is negative or not finite.
    """
    multiplier = finite_scalar("multiplier", multiplier, low=0.0)
    episode_cost = finite_scalar("episode_cost", episode_cost, low=0.0)
    cost_limit = finite_scalar("cost_limit", cost_limit, low=0.0)
    lr = finite_scalar("lr", lr, low=0.0, strict=True)
    return max(0.0, multiplier + lr * (episode_cost - cost_limit))


class CostPenaltyVecEnv(VecEnvWrapper):
    """Subtract ``multiplier * info["cost"]`` from each reward; collect episode costs.

    The per-environment ``Monitor`` sits inside, so ``rollout/ep_rew_mean`` stays
    the task return; the learner sees :math:`r_t - \\lambda c_t`.

    Attributes
    ----------
    multiplier
        :math:`\\lambda`, set by :class:`PPOLagrangian` before each rollout.
    finished_costs
        Costs of the episodes that ended since the last :meth:`pop_episode_costs`.
    """

    def __init__(self, venv: VecEnv) -> None:
        super().__init__(venv)
        self.multiplier = 0.0
        self._running = np.zeros(self.num_envs)
        self.finished_costs: list[float] = []

    def reset(self):
        self._running[:] = 0.0
        return self.venv.reset()

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        costs = finite_array("info['cost']", [info.get("cost", 0.0) for info in infos])
        self._running += costs
        for index in np.flatnonzero(dones):
            self.finished_costs.append(float(self._running[index]))
            self._running[index] = 0.0
        penalised = np.asarray(rewards, dtype=np.float32) - np.float32(self.multiplier) * costs
        return obs, penalised.astype(np.float32), dones, infos

    def pop_episode_costs(self) -> list[float]:
        """The finished episodes' costs, emptying the list."""
        costs, self.finished_costs = self.finished_costs, []
        return costs


def _as_penalty_env(env: Any) -> CostPenaltyVecEnv | None:
    if env is None or isinstance(env, CostPenaltyVecEnv):  # None: PPO.load without env
        return env
    if isinstance(env, gym.Env):
        env = DummyVecEnv([lambda: Monitor(env)])
    if not isinstance(env, VecEnv):
        raise InvalidTypeError(
            f"env must be a gymnasium Env or an SB3 VecEnv, got {type(env).__name__}"
        )
    return CostPenaltyVecEnv(env)


class PPOLagrangian(PPO):
    """PPO on :math:`r - \\lambda c` with :math:`\\lambda` by projected dual ascent.

    See the module docstring for the method. All of PPO's options apply.

    Parameters
    ----------
    policy
        As for PPO (``"MlpPolicy"``).
    env
        A gymnasium environment or an SB3 vector environment whose infos carry
        ``"cost"`` (``safe_nav_env`` environments do); it is wrapped in
        :class:`CostPenaltyVecEnv`.
    cost_limit
        :math:`d`, the allowed mean episode cost (>= 0); 0 asks for no collision.
    lambda_lr
        Dual step size :math:`\\eta_\\lambda` (> 0), per unit of episode cost.
    lambda_init
        Initial multiplier (>= 0).
    **kwargs
        Passed to ``stable_baselines3.PPO``.

    Attributes
    ----------
    lagrange_multiplier
        The current :math:`\\lambda`.
    multiplier_history
        ``(num_timesteps, mean episode cost, lambda after the update)`` per rollout
        that ended at least one episode.
    """

    def __init__(self, policy: Any, env: Any, *, cost_limit: float = 0.0,
                 lambda_lr: float = 0.05, lambda_init: float = 0.0, **kwargs: Any) -> None:
        self.cost_limit = finite_scalar("cost_limit", cost_limit, low=0.0)
        self.lambda_lr = finite_scalar("lambda_lr", lambda_lr, low=0.0, strict=True)
        self.lagrange_multiplier = finite_scalar("lambda_init", lambda_init, low=0.0)
        self.multiplier_history: list[tuple[int, float, float]] = []
        super().__init__(policy, _as_penalty_env(env), **kwargs)

    def set_env(self, env: Any, force_reset: bool = True) -> None:
        super().set_env(_as_penalty_env(env), force_reset=force_reset)

    def collect_rollouts(self, env, callback, rollout_buffer, n_rollout_steps) -> bool:
        self.env.multiplier = self.lagrange_multiplier  # a CostPenaltyVecEnv: __init__, set_env
        keep_going = super().collect_rollouts(env, callback, rollout_buffer, n_rollout_steps)
        costs = self.env.pop_episode_costs()
        if costs:
            mean_cost = float(np.mean(costs))
            self.lagrange_multiplier = dual_ascent_step(
                self.lagrange_multiplier, mean_cost, cost_limit=self.cost_limit,
                lr=self.lambda_lr)
            self.multiplier_history.append(
                (int(self.num_timesteps), mean_cost, self.lagrange_multiplier))
            self.logger.record("lagrangian/episode_cost", mean_cost)
        self.logger.record("lagrangian/lambda", self.lagrange_multiplier)
        self.logger.record("lagrangian/cost_limit", self.cost_limit)
        return keep_going


__all__ = ["CostPenaltyVecEnv", "PPOLagrangian", "dual_ascent_step"]

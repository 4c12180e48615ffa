"""
Training PPO with the filter in the loop
========================================

A tiny Stable-Baselines3 PPO run (a few thousand steps: far too short to learn the
task, long enough to see the metrics) on ``SafeNav/RandomCrossing-v0`` with the
DR-CVaR filter wrapped around the environment, so every action the policy tries is
filtered. :class:`agents.SafetyMetricsCallback` records, per rollout, the
continuous-time collision rate, the goal rate and the filter's mean intervention. The
same run without the filter is the comparison. For real training use
:func:`agents.train_ppo` or ``safe-nav train --filter dr_cvar``.
"""

import gymnasium as gym
import matplotlib.pyplot as plt
import torch
from stable_baselines3 import PPO

import safe_nav_env  # noqa: F401
from agents import SafetyMetricsCallback
from filters import SafetyFilterWrapper

torch.set_num_threads(1)
STEPS = 2048


def train(filtered: bool) -> SafetyMetricsCallback:
    env = gym.make("SafeNav/RandomCrossing-v0")
    if filtered:
        env = SafetyFilterWrapper(env, risk="dr_cvar", alpha=0.2, delta=0.1, epsilon=0.05)
    callback = SafetyMetricsCallback()
    model = PPO("MlpPolicy", env, n_steps=256, batch_size=128, n_epochs=4, seed=0,
                device="cpu")
    model.learn(total_timesteps=STEPS, callback=callback)
    env.close()
    return callback


runs = {"PPO": train(False), "PPO + DR-CVaR filter in the loop": train(True)}
for label, callback in runs.items():
    last = callback.rollout_metrics[-1]
    print(label, {k: round(v, 3) for k, v in last.items()})

# %%
# Per rollout (256 steps each): the share of the episodes that ended in it with a
# collision, and the filter's mean correction of the policy's action.
fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(8.0, 3.4))
for label, callback in runs.items():
    rollouts = range(1, len(callback.rollout_metrics) + 1)
    ax1.plot(rollouts, [m.get("collision_rate", float("nan"))
                        for m in callback.rollout_metrics], "o-", label=label)
    ax2.plot(rollouts, [m.get("intervention", 0.0) for m in callback.rollout_metrics],
             "o-", label=label)
ax1.set_xlabel("rollout (256 steps each)")
ax1.set_ylabel("collision rate (share of episodes)")
ax1.set_title("Collisions while training")
ax2.set_xlabel("rollout (256 steps each)")
ax2.set_ylabel("mean intervention (m/s²)")
ax2.set_title("Filter's correction of the actions")
for ax in (ax1, ax2):
    ax.legend(fontsize=8)
fig.suptitle("PPO on RandomCrossing, with and without the filter in the loop")
fig.tight_layout()
plt.show()

"""
The environment and the filter in ten lines
===========================================

Make an environment, put the DR-CVaR safety filter around it, and let the shipped PPO
planner drive: the planner proposes an acceleration, the filter changes it as little
as it can while keeping the robot inside the safe halfspaces. The same seed runs once
without the filter for comparison.
"""

import gymnasium as gym
import matplotlib.pyplot as plt

import safe_nav_env  # noqa: F401  (registers the SafeNav/* ids)
from agents import load_ppo
from filters import SafetyFilterWrapper

policy = load_ppo()  # the shipped PPO reference planner


def run(filtered: bool, seed: int = 0):
    env = gym.make("SafeNav/Intersection-v0")
    if filtered:
        env = SafetyFilterWrapper(env, risk="dr_cvar", alpha=0.2, delta=0.1, epsilon=0.05,
                                  policy=policy)
    obs, info = env.reset(seed=seed)
    times, clearance, done = [0.0], [info["min_distance_to_collision"]], False
    while not done:
        action, _ = policy.predict(obs, deterministic=True)  # the planner proposes ...
        obs, reward, terminated, truncated, info = env.step(action)  # ... the filter disposes
        times.append(info["time"])
        clearance.append(info["min_swept_distance_to_collision"])
        done = terminated or truncated
    env.close()
    return times, clearance, info


# %%
# Run the same seed with and without the filter and print how each episode ended.
runs = {"PPO alone": run(False), "PPO + DR-CVaR filter": run(True)}
for label, (_, clearance, info) in runs.items():
    print(f"{label:22s} collision: {min(clearance) <= 0}, goal reached: {info['is_success']}")

# %%
# The clearance to the nearest obstacle over the episode (continuous time: the
# minimum over each 0.2 s step). Below zero the robot and the obstacle overlap.
fig, ax = plt.subplots(figsize=(6.4, 3.6))
for label, (times, clearance, _) in runs.items():
    ax.plot(times, clearance, marker="o", markersize=3, label=label)
ax.axhline(0.0, color="black", linewidth=0.8, linestyle="--", label="contact (clearance 0)")
ax.set_xlabel("time (s)")
ax.set_ylabel("clearance to nearest obstacle (m)")
ax.set_title("Intersection, seed 0: PPO with and without the DR-CVaR filter")
ax.legend()
fig.tight_layout()
plt.show()

"""
Filtered against unfiltered: a small evaluation
===============================================

:func:`agents.evaluate` runs seeded episodes of the shipped PPO planner for every
(scenario, risk) pair and returns one :class:`agents.EpisodeRecord` per episode (the
rows of ``safe-nav evaluate``'s CSV); :func:`agents.summarise` aggregates them with
Wilson 95 % intervals. Twenty episodes per cell here: the intervals are wide. The
command line runs 300 (``safe-nav evaluate``).
"""

import matplotlib.pyplot as plt
import numpy as np

from agents import evaluate, summarise

scenarios = ["Intersection", "MultiObstacle"]
risks = ["none", "mean", "cvar", "dr_cvar"]
records = evaluate(scenarios, risks, episodes=20, seed=0, workers=1, progress=False)
rows = {(row.scenario, row.risk): row for row in summarise(records)}
for (scenario, risk), row in rows.items():
    print(f"{scenario:14s} {risk:8s} collisions {row.collision_rate:6.1%} "
          f"[{row.collision_low:.1%}, {row.collision_high:.1%}]  goal {row.goal_rate:6.1%}  "
          f"intervention {row.mean_intervention:.2f} m/s²")

# %%
# Continuous-time collision rate per scenario and risk, with the Wilson 95 % interval.
fig, ax = plt.subplots(figsize=(7.0, 3.8))
width = 0.8 / len(risks)
labels = {"none": "unfiltered", "mean": "mean", "cvar": "CVaR", "dr_cvar": "DR-CVaR"}
for j, risk in enumerate(risks):
    x = np.arange(len(scenarios)) + (j - (len(risks) - 1) / 2) * width
    rate = np.array([rows[s, risk].collision_rate for s in scenarios])
    low = np.array([rows[s, risk].collision_low for s in scenarios])
    high = np.array([rows[s, risk].collision_high for s in scenarios])
    bars = ax.bar(x, 100 * rate, width, label=labels[risk],
                  yerr=100 * np.vstack([rate - low, high - rate]), capsize=3)
    counts = [f"{round(rows[s, risk].collision_rate * rows[s, risk].episodes)}"
              f"/{rows[s, risk].episodes}" for s in scenarios]
    ax.bar_label(bars, counts, fontsize=7, padding=2)  # collided / episodes, 0/20 too
ax.set_xticks(np.arange(len(scenarios)), scenarios)
ax.set_ylabel("collision rate (% of episodes)")
ax.set_xlabel("scenario (20 episodes per bar, seeds 0-19)")
ax.set_ylim(0, 112)
ax.set_title("Shipped PPO planner: collision rate by filter risk (Wilson 95 % CI)")
ax.legend(title="filter", fontsize=8)
fig.tight_layout()
plt.show()

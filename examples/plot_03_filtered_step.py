"""
One filtered step, drawn
========================

One step of the MPC safety filter (the paper's Problem 2) by hand, with
:func:`filters.safe_halfspaces` and :class:`filters.MPCSafetyFilter`. In
``SafeNav/HeadOn-v0`` the robot drives at 1.5 m/s towards an obstacle that comes the
other way. After 1 s the reference (hold zero acceleration for the next 2 s) runs
through the obstacle's predicted positions; the filter returns the closest plan that
keeps the robot inside the DR-CVaR safe halfspaces at every predicted step.

Each halfspace's normal points from the reference position of its step to the mean of
the obstacle's samples there (the paper's choice). Where the reference has already
passed the obstacle (the later steps) the safe side therefore flips to the far side:
the filtered plan brakes, swerves and passes.
"""

import gymnasium as gym
import matplotlib.pyplot as plt
import numpy as np

import safe_nav_env  # noqa: F401
from filters import Disc, MPCSafetyFilter, safe_halfspaces

env = gym.make("SafeNav/HeadOn-v0")
obs, info = env.reset(seed=0)
for _ in range(5):  # 1 s of driving straight on
    obs, reward, terminated, truncated, info = env.step(np.zeros(2, dtype=np.float32))
base = env.unwrapped
A, B, C = base.dynamics
T = base.horizon if hasattr(base, "horizon") else 10
x0 = base.ego_state.copy()

# the reference: hold u = 0 over the horizon (states 0..T, row 0 = x0)
reference = [x0]
for _ in range(T):
    reference.append(A @ reference[-1])
reference = np.array(reference)

samples = info["predictions"]  # (n_obstacles, N_s, T, 2): steps t+1 .. t+T
hs = safe_halfspaces(reference[1:] @ C.T, samples, ego_shape=Disc(base.ego_radius),
                     obstacle_shapes=[Disc(r) for r in base.obstacle_radii],
                     risk="dr_cvar", alpha=0.2, delta=0.1, epsilon=0.05)
mpc = MPCSafetyFilter(A, B, C, horizon=T, Q=np.diag([1.0, 1.0, 0.1, 0.1]),
                      Q_terminal=np.diag([1.0, 1.0, 0.1, 0.1]), R=0.1 * np.eye(2),
                      input_bounds=base.input_bounds, position_bounds=base.position_bounds,
                      n_obstacles=samples.shape[0])
result = mpc.solve(x0, reference, hs)
print(f"status: {result.status.value}, first input {np.round(result.inputs[0], 3)} m/s², "
      f"solve time {1e3 * result.solve_time:.3f} ms")
plan = result.states @ C.T

# %%
# Reference, filtered plan, predicted obstacle samples and three of the ten halfspaces
# (step 1, 5 and 10 of the horizon; each arrow points into the safe side).
fig, ax = plt.subplots(figsize=(7.0, 5.6))
steps = [0, 4, 9]
colors = plt.cm.plasma(np.linspace(0.1, 0.8, len(steps)))
for k, color in zip(steps, colors, strict=True):
    pts = samples[0, :, k]
    ax.scatter(*pts.T, s=4, color=color, alpha=0.5,
               label=f"obstacle samples, step {k + 1} ({0.2 * (k + 1):.1f} s ahead)")
    a, b = hs.normals[0, k], hs.offsets[0, k]
    tangent = np.array([-a[1], a[0]])
    line = b * a + np.linspace(-3, 3, 2)[:, None] * tangent
    ax.plot(*line.T, color=color, linestyle="--",
            label=f"DR-CVaR halfspace boundary, step {k + 1} (arrow: safe side)")
    height = -0.6 - 0.4 * steps.index(k)  # arrows at different heights, below the plan
    foot = b * a + (height - b * a[1]) / tangent[1] * tangent if abs(tangent[1]) > 0.1 else b * a
    ax.annotate("", xy=foot - 0.5 * a, xytext=foot,
                arrowprops={"arrowstyle": "->", "color": color, "linewidth": 1.5})
ax.plot(*reference[:, :2].T, "o-", color="tab:red", markersize=3, label="reference (hold u = 0)")
ax.plot(*plan.T, "o-", color="tab:green", markersize=3, label="filtered plan")
ax.plot(*x0[:2], "s", color="black", label="ego now")
ax.set_xlim(-4.0, 2.5)
ax.set_ylim(-2.0, 1.5)
ax.set_aspect("equal")
ax.set_xlabel("x (m)")
ax.set_ylabel("y (m)")
ax.set_title("HeadOn, t = 1 s: reference against the DR-CVaR filtered plan")
ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2)
fig.tight_layout()
plt.show()

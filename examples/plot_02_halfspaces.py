"""
Safe halfspaces of the mean, CVaR and DR-CVaR
=============================================

The paper's Example 1: an ego reference position :math:`y^r = (-0.9, -0.8)` m, an
obstacle predicted around :math:`p = (0.5, 0)` m by 100 samples of
:math:`\\mathcal N(p, 0.01 I)`, both discs of radius 0.3 m, :math:`\\alpha = 0.2`,
:math:`\\delta = 0.1` m. :func:`filters.safe_halfspaces` returns one halfspace
``normal @ y <= offset`` per risk; the safe side is the one containing the reference.
DR-CVaR moves the boundary back by :math:`\\varepsilon / \\alpha` from CVaR.
"""

import matplotlib.pyplot as plt
import numpy as np

from filters import Disc, safe_halfspaces

rng = np.random.default_rng(0)
y_ref = np.array([-0.9, -0.8])
p = np.array([0.5, 0.0])
samples = p + 0.1 * rng.standard_normal((100, 2))  # N(p, 0.01 I)
# shapes: reference (T, d) = (1, 2); samples (n_obstacles, N_s, T, d) = (1, 100, 1, 2)
reference, points = y_ref[None, :], samples[None, :, None, :]

settings = [("mean", {}), ("cvar", {}), ("dr_cvar", {"epsilon": 0.05}),
            ("dr_cvar", {"epsilon": 0.1}), ("dr_cvar", {"epsilon": 0.2})]
fig, ax = plt.subplots(figsize=(6.0, 5.4))
ax.scatter(*samples.T, s=6, color="tab:gray", label="obstacle samples (100)")
ax.add_patch(plt.Circle(y_ref, 0.3, fill=False, color="tab:blue"))
ax.plot(*y_ref, "o", color="tab:blue", label="ego reference $y^r$ (disc r = 0.3 m)")
t = np.linspace(-2.5, 2.5, 2)
colors = plt.cm.viridis(np.linspace(0, 0.9, len(settings)))
for (risk, extra), color in zip(settings, colors, strict=True):
    hs = safe_halfspaces(reference, points, ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.3)],
                         risk=risk, alpha=0.2, delta=0.1, **extra)
    a, b = hs.normals[0, 0], hs.offsets[0, 0]
    # the boundary a @ y = b: the point b a plus multiples of the tangent
    tangent = np.array([-a[1], a[0]])
    line = b * a + t[:, None] * tangent
    label = risk if not extra else f"DR-CVaR, ε = {extra['epsilon']} m"
    label = {"mean": "mean", "cvar": "CVaR"}.get(label, label)
    ax.plot(*line.T, color=color, label=f"{label}: offset b = {b:.3f} m")
    print(f"{label:20s} normal {np.round(a, 3)}  offset {b:.4f} m  "
          f"reference safe: {a @ y_ref <= b}")
ax.annotate("", xy=p, xytext=y_ref, arrowprops={"arrowstyle": "->", "color": "black"})
ax.set_xlim(-1.6, 1.2)
ax.set_ylim(-1.4, 0.8)
ax.set_aspect("equal")
ax.set_xlabel("x (m)")
ax.set_ylabel("y (m)")
ax.set_title("Boundaries of the safe halfspaces by risk metric\n(safe side: towards the ego)")
ax.legend(fontsize=8, loc="upper left")
fig.tight_layout()
plt.show()

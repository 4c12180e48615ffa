"""Figures of an evaluation: the paper's Fig. 2-5 and a few more, saved as PNG/GIF.

All functions take plain data (records, trajectories, summary rows), draw with
matplotlib's Agg backend, save to ``path`` and return it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from agents.evaluation import EpisodeRecord, Trajectory
from agents.summary import RISK_ORDER, SummaryRow, short_name

RISK_COLORS = {"none": "tab:gray", "mean": "tab:red", "cvar": "tab:blue", "dr_cvar": "tab:green"}
"""The paper's colours: red mean, blue CVaR, green DR-CVaR (grey: unfiltered)."""
RISK_LABELS = {"none": "unfiltered", "mean": "mean", "cvar": "CVaR", "dr_cvar": "DR-CVaR"}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    _pyplot().close(fig)
    return path


def _arena(ax, bounds=((-5.0, -5.0), (5.0, 5.0))) -> None:
    (x0, y0), (x1, y1) = bounds
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")


def plot_trajectories(
    trajectories: Mapping[str, Trajectory], path: str | Path, *, title: str = ""
) -> Path:
    """Ego paths of one seed under each risk setting, obstacles in black (Fig. 4, left)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 6))
    _arena(ax)
    drawn_obstacles = False
    for risk in sorted(trajectories, key=lambda r: RISK_ORDER.get(r, 9)):
        traj = trajectories[risk]
        color = RISK_COLORS.get(risk, "k")
        ax.plot(traj.ego[:, 0], traj.ego[:, 1], "-o", ms=2, color=color,
                label=RISK_LABELS.get(risk, risk))
        if not drawn_obstacles and traj.obstacles.size:
            for i in range(traj.obstacles.shape[1]):
                ax.plot(traj.obstacles[:, i, 0], traj.obstacles[:, i, 1], "-", color="k", lw=1)
                ax.add_patch(plt.Circle(traj.obstacles[-1, i], traj.obstacle_radii[i],
                                        color="k", alpha=0.3))
            ax.plot(*traj.goal, "k*", ms=12, label="goal")
            drawn_obstacles = True
    ax.legend(loc="best", fontsize=8)
    ax.set_title(title)
    return _save(fig, path)


def plot_distance_boxplots(records: Sequence[EpisodeRecord], path: str | Path) -> Path:
    """Box plots of the minimum distance to collision per risk, one panel per scenario.

    The paper's Fig. 4, right column.
    """
    plt = _pyplot()
    scenarios = sorted({r.scenario for r in records})
    fig, axes = plt.subplots(1, len(scenarios), figsize=(3.2 * len(scenarios), 3.6),
                             squeeze=False, sharey=True)
    for ax, scenario in zip(axes[0], scenarios, strict=True):
        risks = sorted({r.risk for r in records if r.scenario == scenario},
                       key=lambda r: RISK_ORDER.get(r, 9))
        data = [[r.min_distance for r in records
                 if r.scenario == scenario and r.risk == risk and not r.error
                 and np.isfinite(r.min_distance)] for risk in risks]
        boxes = ax.boxplot(data, patch_artist=True, whis=(0, 100))
        for patch, risk in zip(boxes["boxes"], risks, strict=True):
            patch.set_facecolor(RISK_COLORS.get(risk, "w"))
            patch.set_alpha(0.6)
        ax.set_xticks(range(1, len(risks) + 1), [RISK_LABELS.get(r, r) for r in risks],
                      rotation=30)
        ax.axhline(0.0, color="k", lw=1, ls="--")
        ax.set_title(short_name(scenario))
        ax.grid(alpha=0.3, axis="y")
    axes[0][0].set_ylabel("min distance to collision (m)")
    return _save(fig, path)


def plot_collision_rates(rows: Sequence[SummaryRow], path: str | Path) -> Path:
    """Collision rate per scenario and risk with Wilson 95 % intervals."""
    plt = _pyplot()
    scenarios = sorted({r.scenario for r in rows})
    risks = sorted({r.risk for r in rows}, key=lambda r: RISK_ORDER.get(r, 9))
    width = 0.8 / max(1, len(risks))
    fig, ax = plt.subplots(figsize=(1.8 * len(scenarios) + 2, 3.6))
    for j, risk in enumerate(risks):
        xs, rates, low, high = [], [], [], []
        for i, scenario in enumerate(scenarios):
            match = [r for r in rows if r.scenario == scenario and r.risk == risk]
            if match:
                row = match[0]
                xs.append(i + (j - (len(risks) - 1) / 2) * width)
                rates.append(row.collision_rate)
                # Clipped at 0: the interval's ends carry rounding error at rates 0 and 1.
                low.append(max(0.0, row.collision_rate - row.collision_low))
                high.append(max(0.0, row.collision_high - row.collision_rate))
        ax.bar(xs, rates, width, yerr=[low, high], capsize=3, color=RISK_COLORS.get(risk),
               label=RISK_LABELS.get(risk, risk))
    ax.set_xticks(range(len(scenarios)), [short_name(s) for s in scenarios])
    ax.set_ylabel("collision rate")
    ax.set_ylim(0, 1)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    return _save(fig, path)


def plot_safe_polytopes(
    trajectory: Trajectory, path: str | Path, *, every: int = 3,
    bounds=((-5.0, -5.0), (5.0, 5.0)), title: str = "",
) -> Path:
    """Ego and obstacle paths with the safe polytope of every ``every``-th step (Fig. 5).

    The polytope at step t is the intersection of the first-step halfspaces of all
    obstacles computed at t, clipped to the arena.
    """
    from filters.plotting import safe_polygon

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 5))
    _arena(ax, bounds)
    low, high = np.asarray(bounds[0]), np.asarray(bounds[1])
    for t in range(0, len(trajectory.halfspaces), every):
        normals, offsets = trajectory.halfspaces[t]
        polygon = safe_polygon(normals[:, 0], offsets[:, 0], (low, high))
        if len(polygon) >= 3:
            ax.fill(polygon[:, 0], polygon[:, 1], color="tab:green", alpha=0.08)
            ax.plot(*np.vstack([polygon, polygon[:1]]).T, color="tab:green", lw=0.6, alpha=0.6)
    ego = trajectory.ego
    ax.plot(ego[:, 0], ego[:, 1], "-o", color="tab:blue", ms=3, label="ego")
    for t in range(0, len(ego), every):
        ax.add_patch(plt.Circle(ego[t], trajectory.ego_radius, color="tab:blue", alpha=0.15))
    colors = plt.cm.autumn(np.linspace(0, 0.8, max(1, trajectory.obstacles.shape[1])))
    for i in range(trajectory.obstacles.shape[1]):
        path_i = trajectory.obstacles[:, i]
        ax.plot(path_i[:, 0], path_i[:, 1], "-", color=colors[i], label=f"obstacle {i + 1}")
        for t in range(0, len(path_i), every):
            ax.add_patch(plt.Circle(path_i[t], trajectory.obstacle_radii[i], color=colors[i],
                                    alpha=0.15))
    fallback = [t + 1 for t, s in enumerate(trajectory.statuses) if s in ("shifted", "brake")]
    if fallback:
        ax.plot(ego[fallback, 0], ego[fallback, 1], "kx", ms=8, label="fallback step")
    ax.plot(*trajectory.goal, "k*", ms=12, label="goal")
    ax.legend(fontsize=7, loc="best")
    ax.set_title(title)
    return _save(fig, path)


def save_gif(frames: Sequence[np.ndarray], path: str | Path, fps: int = 5) -> Path:
    """Write RGB frames (H, W, 3) uint8 as an animated GIF (Pillow, a matplotlib dependency)."""
    from PIL import Image

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    images = [Image.fromarray(np.asarray(f)) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps),
                   loop=0)
    return path


def plot_sweep(points: Sequence[dict], path: str | Path) -> Path:
    """Collision rate against mean intervention for an epsilon/delta sweep.

    ``points`` are dicts with ``epsilon``, ``delta``, ``collision_rate``,
    ``mean_intervention`` (and optionally ``goal_rate``).
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4))
    deltas = sorted({p["delta"] for p in points})
    for delta in deltas:
        pts = sorted((p for p in points if p["delta"] == delta), key=lambda p: p["epsilon"])
        ax.plot([p["mean_intervention"] for p in pts], [p["collision_rate"] for p in pts],
                "-o", label=f"δ = {delta:g}")
        for p in pts:
            ax.annotate(f"ε={p['epsilon']:g}", (p["mean_intervention"], p["collision_rate"]),
                        fontsize=7, textcoords="offset points", xytext=(3, 3))
    ax.set_xlabel("mean intervention ||u_safe - u_ref|| (m/s²)")
    ax.set_ylabel("collision rate")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)

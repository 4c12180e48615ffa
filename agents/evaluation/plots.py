"""Figures of an evaluation: the paper's Fig. 2-5 and a few more, saved as PNG/GIF.

All functions take plain data (records, trajectories, summary rows), draw with
matplotlib's Agg backend, save to ``path`` and return it. matplotlib is imported
inside the functions only, never when :mod:`agents.evaluation.plots` is imported.

Trajectories are read duck-typed: ``ego`` (steps+1, 2), ``obstacles``
(steps+1, n, 2), ``obstacle_radii`` (n,), ``ego_radius`` and ``goal``
(:class:`agents.evaluation.trajectory.Trajectory` has them). A trajectory that also carries
``ego_velocities`` (steps+1, 2), ``inputs`` (steps, 2) and ``dt`` (as
:class:`agents.experiments.encounters.EncounterRecord` does) gets its collisions located
in continuous time exactly (:func:`agents.evaluation.contacts.step_clearance`); without
them the ego is taken on the chord between its samples, which is off the true arc by at most
``dt² a_max / 8`` (0.05 m at 10 m/s², dt = 0.2 s) and is labelled so.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation.contacts import find_collisions
from agents.evaluation.records import EpisodeRecord
from agents.evaluation.summary import RISK_ORDER, SummaryRow, short_name
from agents.evaluation.trajectory import Trajectory
from filters.errors import InvalidArrayError, InvalidParameterError
from filters.wrapper import FALLBACK_STATUSES
from safe_nav_env.constants import DT

RISK_COLORS = {"none": "tab:gray", "mean": "tab:red", "cvar": "tab:blue", "dr_cvar": "tab:green"}
"""The paper's colours: red mean, blue CVaR, green DR-CVaR (grey: unfiltered)."""
RISK_LABELS = {"none": "unfiltered", "mean": "mean", "cvar": "CVaR", "dr_cvar": "DR-CVaR"}

GIF_LEGEND = (
    ("ego", (31, 119, 180)),
    ("obstacles", (0, 0, 0)),
    ("prediction samples", (150, 150, 150)),
    ("safe halfspace (step 1)", (44, 160, 44)),
    ("goal", (44, 160, 44)),
)
"""Legend of the environment's frames (colours of :mod:`safe_nav_env.rendering`)."""


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (imported on first use)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: str | Path) -> Path:
    """Save ``fig`` to ``path`` (folders made; 120 dpi, tight box), close it, return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    pyplot().close(fig)
    return path


def arena_axes(ax, bounds=((-5.0, -5.0), (5.0, 5.0))) -> None:
    """Equal-aspect axes over ``bounds`` ``((x_min, y_min), (x_max, y_max))`` in m, a grid."""
    (x0, y0), (x1, y1) = bounds
    ax.set(xlim=(x0, x1), ylim=(y0, y1), aspect="equal", xlabel="x (m)", ylabel="y (m)")
    ax.grid(alpha=0.3)


def _path(ax, path: Any, radius: float, instants: Any, color: Any, label: str | None,
          **line: Any) -> None:
    """A path (samples, 2) in m as a line, with discs of ``radius`` (m) at ``instants``."""
    path = np.asarray(path)
    ax.plot(path[:, 0], path[:, 1], color=color, label=label, **line)
    for t in instants:
        ax.add_patch(pyplot().Circle(path[t], radius, facecolor=color, edgecolor=color,
                                     alpha=0.12, lw=0.6))


def _obstacles_and_goal(ax, traj: Any, instants: Any, colors: Any, label: Any) -> None:
    """Every obstacle's realised path and discs (colour ``colors[i]``, ``label(i)``), the goal."""
    for i in range(traj.obstacles.shape[1]):
        _path(ax, traj.obstacles[:, i], traj.obstacle_radii[i], instants, colors[i], label(i),
              lw=1)
    ax.plot(*traj.goal, "k*", ms=12, label="goal")


# ---------------------------------------------------------------------------- figures
def plot_trajectories(trajectories: Mapping[str, Any], path: str | Path, *, title: str = "",
                      every: int = 5) -> Path:
    """Ego paths of one seed under each risk setting, obstacles in black (Fig. 4, left).

    The view is the box around the paths, the discs and the goal, 0.5 m wider. The
    discs (ego in the risk's colour, obstacles in black) are drawn to scale at every
    ``every``-th sample and at the end.
    Each first contact with an obstacle
    (:func:`agents.evaluation.contacts.find_collisions`) is marked with an ``x`` at the
    ego's centre, both discs drawn at that instant with a thick outline,
    and the contact time.
    """
    if every < 1:
        raise InvalidParameterError(f"every must be >= 1, got {every!r}")
    plt = pyplot()
    bounds = _fit_bounds(trajectories.values())
    (x0, y0), (x1, y1) = bounds
    width = 7.0
    fig, ax = plt.subplots(figsize=(width, max(3.0, min(8.0, width * (y1 - y0) / (x1 - x0)))))
    arena_axes(ax, bounds)
    drawn_obstacles = False
    collision_label = None
    for risk in sorted(trajectories, key=lambda r: RISK_ORDER.get(r, 9)):
        traj = trajectories[risk]
        color = RISK_COLORS.get(risk, "k")
        ego = np.asarray(traj.ego)
        instants = sorted(set(range(0, len(ego), every)) | {len(ego) - 1})
        _path(ax, ego, traj.ego_radius, instants, color, f"ego, {RISK_LABELS.get(risk, risk)}",
              marker="o", ms=2)
        if not drawn_obstacles and traj.obstacles.size:
            _obstacles_and_goal(ax, traj, instants, ["k"] * traj.obstacles.shape[1],
                                lambda i: None if i else "obstacles (realised paths)")
            drawn_obstacles = True
        for mark in find_collisions(traj):
            collision_label = ("collision (continuous time)" if mark.exact
                               else "collision (ego on chord, ±dt²a/8)")
            ax.add_patch(plt.Circle(mark.ego_position, traj.ego_radius, fill=False,
                                    edgecolor=color, lw=2.0, gid="collision-ego-disc"))
            ax.add_patch(plt.Circle(mark.obstacle_position, traj.obstacle_radii[mark.obstacle],
                                    fill=False, edgecolor="k", lw=2.0,
                                    gid="collision-obstacle-disc"))
            ax.plot(*mark.ego_position, "x", color="crimson", ms=10, mew=2.5,
                    gid="collision-marker")
            ax.annotate(f"t = {mark.time:.2f} s", mark.ego_position, fontsize=7,
                        color=color, textcoords="offset points", xytext=(8, -12),
                        bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="none", alpha=0.8))
    if collision_label is not None:
        ax.plot([], [], "x", color="crimson", ms=8, mew=2, label=collision_label)
    dt = next((float(t.dt) for t in trajectories.values() if getattr(t, "dt", 0.0)), 0.0)
    period = f"every {every} steps" + (f" ({every * dt:g} s)" if dt > 0.0 else "")
    ax.plot([], [], "o", color="0.5", alpha=0.3, ms=10, label=f"discs to scale, {period}")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    ax.set_title(title or "Ego paths with and without the safety filter")
    return save_figure(fig, path)


def _fit_bounds(trajectories: Any, margin: float = 0.5) -> tuple[tuple[float, float], ...]:
    """The box around every path, disc and goal, ``margin`` (m) wider; ±5 m if none."""
    trajectories = list(trajectories)
    if not trajectories:
        return ((-5.0, -5.0), (5.0, 5.0))
    cloud = np.concatenate([np.asarray(getattr(traj, key), float).reshape(-1, 2)
                            for traj in trajectories for key in ("ego", "obstacles", "goal")])
    cloud = cloud[np.all(np.isfinite(cloud), axis=1)]
    pad = margin + max(max([float(t.ego_radius), *np.asarray(t.obstacle_radii, float)])
                       for t in trajectories)
    low, high = cloud.min(axis=0) - pad, cloud.max(axis=0) + pad
    return (tuple(low.tolist()), tuple(high.tolist()))


def plot_distance_boxplots(records: Sequence[EpisodeRecord], path: str | Path) -> Path:
    """Box plots of the minimum distance to collision per risk, one panel per scenario.

    The paper's Fig. 4, right column.
    """
    scenarios = sorted({r.scenario for r in records})
    fig, axes = pyplot().subplots(1, len(scenarios), figsize=(3.2 * len(scenarios), 3.6),
                                  squeeze=False, sharey=True)
    most = 0
    for ax, scenario in zip(axes[0], scenarios, strict=True):
        risks = sorted({r.risk for r in records if r.scenario == scenario},
                       key=lambda r: RISK_ORDER.get(r, 9))
        for j, risk in enumerate(risks):
            values = [r.min_distance for r in records if r.scenario == scenario
                      and r.risk == risk and not r.error and np.isfinite(r.min_distance)]
            _risk_boxes(ax, [values], risk, positions=[j + 1])
            most = max(most, len(values))
        ax.set_xticks(range(1, len(risks) + 1), [RISK_LABELS.get(r, r) for r in risks],
                      rotation=30)
        ax.set_title(short_name(scenario))
    axes[0][0].set_ylabel("smallest clearance of the episode (m)\n(sampled; < 0: collision)")
    fig.suptitle("Smallest distance to collision per episode, by filter risk "
                 f"(up to {most} episodes per box; whiskers: min and max)", fontsize=10)
    return save_figure(fig, path)


def _risk_boxes(ax, data: Any, risk: str, **where: Any) -> None:
    """Box plots of ``data`` in the risk's colour (whiskers: min and max), a dashed line at
    0 m (collision) and a horizontal grid."""
    boxes = ax.boxplot(data, patch_artist=True, whis=(0, 100), manage_ticks=False, **where)
    pyplot().setp(boxes["boxes"], facecolor=RISK_COLORS.get(risk, "w"), alpha=0.6)
    ax.axhline(0.0, color="k", lw=1, ls="--")
    ax.grid(alpha=0.3, axis="y")


def plot_window_boxplots(distances: Mapping[str, Mapping[str, np.ndarray]],
                         windows: Mapping[str, tuple[int, int]], path: str | Path, *,
                         dt: float = DT, title: str = "") -> Path:
    """Per-step box plots of the sampled distance to collision in each scenario's window.

    The paper's Fig. 4, bottom row: for every sample ``k`` of the window, one box
    per risk over the episodes (and the obstacles) of the distance at ``k``.

    Parameters
    ----------
    distances
        ``distances[scenario][risk]``: array (episodes, samples) of the minimum over
        the obstacles of the sampled distance to collision at each sample, in m.
    windows
        ``windows[scenario] = (first, last)``: sample indices, both included.
    """
    fig, axes = pyplot().subplots(1, len(distances), figsize=(3.6 * len(distances), 3.6),
                                  squeeze=False)
    for ax, scenario in zip(axes[0], distances, strict=True):
        first, last = windows[scenario]
        risks = sorted(distances[scenario], key=lambda r: RISK_ORDER.get(r, 9))
        width = 0.8 / max(1, len(risks))
        steps = np.arange(first, last + 1)
        for j, risk in enumerate(risks):
            values = np.asarray(distances[scenario][risk], dtype=float)
            data = [values[np.isfinite(values[:, k]), k] if k < values.shape[1] else []
                    for k in steps]
            positions = np.arange(len(steps)) + (j - (len(risks) - 1) / 2) * width
            _risk_boxes(ax, data, risk, positions=positions, widths=width * 0.9)
            ax.plot([], [], "s", color=RISK_COLORS.get(risk, "w"),
                    label=RISK_LABELS.get(risk, risk))
        ax.set_xticks(range(len(steps)), [f"{k}\n{k * dt:.1f} s" for k in steps])
        ax.set(title=f"{short_name(scenario)}: samples {first}-{last}", xlabel="sample (time)")
    axes[0][0].set_ylabel("sampled distance to collision (m)")
    axes[0][-1].legend(fontsize=7)
    if title:
        fig.suptitle(title, y=1.04)
    return save_figure(fig, path)


def plot_collision_rates(
    rows: Sequence[SummaryRow], path: str | Path, *,
    ylabel: str = "collision rate (continuous time)\nshare of episodes",
    title: str = "Collision rate per scenario, unfiltered and by filter risk "
                 "(bars: Wilson 95 % intervals; labels: collisions / episodes)",
) -> Path:
    """Collision rate per scenario and risk with Wilson 95 % intervals.

    Every bar is outlined and labelled with its count, e.g. ``"3/300"``; a 0 % bar
    is drawn as a thick line at 0 (gid ``"zero-bar"``) so it cannot be mistaken for
    a missing one.
    """
    scenarios = sorted({r.scenario for r in rows})
    risks = sorted({r.risk for r in rows}, key=lambda r: RISK_ORDER.get(r, 9))
    width = 0.8 / max(1, len(risks))
    fig, ax = pyplot().subplots(figsize=(2.2 * len(scenarios) + 2, 3.8))
    table = {(r.scenario, r.risk): r for r in reversed(rows)}  # the first row of each
    for j, risk in enumerate(risks):
        color, label = RISK_COLORS.get(risk, "k"), RISK_LABELS.get(risk, risk)
        for i, scenario in enumerate(scenarios):
            row = table.get((scenario, risk))
            if row is None:
                continue
            x, n = i + (j - (len(risks) - 1) / 2) * width, row.episodes - row.failed
            rate = row.collision_rate if n else 0.0
            # Clipped at 0: the interval's ends carry rounding error at rates 0 and 1.
            low = max(0.0, rate - row.collision_low) if n else 0.0
            top = max(0.0, row.collision_high - rate) if n else 0.0
            text = f"{int(round(rate * n))}/{n}"
            ax.bar(x, rate, width, yerr=[[low], [top]], capsize=3, color=color, alpha=0.8,
                   edgecolor=color, linewidth=1.2, label=label)
            label = None  # one legend entry per risk
            if rate == 0.0:
                ax.plot([x - 0.45 * width, x + 0.45 * width], [0.0, 0.0], color=color, lw=4,
                        solid_capstyle="butt", clip_on=False, zorder=5, gid="zero-bar",
                        label=f"_zero {risk} {text}")
            ax.text(x, rate + top + 0.02, text, ha="center", va="bottom", fontsize=6,
                    rotation=90, gid="bar-count")
    ax.set_xticks(range(len(scenarios)), [short_name(s) for s in scenarios])
    ax.set(ylabel=ylabel, ylim=(0, 1.18), yticks=np.linspace(0, 1, 6))
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=len(risks),
              frameon=False)
    ax.grid(alpha=0.3, axis="y")
    ax.set_title(title, fontsize=10)
    return save_figure(fig, path)


def plot_safe_polytopes(trajectory: Trajectory | Any, path: str | Path, *, every: int = 3,
                        bounds=((-5.0, -5.0), (5.0, 5.0)), title: str = "") -> Path:
    """Ego and obstacle paths with the safe polytope of every ``every``-th step (Fig. 5).

    The polytope at step t is the intersection of the first-step halfspaces of all
    obstacles computed at t, clipped to the arena.
    """
    from matplotlib.colors import to_rgba

    from filters.plotting import safe_polygon

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8.5, 5))
    arena_axes(ax, bounds)
    label = f"safe polytope of the next position, every {every} steps"
    for t in range(0, len(trajectory.halfspaces), every):
        normals, offsets = trajectory.halfspaces[t]
        polygon = safe_polygon(normals[:, 0], offsets[:, 0], bounds)
        if len(polygon) >= 3:
            ax.fill(*polygon.T, facecolor=to_rgba("tab:green", 0.08),
                    edgecolor=to_rgba("tab:green", 0.6), lw=0.6, label=label)
            label = None  # one legend entry
    ego = np.asarray(trajectory.ego)
    instants = range(0, len(ego), every)
    _path(ax, ego, trajectory.ego_radius, instants, "tab:blue", "ego path (disc to scale)",
          marker="o", ms=3)
    colors = plt.cm.autumn(np.linspace(0, 0.8, max(1, trajectory.obstacles.shape[1])))
    _obstacles_and_goal(ax, trajectory, instants, colors,
                        lambda i: f"obstacle {i + 1} (realised path)")
    fallback = [t + 1 for t, s in enumerate(trajectory.statuses) if s in FALLBACK_STATUSES]
    if fallback:
        ax.plot(ego[fallback, 0], ego[fallback, 1], "kx", ms=8, label="fallback step")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title(title or "Safe polytopes along a filtered episode")
    return save_figure(fig, path)


def featured_run(scenarios: Sequence[str], risks: Sequence[str]) -> tuple[str, str]:
    """The ``(scenario, risk)`` whose rendered run gives the safe-polytope figure and the
    animation: MultiObstacle and DR-CVaR when evaluated, else the first scenario and the
    last risk (the names as given: short names or gym ids)."""
    multi = [s for s in scenarios if short_name(s) == "MultiObstacle"]
    return (multi[0] if multi else scenarios[0], "dr_cvar" if "dr_cvar" in risks else risks[-1])


def polytope_figures(trajectory: Any, folder: Path, *, title: str, label: str
                     ) -> dict[str, Path]:
    """``safe_polytopes.png`` of a rendered run and, when it has frames, ``episode.gif``."""
    files = {"safe_polytopes": plot_safe_polytopes(trajectory, folder / "safe_polytopes.png",
                                                   title=title)}
    if trajectory.frames:
        files["animation"] = save_gif(trajectory.frames, folder / "episode.gif", label=label)
    return files


def save_gif(frames: Sequence[np.ndarray], path: str | Path, fps: int = 5, *, label: str = "",
             legend: Sequence[tuple[str, tuple[int, int, int]]] = GIF_LEGEND) -> Path:
    """Write RGB frames (H, W, 3) uint8 as an animated GIF (Pillow, a matplotlib dependency).

    A banner is added under every frame with ``label`` (e.g. the risk setting:
    ``"DR-CVaR (alpha 0.2, eps 0.05 m)"``) and the colour legend ``legend``
    (``(text, (r, g, b))`` pairs; by default the environment's colours).

    Raises
    ------
    InvalidParameterError
        If there are no frames or ``fps < 1``.
    InvalidArrayError
        If the frames are not (H, W, 3) arrays of one size.
    """
    from PIL import Image, ImageDraw, ImageFont

    if len(frames) == 0:
        raise InvalidParameterError("save_gif needs at least one frame, got none")
    if fps < 1:
        raise InvalidParameterError(f"fps must be >= 1, got {fps!r}")
    arrays = [np.asarray(f) for f in frames]
    shape = arrays[0].shape
    if len(shape) != 3 or shape[2] != 3 or any(a.shape != shape for a in arrays):
        raise InvalidArrayError(f"frames must all have shape (H, W, 3), got {shape} and "
                                f"{sorted({a.shape for a in arrays})}")
    width = shape[1]
    size = max(10, width // 45)
    try:
        font = ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: the fixed bitmap font
        font = ImageFont.load_default()
    line = int(1.4 * max(size if hasattr(font, "size") else 0, font.getbbox("Ag")[3]))
    # The white banner: the label, then the legend entries (wrapped); cropped to its rows.
    swatch = line // 2
    banner = Image.new("RGB", (width, line * (len(legend) + 2) + 8), "white")
    draw = ImageDraw.Draw(banner)
    x, y = 8, 4
    if label:
        draw.text((8, y), label, fill=(0, 0, 0), font=font)
        y += line
    for text, color in legend:
        entry = swatch + 6 + int(font.getlength(text)) + 16
        if x + entry > width and x > 8:  # the next row
            x, y = 8, y + line
        draw.ellipse((x, y + 2, x + swatch, y + 2 + swatch), fill=tuple(color))
        draw.text((x + swatch + 6, y), text, fill=(0, 0, 0), font=font)
        x += entry
    strip = np.asarray(banner.crop((0, 0, width, y + line + 4)))  # (rows, W, 3) uint8
    images = [Image.fromarray(np.concatenate([a.astype(np.uint8), strip])) for a in arrays]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps),
                   loop=0)
    return path


def plot_sweep(points: Sequence[dict], path: str | Path) -> Path:
    """Collision rate against mean intervention for an epsilon/delta sweep.

    ``points`` are dicts with ``epsilon``, ``delta``, ``collision_rate``,
    ``mean_intervention`` (and optionally ``goal_rate``).
    """
    fig, ax = pyplot().subplots(figsize=(6.5, 4.5))
    for delta in sorted({p["delta"] for p in points}):
        pts = sorted((p for p in points if p["delta"] == delta), key=lambda p: p["epsilon"])
        ax.plot([p["mean_intervention"] for p in pts], [p["collision_rate"] for p in pts],
                "-o", label=f"δ = {delta:g} m")
        for p in pts:
            ax.annotate(f"ε={p['epsilon']:g} m", (p["mean_intervention"], p["collision_rate"]),
                        fontsize=7, textcoords="offset points", xytext=(3, 3))
    ax.set(xlabel="mean intervention ‖u_safe − u_ref‖ per step (m/s²)",
           ylabel="collision rate (continuous time, share of episodes)")
    ax.set_title("Safety against intervention: sweep of the Wasserstein radius ε (m)",
                 fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, title="risk bound δ (m)", title_fontsize=8)
    return save_figure(fig, path)

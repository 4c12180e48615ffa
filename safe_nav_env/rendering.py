"""Matplotlib drawing of the environment (imported only when rendering).

One figure is created per environment and reused between frames: the static
artists (arena, goal) are drawn once per scenario layout, the moving ones (discs,
trails, prediction samples) are updated in place, and whatever the render hooks
drew in the previous frame is removed before they are called again.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Rectangle

if TYPE_CHECKING:
    from safe_nav_env.env import SafeNavEnv

EGO_COLOR = "tab:blue"
OBSTACLE_COLORS = ("black", "tab:red", "tab:purple", "tab:brown", "tab:olive", "tab:cyan")
"""Obstacle ``i`` is drawn in ``OBSTACLE_COLORS[i % len(OBSTACLE_COLORS)]``."""


class Renderer:
    """Draws a :class:`~safe_nav_env.SafeNavEnv` into a reused matplotlib figure.

    Parameters
    ----------
    human
        Show the figure in a window (pyplot) instead of drawing off-screen (Agg).
    fps
        Frames per second of the window in human mode.
    size
        Figure size in inches; frames are ``size * dpi`` pixels (600 x 600 by default).
    dpi
        Resolution in dots per inch.
    """

    def __init__(
        self, *, human: bool = False, fps: float = 5.0, size: float = 6.0, dpi: int = 100
    ) -> None:
        self.human = human
        self.fps = fps
        if human:
            import matplotlib.pyplot as plt

            self._plt = plt
            self.fig = plt.figure(figsize=(size, size), dpi=dpi)
        else:
            self._plt = None
            self.fig = Figure(figsize=(size, size), dpi=dpi)
            FigureCanvasAgg(self.fig)
        self.ax = self.fig.add_axes((0.09, 0.07, 0.88, 0.88))
        self._layout: tuple | None = None
        self._hook_artists: list[Any] = []
        self._shown = False

    # -------------------------------------------------------------- drawing

    def _setup(self, env: SafeNavEnv, layout: tuple) -> None:
        """Clear the axes and create the artists for a new scenario layout."""
        ax = self.ax
        ax.clear()
        self._hook_artists = []
        low, high = env.position_bounds
        margin = 0.5
        self._limits = ((low[0] - margin, high[0] + margin), (low[1] - margin, high[1] + margin))
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.add_patch(Rectangle(tuple(low), *(high - low), fill=False, edgecolor="0.6", lw=1.5))
        goal = env.goal
        ax.add_patch(Circle(tuple(goal), env.goal_tolerance, fill=False, ls="--",
                            edgecolor="tab:green"))
        ax.plot(*goal, marker="*", ms=14, color="tab:green", ls="none", zorder=5)

        n = env.n_obstacles
        colors = [OBSTACLE_COLORS[i % len(OBSTACLE_COLORS)] for i in range(n)]
        rgba = matplotlib.colors.to_rgba_array(colors) if n else np.zeros((0, 4))
        self._sample_colors = rgba
        self._samples = ax.scatter(np.zeros(0), np.zeros(0), s=2, linewidths=0, zorder=2)
        self._ego_trail = ax.plot([], [], color=EGO_COLOR, lw=1.5, zorder=3)[0]
        self._ego = ax.add_patch(Circle((0, 0), env.ego_radius, color=EGO_COLOR, alpha=0.8,
                                        zorder=4))
        self._obstacle_trails = [ax.plot([], [], color=c, lw=1, alpha=0.7, zorder=3)[0]
                                 for c in colors]
        self._obstacles = [
            ax.add_patch(Circle((0, 0), r, color=c, alpha=0.6, zorder=4))
            for r, c in zip(env.obstacle_radii, colors, strict=True)
        ]
        self._text = ax.text(0.02, 0.98, "", transform=ax.transAxes, va="top", fontsize=9)
        self._layout = layout

    def draw(
        self, env: SafeNavEnv, trail: list[tuple[np.ndarray, np.ndarray]]
    ) -> np.ndarray | None:
        """Draw the current state of ``env``.

        Parameters
        ----------
        env
            The environment (its unwrapped instance).
        trail
            ``(ego position, obstacle positions)`` for each step of the episode so far.

        Returns
        -------
        numpy.ndarray or None
            The frame, uint8 of shape ``(H, W, 3)``, off-screen; ``None`` in human mode.
        """
        layout = (
            tuple(env.goal), tuple(map(tuple, env.position_bounds)), env.ego_radius,
            tuple(env.obstacle_radii), env.goal_tolerance,
        )
        if layout != self._layout:
            self._setup(env, layout)
        for artist in self._hook_artists:
            artist.remove()
        ax = self.ax

        p = env.ego_state[:2]
        self._ego.set_center(tuple(p))
        if trail:
            ego_path = np.array([t[0] for t in trail])
            self._ego_trail.set_data(ego_path[:, 0], ego_path[:, 1])
            if env.n_obstacles:
                paths = np.array([t[1] for t in trail])  # (steps, n, 2)
                for i, line in enumerate(self._obstacle_trails):
                    line.set_data(paths[:, i, 0], paths[:, i, 1])
        for circle, position in zip(self._obstacles, env.obstacle_positions, strict=True):
            circle.set_center(tuple(position))

        predictions = env.predictions  # (n, S, T, 2)
        n, s, t = predictions.shape[:3]
        self._samples.set_offsets(predictions.reshape(-1, 2))
        colors = np.repeat(self._sample_colors, s * t, axis=0)
        colors[:, 3] = 0.15
        self._samples.set_facecolors(colors)
        self._text.set_text(f"t = {env.time:.1f} s   {env.scenario.name}")
        ax.set_xlim(*self._limits[0])
        ax.set_ylim(*self._limits[1])

        before = set(ax.get_children())
        for hook in env.render_hooks:
            hook(ax)
        self._hook_artists = [a for a in ax.get_children() if a not in before]

        if self.human:
            plt = self._plt
            if not self._shown:
                plt.show(block=False)
                self._shown = True
            self.fig.canvas.draw_idle()
            plt.pause(1.0 / self.fps)
            return None
        self.fig.canvas.draw()
        return np.asarray(self.fig.canvas.buffer_rgba())[..., :3].copy()

    def close(self) -> None:
        """Release the figure."""
        if self._plt is not None:
            self._plt.close(self.fig)
        self._layout = None

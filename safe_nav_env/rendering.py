"""Matplotlib drawing of the environment (imported only when rendering), blitted.

A frame costs a few ms (600 x 600 px), not the 30-60 ms of a full matplotlib
redraw, because nothing static is drawn twice:

* once per arena, a full draw of the static scene (axes, ticks, labels, arena) is
  cached as a background (``copy_from_bbox``), and once per layout the goal is
  drawn on it and cached too;
* per frame: the background is restored; the prediction samples (up to thousands
  of points) are composited straight into the Agg buffer with numpy (2 x 2 px dots
  of opacity :data:`SAMPLE_ALPHA`; ``k`` dots of one colour on a pixel give exactly
  what ``k`` alpha-blended scatter markers give, :math:`c + (d - c)(1 - a)^k`);
  the moving artists (the ego's disc and trail, the obstacles' discs and trails as
  two collections) are drawn with ``draw_artist``; then
  the render hooks are called with the axes and whatever artists they add
  (e.g. a filter's halfspace boundary) are drawn the same way and removed again,
  so hooks keep the matplotlib API (``hook(ax)``) they always had;
* the caption (time, scenario) sits above the axes and its pixels are cached per
  string, since text is the slowest thing matplotlib draws (2-4 ms).

``human`` mode shows the same frames in a pyplot window (``imshow``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import EllipseCollection, LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Rectangle

if TYPE_CHECKING:
    from safe_nav_env.env import SafeNavEnv

EGO_COLOR = "tab:blue"
OBSTACLE_COLORS = ("black", "tab:red", "tab:purple", "tab:brown", "tab:olive", "tab:cyan")
"""Obstacle ``i`` is drawn in ``OBSTACLE_COLORS[i % len(OBSTACLE_COLORS)]``."""

SAMPLE_ALPHA = 0.15
"""Opacity of one prediction-sample dot."""

CAPTION_FONT = {"family": "DejaVu Sans Mono", "size": 9}
"""Font of the caption (monospace: it is composed from cached glyph cells)."""


class Renderer:
    """Draws a :class:`~safe_nav_env.SafeNavEnv` into a reused, blitted matplotlib figure.

    Parameters
    ----------
    human
        Also show the frames in a window (pyplot) and return ``None`` from :meth:`draw`.
    fps
        Frames per second of the window in human mode.
    """

    def __init__(self, *, human: bool = False, fps: float = 5.0) -> None:
        self.human = human
        self.fps = fps
        self.fig = Figure(figsize=(6.0, 6.0), dpi=100)  # 600 x 600 px frames
        self.canvas = FigureCanvasAgg(self.fig)
        self.ax = self.fig.add_axes((0.09, 0.07, 0.88, 0.88))
        self._layout: tuple | None = None  # (arena, goal, radii, goal tolerance) drawn
        self._moving: list = []
        self._window = self._image = None  # the pyplot window of human mode

    # -------------------------------------------------------------- set-up

    def _setup(self, env: SafeNavEnv, layout: tuple) -> None:
        """Cache the static scene of ``layout`` and create the moving artists.

        A new arena is drawn in full (axes, ticks, labels, arena box) and cached as
        ``_background``; the goal is drawn on it and cached as the layout's background.
        The obstacles are one ``EllipseCollection`` and their trails one
        ``LineCollection``: a few artists to draw per frame, whatever the obstacle count.
        """
        ax = self.ax
        for artist in self._moving:
            artist.remove()
        if self._layout is None or self._layout[0] != layout[0]:  # a new arena: full draw
            ax.clear()
            low, high = env.position_bounds
            self._limits = ((low[0] - 0.5, high[0] + 0.5), (low[1] - 0.5, high[1] + 0.5))
            ax.set(xlim=self._limits[0], ylim=self._limits[1], aspect="equal", xlabel="x [m]",
                   ylabel="y [m]")
            ax.add_patch(Rectangle(tuple(low), *(high - low), fill=False, edgecolor="0.6",
                                   lw=1.5))
            self.canvas.draw()
            self._background = self.canvas.copy_from_bbox(self.fig.bbox)
            self._transform = ax.transData.frozen()
            self._affine = self._transform.get_matrix()  # data -> display pixels (affine)
            self._height = int(round(self.fig.bbox.height))
            self._width = int(round(self.fig.bbox.width))
            x0, y0, x1, y1 = ax.bbox.extents  # display pixels, origin bottom left
            # Buffer rows/columns inside the axes (samples are clipped to them).
            self._clip = (int(np.ceil(x0)), int(np.floor(x1)),
                          int(np.ceil(self._height - y1)), int(np.floor(self._height - y0)))
            self._caption = _Caption(self, top_row=int(np.floor(self._height - y1)) - 1,
                                     left=int(round(x0)))
        moving = dict(animated=True)  # never part of the arena's cached background
        goal_ring = ax.add_patch(Circle(tuple(env.goal), env.goal_tolerance, fill=False, ls="--",
                                        edgecolor="tab:green", **moving))
        goal_star = ax.plot(*env.goal, marker="*", ms=14, color="tab:green", ls="none",
                            zorder=5, **moving)[0]
        self.canvas.restore_region(self._background)
        for artist in (goal_ring, goal_star):  # drawn once, into the layout's background
            ax.draw_artist(artist)
            artist.remove()
        self._layout_background = self.canvas.copy_from_bbox(self.fig.bbox)

        n = env.n_obstacles
        colors = [OBSTACLE_COLORS[i % len(OBSTACLE_COLORS)] for i in range(n)]
        rgba = matplotlib.colors.to_rgba_array(colors) if n else np.zeros((0, 4))
        self._sample_rgb = rgba[:, :3] * 255.0
        discs, trails = rgba.copy(), rgba.copy()
        discs[:, 3], trails[:, 3] = 0.6, 0.7
        diameters = 2.0 * np.asarray(env.obstacle_radii, dtype=float)
        self._obstacle_trails = ax.add_collection(
            LineCollection([], colors=trails, linewidths=1.0, zorder=3, **moving),
            autolim=False)
        self._ego_trail = ax.plot([], [], color=EGO_COLOR, lw=1.5, zorder=3, **moving)[0]
        self._obstacles = ax.add_collection(
            EllipseCollection(diameters, diameters, np.zeros(n), units="xy",
                              offsets=np.zeros((n, 2)), offset_transform=ax.transData,
                              facecolors=discs, edgecolors=discs, zorder=4, **moving),
            autolim=False)
        self._ego = ax.add_patch(Circle((0, 0), env.ego_radius, color=EGO_COLOR, alpha=0.8,
                                        zorder=4, **moving))
        self._moving = [self._obstacle_trails, self._ego_trail, self._obstacles, self._ego]
        self._layout = layout

    # -------------------------------------------------------------- drawing

    def _composite_samples(self, buffer: np.ndarray, predictions: np.ndarray) -> None:
        """Alpha-blend 2 x 2 px dots of each obstacle's samples into ``buffer`` (H, W, 4).

        Obstacle by obstacle, in order (as a scatter plot would draw them): a pixel
        under ``k`` dots of colour ``c`` goes from ``d`` to ``c + (d - c)(1 - a)^k``.
        The dots are counted per pixel with ``bincount`` over the box that the
        obstacle's dots touching the axes cover; pixels outside the axes are dropped.
        """
        linear, shift = self._affine[:2, :2].T, self._affine[:2, 2]  # data -> display pixels
        c0, c1, r0, r1 = self._clip
        height = self._height
        keep = 1.0 - SAMPLE_ALPHA
        rgb = buffer.reshape(-1, 4)  # a view: the buffer is contiguous
        for i in range(predictions.shape[0]):
            points = predictions[i].reshape(-1, 2)
            if not np.isfinite(points).all():
                points = points[np.isfinite(points).all(axis=1)]
            x, y = (points @ linear + shift).T
            cols = np.floor(x - 0.5).astype(np.int64)  # dot's left column
            rows = np.floor(height - y - 0.5).astype(np.int64)  # dot's top row
            # The dots with a pixel inside the axes; their box is then small.
            touch = (cols >= c0 - 1) & (cols < c1) & (rows >= r0 - 1) & (rows < r1)
            if not touch.all():
                cols, rows = cols[touch], rows[touch]
                if cols.size == 0:
                    continue
            left, top = int(cols.min()), int(rows.min())
            width = int(cols.max()) + 2 - left
            base = (rows - top) * width + (cols - left)
            index = np.concatenate((base, base + 1, base + width, base + width + 1))
            counts = np.bincount(index)
            hit = np.flatnonzero(counts)
            row_of, col_of = np.divmod(hit, width)
            row_of += top
            col_of += left
            inside = (row_of >= r0) & (row_of < r1) & (col_of >= c0) & (col_of < c1)
            hit, row_of, col_of = hit[inside], row_of[inside], col_of[inside]
            pixels = row_of * self._width + col_of
            colour = self._sample_rgb[i]
            old = rgb[pixels, :3].astype(np.float64)
            new = colour + (old - colour) * (keep ** counts[hit])[:, None]
            rgb[pixels, :3] = np.rint(new).astype(np.uint8)

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
            The frame, uint8 of shape ``(H, W, 3)``; ``None`` in human mode.
        """
        layout = (tuple(map(tuple, env.position_bounds)), tuple(env.goal), env.ego_radius,
                  tuple(env.obstacle_radii), env.goal_tolerance)
        if layout != self._layout:
            self._setup(env, layout)
        ax, canvas = self.ax, self.canvas

        self._ego.set_center(tuple(env.ego_state[:2]))
        if trail:
            ego_path = np.array([t[0] for t in trail])
            self._ego_trail.set_data(ego_path[:, 0], ego_path[:, 1])
            paths = np.array([t[1] for t in trail]).reshape(len(trail), -1, 2)  # (steps, n, 2)
            self._obstacle_trails.set_segments(list(paths.transpose(1, 0, 2)))
        self._obstacles.set_offsets(np.asarray(env.obstacle_positions, float).reshape(-1, 2))

        canvas.restore_region(self._layout_background)
        buffer = np.asarray(canvas.buffer_rgba())  # a view of the Agg buffer
        self._composite_samples(buffer, np.asarray(env.predictions))
        for artist in self._moving:
            ax.draw_artist(artist)

        before = set(ax.get_children())
        try:
            for hook in env.render_hooks:
                hook(ax)
            if ax.get_xlim() != self._limits[0] or ax.get_ylim() != self._limits[1]:
                ax.set(xlim=self._limits[0], ylim=self._limits[1])  # a hook moved the view
            added = [a for a in ax.get_children() if a not in before]
            for artist in sorted(added, key=lambda a: a.get_zorder()):
                ax.draw_artist(artist)
        finally:
            for artist in [a for a in ax.get_children() if a not in before]:
                artist.remove()
        self._caption.draw(buffer, f"t = {env.time:.1f} s   {env.scenario.name}")

        frame = np.empty((*buffer.shape[:2], 3), dtype=np.uint8)
        for k in range(3):  # per channel: faster than copying the strided [..., :3] view
            frame[..., k] = buffer[..., k]
        if self.human:
            self._show(frame)
            return None
        return frame

    def _show(self, frame: np.ndarray) -> None:
        import matplotlib.pyplot as plt  # human mode only

        if self._window is None:
            self._window = plt.figure(figsize=self.fig.get_size_inches(), dpi=self.fig.dpi)
            axes = self._window.add_axes((0, 0, 1, 1))
            axes.set_axis_off()
            self._image = axes.imshow(frame, interpolation="nearest")
            plt.show(block=False)
        else:
            self._image.set_data(frame)
        self._window.canvas.draw_idle()
        plt.pause(1.0 / self.fps)

    def close(self) -> None:
        """Release the window, if any, and forget the cached background."""
        if self._window is not None:
            import matplotlib.pyplot as plt

            plt.close(self._window)
        self._window = self._image = self._layout = None


class _Caption:
    """The caption above the axes, composed from cached monospace glyph cells.

    Text is the slowest thing matplotlib draws (2-4 ms a string). Each character is
    drawn by matplotlib once, into a cell of the caption strip, and its pixels are
    kept; a caption is then the cells side by side, one advance width apart (ink
    combined with ``min``: dark text on the white figure). Only the strip above the
    axes is touched, where nothing else is drawn.
    """

    def __init__(self, renderer: Renderer, *, top_row: int, left: int) -> None:
        from matplotlib.font_manager import FontProperties

        self._renderer = renderer
        self._rows = slice(max(0, top_row - 22), max(1, top_row))  # 22 px tall strip
        self._left = left
        prop = FontProperties(**CAPTION_FONT)
        width = renderer.canvas.get_renderer().get_text_width_height_descent(
            "0" * 20, prop, ismath=False)[0]
        self.advance = width / 20.0
        self._cell = int(np.ceil(self.advance)) + 2
        fig = renderer.fig
        height = fig.bbox.height
        self._text = fig.text(left / fig.bbox.width, (height - self._rows.stop + 6) / height,
                              "", fontproperties=prop, animated=True)
        self._glyphs: dict[str, np.ndarray] = {}

    def draw(self, buffer: np.ndarray, caption: str) -> None:
        """Write ``caption`` into the strip of ``buffer`` (H, W, 4), over white."""
        strip = buffer[self._rows, :, :3]
        for char in set(caption) - self._glyphs.keys():  # drawn once, then kept
            strip[...] = 255
            self._text.set_text(char)
            self._renderer.ax.draw_artist(self._text)
            self._glyphs[char] = strip[:, self._left : self._left + self._cell].copy()
        strip[...] = 255
        width = strip.shape[1]
        for i, char in enumerate(caption):
            cell = self._glyphs[char]
            x = self._left + int(round(i * self.advance))
            if x + cell.shape[1] > width:
                break
            target = strip[:, x : x + cell.shape[1]]
            np.minimum(target, cell, out=target)

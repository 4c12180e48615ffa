"""Drawing halfspaces and safe polytopes with matplotlib (imported lazily by callers).

``import filters`` never imports this module; the wrapper's render hook and the
evaluation plots do, when they draw.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def clip_polygon(polygon: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """Intersect a convex polygon with the halfspace ``normal @ y <= offset``.

    One Sutherland-Hodgman pass: keeps the vertices on the safe side and adds the
    crossing points of the edges that leave or enter it.

    Parameters
    ----------
    polygon
        Vertices in order, shape (k, 2).
    normal, offset
        The halfspace, ``normal`` shape (2,).

    Returns
    -------
    numpy.ndarray
        Vertices of the intersection, shape (k', 2); empty (0, 2) if it is empty.
    """
    values = polygon @ normal - offset
    result = []
    for current, following, v_current, v_following in zip(  # each edge, the last closing
            polygon, np.roll(polygon, -1, axis=0), values, np.roll(values, -1), strict=True):
        if v_current <= 0:
            result.append(current)
        if (v_current < 0 < v_following) or (v_following < 0 < v_current):
            share = v_current / (v_current - v_following)
            result.append(current + share * (following - current))
    return np.asarray(result, dtype=float).reshape(-1, 2)


def safe_polygon(
    normals: np.ndarray, offsets: np.ndarray, bounds: tuple[np.ndarray, np.ndarray]
) -> np.ndarray:
    """The polygon ``{y in box : normals[i] @ y <= offsets[i] for all i}``.

    Parameters
    ----------
    normals
        Shape (k, 2).
    offsets
        Shape (k,).
    bounds
        ``(low, high)`` corners of the bounding box (the arena), each shape (2,).
    """
    low, high = (np.asarray(b, dtype=float) for b in bounds)
    polygon = np.array([low, [high[0], low[1]], high, [low[0], high[1]]])
    for normal, offset in zip(np.asarray(normals), np.asarray(offsets), strict=True):
        polygon = clip_polygon(polygon, np.asarray(normal, dtype=float), float(offset))
    return polygon


def halfspace_segments(
    normals: np.ndarray, offsets: np.ndarray, xlim: tuple[float, float],
    ylim: tuple[float, float],
) -> np.ndarray:
    """End points ``(k, 2, 2)`` of the boundaries ``normals[i] @ y = offsets[i]`` across a view.

    Each segment runs along the boundary through its foot point ``offset * n / |n|^2``,
    twice the view's larger side in each direction, so it crosses the whole view. Rows
    with a zero normal (switched off) are left out.
    """
    normals = np.asarray(normals, dtype=float).reshape(-1, 2)
    norms = np.hypot(normals[:, 0], normals[:, 1])
    offsets, keep = np.asarray(offsets, dtype=float).reshape(-1), norms > 0
    unit = normals[keep] / norms[keep, None]
    foot = unit * (offsets[keep] / norms[keep])[:, None]
    tangent = np.stack([-unit[:, 1], unit[:, 0]], axis=1)
    span = 2.0 * max(xlim[1] - xlim[0], ylim[1] - ylim[0])
    return np.stack([foot - span * tangent, foot + span * tangent], axis=1)


def draw_halfspaces(
    ax: Any, normals: np.ndarray, offsets: np.ndarray, *, color: str = "tab:green",
    alpha: float = 0.6, reuse: Any = None, label: str | None = None,
) -> Any:
    """Draw the boundaries ``normals[i] @ y = offsets[i]`` as one line collection.

    The safe side of each is where ``normals[i] @ y <= offsets[i]``, away from the
    obstacle; one boundary (``normals`` shape (2,), a scalar offset) is the case k = 1.
    The segments cross the current view, whose limits are kept (the collection does not
    update the data limits). Pass the collection returned by the previous call as
    ``reuse`` to update it instead of building a new one (building it is most of the
    render hook's cost per frame).

    Returns
    -------
    matplotlib.collections.LineCollection or None
        The collection drawn (``None`` if every row was switched off).
    """
    from matplotlib.collections import LineCollection

    segments = halfspace_segments(normals, offsets, ax.get_xlim(), ax.get_ylim())
    if not len(segments):
        return None
    if reuse is None:
        reuse = LineCollection([], colors=color, alpha=alpha, linewidths=1.2, label=label)
    reuse.set_segments(segments)
    ax.add_collection(reuse, autolim=False)
    return reuse


draw_halfspace = draw_halfspaces
"""One boundary ``normal @ y = offset`` (the same function: ``k = 1``)."""

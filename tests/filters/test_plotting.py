"""filters.plotting: the safe polygon is the box cut by every halfspace; boundaries drawn."""

from __future__ import annotations

import matplotlib
import numpy as np

from filters.plotting import draw_halfspace, draw_halfspaces, safe_polygon

matplotlib.use("Agg", force=False)


def _inside(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Whether each point lies in the convex polygon (vertices counter-clockwise)."""
    edges = np.roll(polygon, -1, axis=0) - polygon
    rel = points[:, None, :] - polygon[None]
    cross = edges[None, :, 0] * rel[..., 1] - edges[None, :, 1] * rel[..., 0]
    return np.all(cross >= -1e-9, axis=1)


def test_safe_polygon_is_the_box_cut_by_every_halfspace():
    rng = np.random.default_rng(5)
    low, high = np.array([-5.0, -4.0]), np.array([5.0, 6.0])
    for _ in range(50):
        k = int(rng.integers(1, 5))
        normals, offsets = rng.normal(size=(k, 2)), rng.normal(scale=2.0, size=k)
        polygon = safe_polygon(normals, offsets, (low, high))
        points = rng.uniform(low, high, size=(400, 2))
        safe = np.all(points @ normals.T <= offsets, axis=1)
        if len(polygon) < 3:  # empty (or degenerate): no sampled point is safe
            assert not safe.any()
            continue
        assert np.all(polygon @ normals.T <= offsets + 1e-9)
        assert np.all((polygon >= low - 1e-9) & (polygon <= high + 1e-9))
        margin = np.min(np.abs(points @ normals.T - offsets), axis=1) > 1e-6
        np.testing.assert_array_equal(_inside(points, polygon)[margin], safe[margin])


def test_boundaries_are_one_reused_collection_within_the_view():
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    ax.set(xlim=(-2, 2), ylim=(-1, 3))
    lines = draw_halfspaces(ax, np.array([[1.0, 0.0], [0.0, 0.0]]), np.array([0.5, 1.0]))
    assert len(lines.get_segments()) == 1  # the zero normal is switched off
    again = draw_halfspaces(ax, np.array([[0.0, 1.0]]), np.array([2.0]), reuse=lines)
    assert again is lines
    np.testing.assert_allclose(again.get_segments()[0][:, 1], 2.0)
    one = draw_halfspace(ax, np.array([1.0, 1.0]), 0.0, label="mean")
    assert one.get_label() == "mean" and len(one.get_segments()) == 1
    assert ax.get_xlim() == (-2, 2) and ax.get_ylim() == (-1, 3)  # the view is kept
    plt.close(fig)

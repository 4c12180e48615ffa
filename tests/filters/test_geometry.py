"""Support functions and collision margins of :mod:`filters.geometry`."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from filters.errors import InvalidArrayError, InvalidShapeError, InvalidTypeError
from filters.geometry import ConvexPolygon, Disc, collision_margin


def random_polygon(rng: np.random.Generator, n_points: int = 12) -> np.ndarray:
    """Vertices (counter-clockwise) of the convex hull of random points."""
    points = rng.normal(size=(n_points, 2)) * rng.uniform(0.2, 2.0, size=2)
    return points[ConvexHull(points).vertices]


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_disc_support_is_radius_times_norm(dim):
    rng = np.random.default_rng(dim)
    directions = rng.normal(size=(4, 5, dim))
    support = Disc(0.7).support(directions)
    assert support.shape == (4, 5)
    np.testing.assert_allclose(support, 0.7 * np.linalg.norm(directions, axis=-1), rtol=1e-15)


def test_disc_is_symmetric_and_zero_radius_is_a_point():
    disc = Disc(0.3)
    assert disc.reflected() == disc
    assert Disc(0).support(np.array([3.0, 4.0])) == 0.0
    assert Disc(np.float32(0.5)).radius == 0.5


@pytest.mark.parametrize("radius", [-0.1, math.nan, math.inf, -math.inf])
def test_disc_rejects_bad_radius(radius):
    with pytest.raises(InvalidShapeError, match="radius"):
        Disc(radius)


@pytest.mark.parametrize("radius", ["0.3", None, True])
def test_disc_rejects_non_numbers(radius):
    with pytest.raises(InvalidTypeError, match="radius"):
        Disc(radius)


@pytest.mark.parametrize("seed", range(5))
def test_polygon_support_matches_brute_force_over_vertices(seed):
    rng = np.random.default_rng(seed)
    vertices = random_polygon(rng)
    polygon = ConvexPolygon(vertices)
    directions = rng.normal(size=(7, 3, 2))
    brute = np.array([[max(float(z @ v) for v in vertices) for z in row] for row in directions])
    np.testing.assert_allclose(polygon.support(directions), brute, rtol=1e-14, atol=1e-14)


def test_polygon_orientation_is_normalised():
    rng = np.random.default_rng(7)
    vertices = random_polygon(rng)
    ccw, cw = ConvexPolygon(vertices), ConvexPolygon(vertices[::-1])
    assert ccw == cw and hash(ccw) == hash(cw)
    directions = rng.normal(size=(20, 2))
    np.testing.assert_array_equal(ccw.support(directions), cw.support(directions))


def test_box_support_closed_form():
    box = ConvexPolygon.box(2.0, 0.5)
    z = np.random.default_rng(1).normal(size=(50, 2))
    np.testing.assert_allclose(box.support(z), 1.0 * np.abs(z[:, 0]) + 0.25 * np.abs(z[:, 1]))
    np.testing.assert_allclose(np.mean(box.vertex_array, axis=0), [0.0, 0.0])


def test_reflected_polygon_support():
    rng = np.random.default_rng(3)
    polygon = ConvexPolygon(random_polygon(rng) + [1.0, -2.0])
    z = rng.normal(size=(30, 2))
    np.testing.assert_allclose(polygon.reflected().support(z), polygon.support(-z), rtol=1e-14)


@pytest.mark.parametrize(
    "vertices",
    [
        [(0, 0), (1, 0)],  # too few
        [(0, 0), (1, 0), (1, 1), (1, 0)],  # duplicate
        [(0, 0), (1, 0), (2, 0), (1, 1)],  # collinear triple
        [(0, 0), (1, 0), (2, 0)],  # zero area
        [(0, 0), (2, 0), (1, 0.5), (2, 2), (0, 2)],  # non-convex (dart)
        [(np.cos(a), np.sin(a)) for a in 4 * np.pi * np.arange(5) / 5],  # pentagram
    ],
)
def test_polygon_rejects_degenerate_or_non_convex(vertices):
    with pytest.raises(InvalidShapeError, match="ConvexPolygon"):
        ConvexPolygon(vertices)


def test_polygon_rejects_bad_arrays():
    with pytest.raises(InvalidArrayError, match="vertices"):
        ConvexPolygon([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    with pytest.raises(InvalidArrayError, match="vertices"):
        ConvexPolygon([(0, 0), (1, np.nan), (0, 1)])


@pytest.mark.parametrize("width, height", [(0.0, 1.0), (1.0, -1.0), (math.inf, 1.0)])
def test_box_rejects_bad_size(width, height):
    with pytest.raises(InvalidShapeError, match="width|height"):
        ConvexPolygon.box(width, height)


def test_support_rejects_bad_directions():
    with pytest.raises(InvalidArrayError, match="directions"):
        ConvexPolygon.box(1, 1).support(np.ones((3, 3)))
    with pytest.raises(InvalidArrayError, match="directions"):
        Disc(1.0).support(np.array([np.nan, 1.0]))
    with pytest.raises(InvalidArrayError, match="directions"):
        Disc(1.0).support(1.0)


def test_collision_margin_of_two_discs_is_sum_of_radii():
    rng = np.random.default_rng(0)
    h = rng.normal(size=(3, 10, 2))
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    margin = collision_margin(Disc(0.3), Disc(0.45), h)
    assert margin.shape == (3, 10)
    np.testing.assert_allclose(margin, 0.75, rtol=1e-15)


def test_collision_margin_uses_reflected_ego():
    rng = np.random.default_rng(1)
    ego = ConvexPolygon([(0.0, 0.0), (1.0, 0.0), (0.0, 0.5)])  # not symmetric
    obstacle = Disc(0.2)
    h = rng.normal(size=(25, 2))
    expected = 0.2 * np.linalg.norm(h, axis=-1) + np.max(-(h @ ego.vertex_array.T), axis=-1)
    np.testing.assert_allclose(collision_margin(ego, obstacle, h), expected, rtol=1e-14)


def test_collision_margin_rejects_non_shapes():
    with pytest.raises(InvalidTypeError, match="obstacle_shape"):
        collision_margin(Disc(0.3), 0.3, np.ones(2))

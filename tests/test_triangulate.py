"""Triangulation of planar polygons with holes: area is preserved, orientation follows the exterior."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from semcityloc.citymodel.triangulate import polygon_area, triangulate_polygon


def shoelace(xy: np.ndarray) -> float:
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def star(rng: np.random.Generator, n: int, r_min: float, r_max: float, ccw: bool = True) -> np.ndarray:
    """A simple star-shaped polygon around the origin: n evenly spaced angles jittered by up to a sixth of
    their spacing, radii in [r_min, r_max]. With n >= 6 the gaps stay below 80 degrees, so the disc of
    radius r_min * cos(40 deg) ~ 0.77 r_min lies inside it."""
    spacing = 2 * np.pi / n
    angles = np.arange(n) * spacing + rng.uniform(-spacing / 6, spacing / 6, n)
    radii = rng.uniform(r_min, r_max, n)
    pts = np.stack([radii * np.cos(angles), radii * np.sin(angles)], axis=1)
    return pts if ccw else pts[::-1]


def lift(xy: np.ndarray, rotation: np.ndarray, offset: np.ndarray) -> np.ndarray:
    return np.c_[xy, np.zeros(len(xy))] @ rotation.T + offset


def triangulated_area(tri) -> float:
    p = tri.points[tri.triangles]
    return 0.5 * float(np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum())


@settings(max_examples=150, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    n_outer=st.integers(6, 40),
    n_holes=st.integers(0, 3),
    size=st.floats(0.5, 300.0),
)
def test_area_preserved_for_random_polygons_with_holes(seed, n_outer, n_holes, size):
    rng = np.random.default_rng(seed)
    outer = star(rng, n_outer, 0.6 * size, size)
    holes = []
    for k in range(n_holes):
        # Holes are small stars around points well inside the outer polygon's kernel, not overlapping.
        angle = 2 * np.pi * k / max(n_holes, 1)
        centre = 0.3 * size * np.array([np.cos(angle), np.sin(angle)]) if n_holes > 1 else np.zeros(2)
        holes.append(star(rng, int(rng.integers(3, 12)), 0.02 * size, 0.1 * size, ccw=False) + centre)
    expected = abs(shoelace(outer)) - sum(abs(shoelace(h)) for h in holes)

    rotation = Rotation.random(random_state=seed).as_matrix()
    offset = np.array([391000.0, 5817000.0, 40.0])  # UTM-sized coordinates
    tri = triangulate_polygon(lift(outer, rotation, offset), [lift(h, rotation, offset) for h in holes])
    assert tri is not None
    np.testing.assert_allclose(triangulated_area(tri), expected, rtol=1e-6)
    np.testing.assert_allclose(
        polygon_area(lift(outer, rotation, offset), [lift(h, rotation, offset) for h in holes]),
        expected,
        rtol=1e-6,
    )
    # Every triangle faces the way the exterior ring does (CityGML: counter-clockwise from outside).
    p = tri.points[tri.triangles]
    normals = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert np.all(normals @ rotation[:, 2] > 0)


def test_orientation_follows_ring_direction():
    square = np.array([[0, 0, 5], [4, 0, 5], [4, 4, 5], [0, 4, 5]], dtype=float)
    up = triangulate_polygon(square)
    down = triangulate_polygon(square[::-1])
    assert up.normal[2] == 1.0 and down.normal[2] == -1.0
    for tri, sign in ((up, 1), (down, -1)):
        p = tri.points[tri.triangles]
        assert np.all(sign * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])[:, 2] > 0)


def test_closing_point_and_duplicates_are_removed():
    ring = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 0]], dtype=float)
    tri = triangulate_polygon(ring)
    assert len(tri.points) == 4 and len(tri.triangles) == 2


def test_degenerate_polygons_give_none():
    assert triangulate_polygon(np.zeros((0, 3))) is None
    assert triangulate_polygon(np.array([[0, 0, 0], [1, 1, 1], [0, 0, 0]], dtype=float)) is None
    collinear = np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3]], dtype=float)
    assert triangulate_polygon(collinear) is None


def test_nonplanar_polygon_is_meshed_and_reported():
    ring = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 1.0], [0, 10, 0]], dtype=float)
    tri = triangulate_polygon(ring)
    assert tri is not None and len(tri.triangles) == 2
    assert tri.planarity_m > 0.2

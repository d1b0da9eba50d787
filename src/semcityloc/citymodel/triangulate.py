"""Triangulate planar 3D polygons with holes (CityGML / CityJSON surfaces).

Each polygon is projected onto the plane through its centroid with the Newell normal of its exterior
ring, triangulated in 2D with mapbox-earcut, and lifted back with the original 3D points (no vertex is
moved). Triangles are oriented so that their normals agree with the exterior ring's Newell normal: the
CityGML rule (counter-clockwise seen from outside) carries over to the triangles.

Degenerate polygons (fewer than 3 distinct points, zero area) return ``None`` and the caller counts them;
non-planar polygons are still triangulated (the deviation is reported).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import mapbox_earcut
import numpy as np

# A polygon whose points lie farther than this from its best plane counts as non-planar (metres).
NONPLANAR_TOLERANCE_M = 0.05
# Points closer than this are one point (metres): removes repeated and closing points.
DUPLICATE_TOLERANCE_M = 1e-6


@dataclass
class Triangulation:
    """One polygon triangulated: its distinct points (exterior first, then holes), the triangles as indices
    into them, the unit Newell normal of the exterior ring and how far the polygon is from planar, which
    the builder uses to classify and to warn about warped surfaces.
    """

    points: np.ndarray  # (n, 3) float64, the polygon's distinct points (exterior first, then holes)
    triangles: np.ndarray  # (m, 3) int64 indices into points
    normal: np.ndarray  # (3,) unit Newell normal of the exterior ring
    planarity_m: float  # largest distance of a point from the polygon's plane


def clean_ring(ring: np.ndarray) -> np.ndarray:
    """Drop the closing point and consecutive duplicates of a (n, 3) ring."""
    ring = np.asarray(ring, dtype=np.float64).reshape(-1, 3)
    if len(ring) == 0:
        return ring
    step = np.empty_like(ring)
    np.subtract(ring[1:], ring[:-1], out=step[:-1])
    np.subtract(ring[0], ring[-1], out=step[-1])
    return ring[np.einsum("ij,ij->i", step, step) > DUPLICATE_TOLERANCE_M * DUPLICATE_TOLERANCE_M]


def newell_normal(ring: np.ndarray) -> np.ndarray:
    """Newell's (unnormalised) normal of a closed ring given without its closing point: 2 * area * n."""
    # Centre first: the products then stay small for coordinates like 5.8e6.
    a = ring - ring.sum(0) / len(ring)
    return _newell_centred(a)


# Newell: n_x = sum (y_i - y_j)(z_i + z_j), n_y = sum (z_i - z_j)(x_i + x_j), n_z = sum (x_i - x_j)(y_i + y_j)
_NEWELL_D = np.array([1, 2, 0])
_NEWELL_S = np.array([2, 0, 1])


def _newell_centred(a: np.ndarray) -> np.ndarray:
    """Newell's normal of a ring already centred on its mean (one vectorised expression)."""
    b = np.concatenate((a[1:], a[:1]))
    return ((a - b)[:, _NEWELL_D] * (a + b)[:, _NEWELL_S]).sum(0)


def _cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of two 3-vectors (np.cross costs ~10x more for single vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def plane_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors u, v with u x v = normal (right-handed in-plane axes)."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = _cross3(helper, normal)
    u /= np.sqrt(u @ u)
    v = _cross3(normal, u)
    return u, v


def triangulate_polygon(
    exterior: np.ndarray, interiors: list[np.ndarray] | tuple = ()
) -> Triangulation | None:
    """Triangulate one polygon; ``None`` when it is degenerate or earcut finds no triangle."""
    ext = clean_ring(exterior)
    if len(ext) < 3:
        return None
    centre = ext.sum(0) / len(ext)
    rel_ext = ext - centre
    n = _newell_centred(rel_ext)  # = newell_normal(ext), centred once for both uses
    norm = math.sqrt(float(n @ n))
    scale = max(float((ext.max(0) - ext.min(0)).max()), 1e-12)
    if norm < 1e-12 * scale * scale or norm < 1e-10:
        return None
    n = n / norm
    holes = [h for h in (clean_ring(r) for r in interiors) if len(h) >= 3] if len(interiors) else []
    pts = np.concatenate([ext, *holes]) if holes else ext
    rel = np.concatenate([rel_ext, *(h - centre for h in holes)]) if holes else rel_ext
    planarity = float(np.abs(rel @ n).max())

    if len(ext) == 3 and not holes:
        return Triangulation(ext, np.array([[0, 1, 2]]), n, planarity)

    u, v = plane_basis(n)
    pts2d = rel @ np.array((u, v)).T
    ends = np.array(list(itertools.accumulate([len(ext)] + [len(h) for h in holes])), dtype=np.uint32)
    idx = mapbox_earcut.triangulate_float64(pts2d, ends)
    if len(idx) == 0:
        return None
    tris = idx.reshape(-1, 3).astype(np.int64)
    p = pts2d[tris]
    e1 = p[:, 1] - p[:, 0]
    e2 = p[:, 2] - p[:, 0]
    signed = e1[:, 0] * e2[:, 1] - e2[:, 0] * e1[:, 1]
    keep = np.abs(signed) > 1e-14 * scale * scale
    if not keep.all():
        tris, signed = tris[keep], signed[keep]
    if len(tris) == 0:
        return None
    flip = signed < 0
    if flip.any():
        tris[flip] = tris[flip][:, [0, 2, 1]]
    return Triangulation(pts, tris, n, planarity)


def ring_area_xy(ring: np.ndarray) -> float:
    """Signed area of a ring (N, 2+) seen from above: the shoelace formula on its x, y about the ring's mean
    (so CRS-sized coordinates lose no digits); positive when counter-clockwise. The one 2-D shoelace of the
    library (LoD1 footprints, the generated city's footprints)."""
    c = ring[:, :2] - ring[:, :2].mean(0)
    x, y = c[:, 0], c[:, 1]
    return float(0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def polygon_area(exterior: np.ndarray, interiors: list[np.ndarray] | tuple = ()) -> float:
    """Area of a planar polygon with holes in any orientation in 3D (the Newell normal's length on its own
    plane), for checks and statistics. Public API: the tests measure a model's surface areas with it (a
    wall's area minus its openings); the library itself needs only ``ring_area_xy``."""
    ext = clean_ring(exterior)
    if len(ext) < 3:
        return 0.0
    n = newell_normal(ext)
    norm = np.linalg.norm(n)
    if norm == 0:
        return 0.0
    unit = n / norm
    area = 0.5 * norm
    for ring in interiors:
        h = clean_ring(ring)
        if len(h) >= 3:
            area -= 0.5 * abs(float(newell_normal(h) @ unit))
    return float(area)

"""Where buildings meet the ground: their bottoms, their base points, and the border ring of a terrain.

Why here (and not in ``render.terrain``, which triangulates them): these are facts of the model alone,
and a tile store (``citymodel.tiles``) computes the whole city's border ring when it is built, so that a
part of the city loaded for one photo gets the same terrain as the whole city.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from semcityloc.citymodel.model import CityModel
from semcityloc.classes import SemanticClass

# Terrain lies this far below the building bottoms: enough for the z-buffer, invisible in a mask.
TERRAIN_DROP_M = 0.05
# A vertex within this height of its building's lowest point is a base (footprint) point.
BASE_HEIGHT_TOLERANCE_M = 0.5
# Margin around the model: max(MIN_MARGIN_M, MARGIN_FRACTION * largest horizontal extent).
MIN_MARGIN_M = 200.0
MARGIN_FRACTION = 0.3
# Spacing of the points on the border ring.
RING_SPACING_M = 50.0
# Base points closer than this in x, y are merged (keeping the lowest): Delaunay needs distinct points.
MERGE_XY_M = 0.01


def building_bottom_mask(model: CityModel) -> np.ndarray:
    """(T,) bool: GROUND triangles that are building bottoms (never visible from the air).

    A GROUND triangle is a bottom when its building also has non-ground surfaces (walls, roofs) and all
    its vertices lie within ``BASE_HEIGHT_TOLERANCE_M`` of that building's lowest point. Ground-only
    objects (a CityJSON TrafficArea, a terrain TIN read as ground) are kept: they are seen from above.
    """
    t = model.num_triangles
    if t == 0:
        return np.zeros(0, dtype=bool)
    z = model.vertices[model.triangles][:, :, 2].astype(np.float64)  # (T, 3)
    b = model.building_index
    nb = int(b.max()) + 1
    b_min = np.full(nb, np.inf)
    np.minimum.at(b_min, b, z.min(1))
    ground = model.classes == SemanticClass.GROUND
    has_other = np.zeros(nb, dtype=bool)
    has_other[b[~ground]] = True
    near_bottom = z.max(1) <= b_min[b] + BASE_HEIGHT_TOLERANCE_M
    return ground & has_other[b] & near_bottom


def base_points(model: CityModel) -> np.ndarray:
    """(M, 3) float64 footprint points: every vertex within the tolerance of its building's bottom.

    Only buildings with walls or roofs count. Points with the same x, y (shared walls of adjacent
    buildings) are merged, keeping the lowest height.
    """
    if model.num_triangles == 0:
        return np.zeros((0, 3))
    corners = model.vertices[model.triangles].astype(np.float64)  # (T, 3, 3)
    b = model.building_index
    nb = int(b.max()) + 1
    b_min = np.full(nb, np.inf)
    np.minimum.at(b_min, b, corners[:, :, 2].min(1))
    ground = model.classes == SemanticClass.GROUND
    has_other = np.zeros(nb, dtype=bool)
    has_other[b[~ground]] = True
    pts = corners.reshape(-1, 3)
    pb = np.repeat(b, 3)
    keep = has_other[pb] & (pts[:, 2] <= b_min[pb] + BASE_HEIGHT_TOLERANCE_M)
    return merge_base_points(pts[keep])


def merge_base_points(pts: np.ndarray) -> np.ndarray:
    """``pts`` (M, 3) with points of the same x, y (within ``MERGE_XY_M``) merged, keeping the lowest,
    sorted by their x, y key (so the same set of points always comes out in the same order)."""
    if len(pts) == 0:
        return pts
    key = np.round(pts[:, :2] / MERGE_XY_M).astype(np.int64)
    order = np.lexsort((pts[:, 2], key[:, 1], key[:, 0]))  # per (x, y) key, lowest z first
    key, pts = key[order], pts[order]
    first = np.ones(len(pts), dtype=bool)
    first[1:] = np.any(key[1:] != key[:-1], axis=1)
    return pts[first]


def _ring(lo: np.ndarray, hi: np.ndarray, spacing: float) -> np.ndarray:
    """(K, 2) points along the rectangle [lo, hi], about ``spacing`` apart, corners included."""
    nx = max(1, int(np.ceil((hi[0] - lo[0]) / spacing)))
    ny = max(1, int(np.ceil((hi[1] - lo[1]) / spacing)))
    xs = np.linspace(lo[0], hi[0], nx + 1)
    ys = np.linspace(lo[1], hi[1], ny + 1)
    bottom = np.stack([xs, np.full_like(xs, lo[1])], 1)
    top = np.stack([xs, np.full_like(xs, hi[1])], 1)
    left = np.stack([np.full_like(ys[1:-1], lo[0]), ys[1:-1]], 1)
    right = np.stack([np.full_like(ys[1:-1], hi[0]), ys[1:-1]], 1)
    return np.concatenate([bottom, top, left, right])


def store_ring(bases: list[np.ndarray]) -> np.ndarray:
    """The border ring (``ring_points``) of the terrain through the base points of several models (the
    tiles of a store, ``base_points`` of each), lowered by ``TERRAIN_DROP_M`` as ``build_terrain`` does."""
    base = merge_base_points(np.concatenate([b.reshape(-1, 3) for b in bases]))
    if not len(base):
        return np.zeros((0, 3))
    base = base.copy()
    base[:, 2] -= TERRAIN_DROP_M
    return ring_points(base)


def ring_points(base: np.ndarray, margin_m: float | None = None) -> np.ndarray:
    """(K, 3) the terrain's border ring: points about ``RING_SPACING_M`` apart on the rectangle ``margin_m``
    outside the base points' x, y box (default ``max(MIN_MARGIN_M, MARGIN_FRACTION * largest extent)``),
    each at the height of its nearest base point."""
    lo, hi = base[:, :2].min(0), base[:, :2].max(0)
    if margin_m is None:
        margin_m = max(MIN_MARGIN_M, MARGIN_FRACTION * float(np.max(hi - lo)))
    ring_xy = _ring(lo - margin_m, hi + margin_m, RING_SPACING_M)
    _, nearest = cKDTree(base[:, :2]).query(ring_xy)
    return np.column_stack([ring_xy, base[nearest, 2]])

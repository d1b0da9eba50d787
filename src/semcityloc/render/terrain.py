"""A ground surface for the renderer: a TIN through the buildings' base points, extended by a margin.

City models describe buildings, not the ground between them. From the air the ground is most of the
picture, so the renderer adds a terrain of class GROUND: a Delaunay triangulation (in x, y) of the
buildings' base points (the footprint corners at their bottom height), lowered by ``TERRAIN_DROP_M`` so it
never z-fights with the building bottoms, and surrounded by a border ring ``margin`` metres outside the
model whose heights are those of the nearest base point. Terrain slopes therefore follow the model.

Terrain triangles lying entirely under a building (inside the union of its GroundSurface triangles, the
footprint) are dropped: the building's walls and roof hide them from every camera outside it, and in
dense districts they are half of the terrain triangles (Berlin: 2298 of 4564) and 15-20% of the raster
work. The price: where a model is not watertight (cracks between roof and wall polygons), or a grazing
ray slips through the ``TERRAIN_DROP_M`` slit under a wall, a pixel that saw ground under the building
now sees nothing (class 0): 0.03% of the pixels of 400 random aerial Berlin views at 256 x 192.
``build_terrain(..., drop_hidden=False)`` / ``build_scene(..., drop_hidden_terrain=False)`` keep them.

Everything here is in the model's local frame (float64 in, float64 out; the scene casts to float32).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.spatial import Delaunay, cKDTree

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
    pts = pts[keep]
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


def build_terrain(
    model: CityModel,
    margin_m: float | None = None,
    drop_hidden: bool = True,
    extra_points: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Terrain TIN in the local frame: (vertices (V, 3) float64, triangles (F, 3) int32).

    ``drop_hidden``: leave out the triangles that lie under building footprints (module docstring).
    ``extra_points``: (K, 3) more terrain points, triangulated with the others as given (not lowered;
    e.g. the benchmark reality's relief grid). Returns empty arrays when the model has no building with
    walls or roofs.
    """
    base = base_points(model)
    if len(base) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int32)
    base = base.copy()
    base[:, 2] -= TERRAIN_DROP_M
    lo, hi = base[:, :2].min(0), base[:, :2].max(0)
    if margin_m is None:
        margin_m = max(MIN_MARGIN_M, MARGIN_FRACTION * float(np.max(hi - lo)))
    ring_xy = _ring(lo - margin_m, hi + margin_m, RING_SPACING_M)
    _, nearest = cKDTree(base[:, :2]).query(ring_xy)
    ring = np.column_stack([ring_xy, base[nearest, 2]])
    points = np.concatenate([base, ring])
    if extra_points is not None and len(extra_points):
        points = np.concatenate([points, np.asarray(extra_points, dtype=np.float64).reshape(-1, 3)])
    tri = Delaunay(points[:, :2])
    simplices = tri.simplices.astype(np.int32)
    if drop_hidden:
        bottoms = model.vertices[model.triangles[building_bottom_mask(model)]][:, :, :2].astype(np.float64)
        if len(bottoms):
            simplices = simplices[~_under_footprints(points[simplices][:, :, :2], bottoms)]
    # Delaunay may drop coincident points; keep only the vertices it used.
    used, inverse = np.unique(simplices, return_inverse=True)
    return points[used], inverse.reshape(-1, 3).astype(np.int32)


# Sample points (barycentric) tested per terrain triangle: the centroid, points near the corners and
# along the edges, all pulled 2% toward the centroid so that edges on a footprint outline count inside
# only when the triangle is on the inner side.
_SAMPLES = np.array(
    [[1 / 3, 1 / 3, 1 / 3]]
    + [[a, b, 1 - a - b] for a, b in [(0.96, 0.02), (0.02, 0.96), (0.02, 0.02)]]
    + [[a, 1 - a - 0.02, 0.02] for a in (0.25, 0.5, 0.75)]
    + [[0.02, a, 1 - a - 0.02] for a in (0.25, 0.5, 0.75)]
    + [[a, 0.02, 1 - a - 0.02] for a in (0.25, 0.5, 0.75)]
)


def _under_footprints(tris2d: np.ndarray, footprint2d: np.ndarray) -> np.ndarray:
    """(F,) bool: every sample point of terrain triangle f lies in some footprint triangle (2D)."""
    samples = np.einsum("sk,fkd->fsd", _SAMPLES, tris2d)  # (F, S, 2)
    lo = footprint2d.min(1)
    hi = footprint2d.max(1)
    cell = max(float(np.median(hi - lo)) * 2.0, 1.0)
    origin = lo.min(0)
    c0 = np.floor((lo - origin) / cell).astype(np.int64)
    c1 = np.floor((hi - origin) / cell).astype(np.int64)
    ncx, ncy = int(c1[:, 0].max()) + 1, int(c1[:, 1].max()) + 1
    # CSR grid: footprint triangles per cell.
    spans = (c1[:, 0] - c0[:, 0] + 1) * (c1[:, 1] - c0[:, 1] + 1)
    owner = np.repeat(np.arange(len(footprint2d)), spans)
    k = np.arange(len(owner)) - np.repeat(np.cumsum(spans) - spans, spans)
    w = np.repeat(c1[:, 0] - c0[:, 0] + 1, spans)
    cx = np.repeat(c0[:, 0], spans) + k % w
    cy = np.repeat(c0[:, 1], spans) + k // w
    key = cy * ncx + cx
    order = np.argsort(key, kind="stable")
    cell_start = np.searchsorted(key[order], np.arange(ncx * ncy + 1)).astype(np.int64)
    return _all_samples_inside(samples, footprint2d, owner[order], cell_start, origin, cell, ncx, ncy)


@njit(cache=True)
def _all_samples_inside(samples, tris, cell_tri, cell_start, origin, cell, ncx, ncy):
    out = np.zeros(samples.shape[0], dtype=np.bool_)
    for f in range(samples.shape[0]):
        all_in = True
        for s in range(samples.shape[1]):
            x, y = samples[f, s, 0], samples[f, s, 1]
            gx = int(np.floor((x - origin[0]) / cell))
            gy = int(np.floor((y - origin[1]) / cell))
            found = False
            if 0 <= gx < ncx and 0 <= gy < ncy:
                c = gy * ncx + gx
                for q in range(cell_start[c], cell_start[c + 1]):
                    t = cell_tri[q]
                    ax, ay = tris[t, 0, 0], tris[t, 0, 1]
                    bx, by = tris[t, 1, 0], tris[t, 1, 1]
                    qx, qy = tris[t, 2, 0], tris[t, 2, 1]
                    d1 = (bx - ax) * (y - ay) - (by - ay) * (x - ax)
                    d2 = (qx - bx) * (y - by) - (qy - by) * (x - bx)
                    d3 = (ax - qx) * (y - qy) - (ay - qy) * (x - qx)
                    if (d1 >= 0 and d2 >= 0 and d3 >= 0) or (d1 <= 0 and d2 <= 0 and d3 <= 0):
                        found = True
                        break
            if not found:
                all_in = False
                break
        out[f] = all_in
    return out

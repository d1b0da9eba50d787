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
from scipy.spatial import Delaunay

from semcityloc.citymodel.ground import TERRAIN_DROP_M, base_points, building_bottom_mask, ring_points
from semcityloc.citymodel.model import CityModel


def build_terrain(
    model: CityModel,
    margin_m: float | None = None,
    drop_hidden: bool = True,
    extra_points: np.ndarray | None = None,
    ring: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Terrain TIN in the local frame: (vertices (V, 3) float64, triangles (F, 3) int32).

    ``drop_hidden``: leave out the triangles that lie under building footprints (module docstring).
    ``extra_points``: (K, 3) more terrain points, triangulated with the others as given (not lowered;
    e.g. the benchmark reality's relief grid). ``ring``: (K, 3) border points replacing the model's own
    (``ground.ring_points`` of a bigger area: a tile store's, so a part of the city gets the whole city's
    border). Returns empty arrays when the model has no building with
    walls or roofs.
    """
    base = base_points(model)
    if len(base) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int32)
    base = base.copy()
    base[:, 2] -= TERRAIN_DROP_M
    if ring is None:
        ring = ring_points(base, margin_m)
    points = np.concatenate([base, np.asarray(ring, dtype=np.float64).reshape(-1, 3)])
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

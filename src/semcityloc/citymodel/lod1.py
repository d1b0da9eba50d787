"""Derive an LoD1 block model from any (LoD2/LoD3) ``CityModel``.

Why: LoD-Loc style localization is evaluated against LoD1 city models as much as LoD2; deriving LoD1
from the same LoD2 source gives a pair of models with identical footprints, so the effect of the level of
detail can be measured in isolation.

Per building (``building_index``):

- Footprint: the union of the building's GROUND triangles projected to xy. Vertices are welded (within
  ``WELD_TOLERANCE_M``), triangles are made counter-clockwise, edges are split at vertices lying on them
  (T-junctions between neighbouring ground polygons), and the boundary is the set of edges whose
  directed uses do not cancel (used by exactly one triangle). The boundary edges are chained into rings
  (split where a ring touches itself), counter-clockwise rings are outlines and clockwise rings are holes
  (courtyards), each hole assigned to the outline that contains it.
- Overlaps: when a point just left of some boundary edge has winding number other than 1 (ground
  polygons of building parts overlapping, roof projections overlapping under dormers), the boundary edges
  are split where they cross and only the pieces with no triangle on their right are kept: the exact
  outline of the union. Probes sit ``PROBE_OFFSET_M`` beside the edges, so slivers thinner than that
  count as closed.
- Fallbacks, each noted in ``stats.warnings``: when the union cannot be made consistent (numerically
  degenerate overlaps), the rings of the net boundary are used as drawn (overlapping blocks); a building
  without ground triangles uses the outline of its ROOF triangles the same way; the last resort is the 2D
  convex hull of all its triangles (e.g. a building of walls only).
- Height: from the building's lowest point (``z0``) to ``z1`` chosen by ``height``:
  ``"median_roof"`` (default) the area-weighted median height of the roof surface, computed exactly from
  the height distribution over each roof triangle (so it does not depend on the triangulation; a gable
  roof gives the mid-height between eaves and ridge); ``"max"`` the building's top; ``"eaves"`` the
  lowest roof point. Buildings without roof triangles use their top for every option.
- Output: one vertical WALL quad per outline edge (collinear outline vertices removed first), a flat ROOF
  and a GROUND polygon (holes kept), all with outward orientation, ``lod`` = 1, the same origin, CRS and
  ``building_ids`` as the input. Buildings without an area footprint or height are skipped with a
  warning.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError, cKDTree

from semcityloc.citymodel.builder import MeshBuilder
from semcityloc.citymodel.model import CityModel, ParseStats
from semcityloc.citymodel.triangulate import ring_area_xy
from semcityloc.classes import SemanticClass
from semcityloc.errors import EmptyModelError, ParameterError, unknown_choice

HEIGHT_MODES = ("median_roof", "max", "eaves")
WELD_TOLERANCE_M = 1e-3  # footprint vertices closer than this are one vertex
COLLINEAR_TOLERANCE_M = 1e-4  # an outline vertex this close to the line through its neighbours is dropped
MIN_AREA_M2 = 1e-6  # smaller projected triangles are ignored
PROBE_OFFSET_M = 1e-5  # inside/outside probes sit this far beside an edge (thinner slivers are ignored)
MIN_HEIGHT_M = 1e-3
_PAIR_BUDGET = 1_000_000  # edge x vertex pairs per vectorised block (bounds the memory of big buildings)


Lod1ParameterError = ParameterError  # kept as a name for callers; the class lives in semcityloc.errors


@dataclass
class FootprintPolygon:
    """One outline (counter-clockwise seen from above) with its holes (clockwise), (n, 2) float64."""

    outer: np.ndarray
    holes: list[np.ndarray]

    @property
    def area(self) -> float:
        """Area in m² seen from above: the outline's minus its holes' (they wind clockwise)."""
        return ring_area_xy(self.outer) + sum(ring_area_xy(h) for h in self.holes)

    @property
    def perimeter(self) -> float:
        """Length in metres of the outline and every hole's ring."""
        return sum(_ring_length(r) for r in (self.outer, *self.holes))


def derive_lod1(model: CityModel, height: str = "median_roof") -> CityModel:
    """An LoD1 block model with one extruded footprint per building of ``model`` (see module doc)."""
    if height not in HEIGHT_MODES:
        raise unknown_choice("LoD1 height", height, HEIGHT_MODES, Lod1ParameterError)
    if model.num_triangles == 0:
        raise EmptyModelError(f"{model.source or 'city model'}: no triangles to derive LoD1 from")
    stats = ParseStats()
    builder = MeshBuilder(stats)
    for bid in model.building_ids:
        builder.building(bid)
    corners = model.triangle_corners()
    order = np.argsort(model.building_index, kind="stable")
    buildings, starts = np.unique(model.building_index[order], return_index=True)
    extruded = 0
    for b, idx in zip(buildings, np.split(order, starts[1:]), strict=True):
        name = model.building_ids[b] if b < len(model.building_ids) else str(b)
        c, cls = corners[idx], model.classes[idx]
        z0 = float(c[:, :, 2].min())
        z1 = building_height(c, cls, height)
        if z1 - z0 < MIN_HEIGHT_M:
            stats.warnings.append(f"building {name}: no height above its lowest point, skipped")
            continue
        polygons = building_footprint(c, cls, stats, name)
        if not polygons:
            stats.warnings.append(f"building {name}: no footprint area, skipped")
            continue
        for poly in polygons:
            _extrude(builder, model.origin, poly, z0, z1, name)
        extruded += 1
    if not extruded:
        raise EmptyModelError(f"{model.source or 'city model'}: no building gave an LoD1 footprint")
    return builder.build(
        crs=model.crs,
        source_crs=model.source_crs,
        source=f"{model.source} (derived LoD1)",
        origin=model.origin,
    )


# ----------------------------------------------------------------------------------------------- height
def building_height(corners: np.ndarray, classes: np.ndarray, mode: str = "median_roof") -> float:
    """Top height of one building's LoD1 block from its (T, 3, 3) triangle corners (see module doc)."""
    roof = corners[classes == SemanticClass.ROOF]
    if mode == "max" or len(roof) == 0:
        return float(corners[:, :, 2].max())
    if mode == "eaves":
        return float(roof[:, :, 2].min())
    return roof_median_height(roof)


def roof_median_height(corners: np.ndarray) -> float:
    """Area-weighted median height of a set of (T, 3, 3) triangles: the h with half the surface below.

    The surface area below h is exact per triangle (the height over a triangle has a triangular
    distribution), so the answer does not depend on how the roof was triangulated. Bisection on h.
    """
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area = 0.5 * np.linalg.norm(normals, axis=1)
    keep = area > 0
    z = np.sort(corners[keep][:, :, 2], axis=1)
    area = area[keep]
    if len(z) == 0:
        return float(corners[:, :, 2].max())
    za, zb, zc = (z[:, k, None] for k in range(3))
    span, low_span, high_span = zc - za, zb - za, zc - zb
    half = 0.5 * area.sum()

    def below(h: np.ndarray) -> np.ndarray:
        """Roof area below each of the heights ``h`` (k,)."""
        frac = (h[None, :] >= zc).astype(np.float64)
        lower = (h > za) & (h <= zb) & (span > 0)
        upper = (h > zb) & (h < zc) & (span > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            frac = np.where(lower, (h - za) ** 2 / (span * low_span), frac)
            frac = np.where(upper, 1.0 - (zc - h) ** 2 / (span * high_span), frac)
        return area @ frac

    lo, hi = float(za.min()), float(zc.max())
    for _ in range(8):  # 16 sub-intervals per step: 16^-8 of the height range, far below float32 precision
        h = np.linspace(lo, hi, 17)
        k = int(np.clip(np.searchsorted(below(h), half), 1, 16))
        lo, hi = float(h[k - 1]), float(h[k])
    return hi


# -------------------------------------------------------------------------------------------- footprint
def building_footprint(
    corners: np.ndarray, classes: np.ndarray, stats: ParseStats | None = None, name: str = ""
) -> list[FootprintPolygon]:
    """Footprint polygons of one building: the outline of its ground, else of its roof (exact union
    first, then the outline as drawn when the union fails), else the convex hull of all its triangles."""
    stats = stats if stats is not None else ParseStats()
    for cls, label in ((SemanticClass.GROUND, "ground"), (SemanticClass.ROOF, "roof")):
        tri = corners[classes == cls][:, :, :2]
        if not len(tri):
            continue
        polys = outline_of_triangles(tri)
        if polys:
            return polys
        polys = outline_of_triangles(tri, exact=False)
        if polys:
            stats.warnings.append(f"building {name}: the {label} triangles overlap; outline kept as drawn")
            return polys
    hull = convex_hull_polygon(corners[:, :, :2].reshape(-1, 2))
    if hull is not None:
        stats.warnings.append(f"building {name}: footprint from the convex hull of all its triangles")
        return [hull]
    return []


def convex_hull_polygon(xy: np.ndarray) -> FootprintPolygon | None:
    """The convex hull of points as a footprint polygon, or None when the points are degenerate (collinear,
    too few) or the hull is smaller than ``MIN_AREA_M2``; the fallback outline when a building's exact
    outline cannot be traced.
    """
    try:
        hull = ConvexHull(np.unique(np.round(xy, 6), axis=0))
    except (QhullError, ValueError):
        return None
    ring = hull.points[hull.vertices]  # counter-clockwise for 2D input
    return FootprintPolygon(ring, []) if ring_area_xy(ring) > MIN_AREA_M2 else None


def outline_of_triangles(tri_xy: np.ndarray, exact: bool = True) -> list[FootprintPolygon] | None:
    """Outline polygons (with holes) of the union of (T, 3, 2) triangles; None when nothing has area or
    (``exact``) the union of overlapping triangles cannot be made consistent. ``exact=False`` returns
    the rings of the triangles' net boundary instead (overlapping outlines stay overlapping)."""
    pts, tris = _weld(tri_xy.reshape(-1, 2))
    tris = tris.reshape(-1, 3)
    tris = tris[(tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])]
    if len(tris) == 0:
        return None
    p = pts[tris]
    signed = 0.5 * (
        (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
        - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1])
    )
    keep = np.abs(signed) > MIN_AREA_M2
    tris, signed = tris[keep], signed[keep]
    if len(tris) == 0:
        return None
    tris[signed < 0] = tris[signed < 0][:, [0, 2, 1]]
    edges = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    edges = _split_at_vertices(pts, edges)
    boundary = _net_boundary(edges, len(pts))
    if len(boundary) == 0:
        return None
    if exact and not _winding_ok(pts, boundary):  # overlapping triangles: cut the outline of their union
        pts, boundary = _union_boundary(pts, boundary)
        if len(boundary) == 0 or not _balanced(boundary) or not _winding_ok(pts, boundary):
            return None
    rings = []
    for ring in _chain(boundary):
        ring_xy = _drop_collinear(pts[ring])
        if len(ring_xy) >= 3 and abs(ring_area_xy(ring_xy)) > MIN_AREA_M2:
            rings.append(ring_xy)
    return _assemble(rings) or None


def _weld(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge points closer than WELD_TOLERANCE_M: (unique points, index of each input point)."""
    xy = np.asarray(xy, dtype=np.float64)
    pairs = cKDTree(xy).query_pairs(WELD_TOLERANCE_M, output_type="ndarray")
    n = len(xy)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    _, first = np.unique(label, return_index=True)  # labels are 0..k-1
    return xy[first], label


def _split_at_vertices(pts: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Split every edge at the vertices lying on it (T-junctions), keeping its direction."""
    out = []
    chunk = max(1, _PAIR_BUDGET // len(pts))
    for start in range(0, len(edges), chunk):
        e = edges[start : start + chunk]
        a, b = pts[e[:, 0]], pts[e[:, 1]]
        d = b - a
        length2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-30)
        rel = pts[None, :, :] - a[:, None, :]  # (E, V, 2)
        t = np.einsum("evk,ek->ev", rel, d) / length2[:, None]
        perp = rel - t[:, :, None] * d[:, None, :]
        dist2 = np.einsum("evk,evk->ev", perp, perp)
        eps = WELD_TOLERANCE_M / np.sqrt(length2)[:, None]
        on = (dist2 < WELD_TOLERANCE_M**2) & (t > eps) & (t < 1.0 - eps)
        rows = np.flatnonzero(on.any(axis=1))
        plain = np.ones(len(e), dtype=bool)
        plain[rows] = False
        out.append(e[plain])
        for r in rows:
            verts = np.flatnonzero(on[r])
            chain = np.concatenate([[e[r, 0]], verts[np.argsort(t[r, verts])], [e[r, 1]]])
            out.append(np.stack([chain[:-1], chain[1:]], axis=1))
    return np.concatenate(out)


def _net_boundary(edges: np.ndarray, n: int) -> np.ndarray:
    """Directed edges whose uses do not cancel (i->j against j->i), repeated by their multiplicity."""
    lo, hi = np.minimum(edges[:, 0], edges[:, 1]), np.maximum(edges[:, 0], edges[:, 1])
    keep = lo != hi
    lo, hi, sign = lo[keep], hi[keep], np.where(edges[keep, 0] < edges[keep, 1], 1, -1)
    keys, inverse = np.unique(lo.astype(np.int64) * n + hi, return_inverse=True)
    net = np.bincount(inverse, weights=sign, minlength=len(keys)).astype(np.int64)
    nz = net != 0
    a, b, m = keys[nz] // n, keys[nz] % n, net[nz]
    directed = np.where(m[:, None] > 0, np.stack([a, b], 1), np.stack([b, a], 1))
    return np.repeat(directed, np.abs(m), axis=0)


def _crossings(pts: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(k, 2) points where two edges cross properly (not at their end points)."""
    a, d = pts[edges[:, 0]], pts[edges[:, 1]] - pts[edges[:, 0]]
    length = np.maximum(np.linalg.norm(d, axis=1), 1e-30)
    found = []
    chunk = max(1, _PAIR_BUDGET // len(edges))
    for start in range(0, len(edges), chunk):
        ai, di, li = (
            a[start : start + chunk, None],
            d[start : start + chunk, None],
            length[start : start + chunk],
        )
        denom = di[..., 0] * d[None, :, 1] - di[..., 1] * d[None, :, 0]
        ac = a[None] - ai
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (ac[..., 0] * d[None, :, 1] - ac[..., 1] * d[None, :, 0]) / denom
            u = (ac[..., 0] * di[..., 1] - ac[..., 1] * di[..., 0]) / denom
        eps_i, eps_j = (WELD_TOLERANCE_M / li)[:, None], (WELD_TOLERANCE_M / length)[None, :]
        proper = (np.abs(denom) > 1e-12 * li[:, None] * length[None, :]) & (t > eps_i) & (t < 1 - eps_i)
        proper &= (u > eps_j) & (u < 1 - eps_j)
        i, j = np.nonzero(proper)
        found.append(ai[i, 0] + t[i, j, None] * di[i, 0])
    return np.concatenate(found) if found else np.zeros((0, 2))


def _union_boundary(pts: np.ndarray, boundary: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Outline of the union of overlapping triangles from their net boundary: split the boundary edges
    where they cross, then keep each piece that has no triangle on its right (coverage 0 outside)."""
    cross = _crossings(pts, boundary)
    if len(cross):
        pts, label = _weld(np.concatenate([pts, cross]))  # old points stay their clusters' representatives
        boundary = _net_boundary(_split_at_vertices(pts, label[boundary]), len(pts))
    if len(boundary) == 0:
        return pts, boundary
    edges = np.unique(boundary, axis=0)
    a, b = pts[edges[:, 0]], pts[edges[:, 1]]
    d = b - a
    length = np.linalg.norm(d, axis=1)
    left = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.maximum(length, 1e-30)[:, None]
    right = 0.5 * (a + b) - left * np.minimum(PROBE_OFFSET_M, 0.01 * length)[:, None]
    starts, ends = pts[boundary[:, 0]], pts[boundary[:, 1]]
    coverage = np.concatenate(
        [
            _winding(right[k : k + max(1, _PAIR_BUDGET // len(boundary))], starts, ends)
            for k in range(0, len(right), max(1, _PAIR_BUDGET // len(boundary)))
        ]
    )
    return pts, edges[coverage == 0]


def _balanced(edges: np.ndarray) -> bool:
    """Every vertex has as many boundary edges leaving as arriving (the edges form closed rings)."""
    n = int(edges.max()) + 1
    return bool(np.array_equal(np.bincount(edges[:, 0], minlength=n), np.bincount(edges[:, 1], minlength=n)))


def _winding(points: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Winding number of each point with respect to a set of directed edges (Sunday's rule)."""
    px, py = points[:, 0:1], points[:, 1:2]
    ax, ay, bx, by = starts[:, 0], starts[:, 1], ends[:, 0], ends[:, 1]
    is_left = (bx - ax) * (py - ay) - (px - ax) * (by - ay)
    up = (ay <= py) & (by > py) & (is_left > 0)
    down = (ay > py) & (by <= py) & (is_left < 0)
    return up.sum(axis=1) - down.sum(axis=1)


def _winding_ok(pts: np.ndarray, boundary: np.ndarray) -> bool:
    """Every boundary edge has the union's interior (winding 1) just to its left and simple multiplicity."""
    keys = boundary[:, 0].astype(np.int64) * len(pts) + boundary[:, 1]
    if len(np.unique(keys)) != len(keys):
        return False
    a, b = pts[boundary[:, 0]], pts[boundary[:, 1]]
    d = b - a
    length = np.linalg.norm(d, axis=1)
    left = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.maximum(length, 1e-30)[:, None]
    probe = 0.5 * (a + b) + left * np.minimum(PROBE_OFFSET_M, 0.01 * length)[:, None]
    chunk = max(1, _PAIR_BUDGET // len(a))
    for start in range(0, len(probe), chunk):
        if np.any(_winding(probe[start : start + chunk], a, b) != 1):
            return False
    return True


def _chain(boundary: np.ndarray) -> list[list[int]]:
    """Chain directed boundary edges into closed vertex rings; rings touching themselves are split."""
    outgoing: dict[int, list[int]] = {}
    for k, s in enumerate(boundary[:, 0].tolist()):
        outgoing.setdefault(s, []).append(k)
    used = np.zeros(len(boundary), dtype=bool)
    rings: list[list[int]] = []
    for first in range(len(boundary)):
        if used[first]:
            continue
        walk = [int(boundary[first, 0])]
        k = first
        while True:
            used[k] = True
            nxt = int(boundary[k, 1])
            if nxt == walk[0]:
                break
            walk.append(nxt)
            options = [e for e in outgoing.get(nxt, []) if not used[e]]
            if not options:  # an open chain: cannot happen for a balanced boundary; drop it
                walk = []
                break
            k = options[0]
        rings.extend(_split_pinches(walk))
    return [r for r in rings if len(r) >= 3]


def _split_pinches(walk: list[int]) -> list[list[int]]:
    """Cut a closed walk that visits a vertex twice into simple loops."""
    loops: list[list[int]] = []
    stack: list[int] = []
    position: dict[int, int] = {}
    for v in walk:
        if v in position:
            start = position[v]
            loop = stack[start:]
            for u in loop[1:]:
                del position[u]
            stack = stack[: start + 1]
            loops.append(loop)
        else:
            position[v] = len(stack)
            stack.append(v)
    loops.append(stack)
    return loops


def _drop_collinear(ring: np.ndarray) -> np.ndarray:
    """Remove vertices lying on the straight line between their neighbours (repeat until stable)."""
    while len(ring) > 3:
        prev, nxt = np.roll(ring, 1, axis=0), np.roll(ring, -1, axis=0)
        span = nxt - prev
        span_len = np.linalg.norm(span, axis=1)
        cross = span[:, 0] * (ring[:, 1] - prev[:, 1]) - span[:, 1] * (ring[:, 0] - prev[:, 0])
        forward = np.einsum("ij,ij->i", ring - prev, nxt - ring) > 0
        straight = (np.abs(cross) <= COLLINEAR_TOLERANCE_M * np.maximum(span_len, 1e-30)) & forward
        if not straight.any():
            break
        # never drop two neighbours at once (keeps the removal error within the tolerance)
        drop = straight & ~np.roll(straight, 1)
        if not drop.any():
            drop = np.zeros(len(ring), dtype=bool)
            drop[np.flatnonzero(straight)[0]] = True
        ring = ring[~drop]
    return ring


def _ring_length(ring: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1)))


def _assemble(rings: list[np.ndarray]) -> list[FootprintPolygon]:
    """Counter-clockwise rings are outlines, clockwise ones holes of the smallest outline around them."""
    outers = [FootprintPolygon(r, []) for r in rings if ring_area_xy(r) > 0]
    outers.sort(key=lambda p: ring_area_xy(p.outer))
    for hole in (r for r in rings if ring_area_xy(r) < 0):
        a, b = hole[0], hole[1]
        d = b - a
        probe = (
            0.5 * (a + b)
            + np.array([-d[1], d[0]]) / np.linalg.norm(d) * min(PROBE_OFFSET_M, 0.01 * np.linalg.norm(d))
        )[None]
        for poly in outers:  # smallest first
            if _winding(probe, poly.outer, np.roll(poly.outer, -1, axis=0))[0] == 1:
                poly.holes.append(hole)
                break
    return outers


# --------------------------------------------------------------------------------------------- extrude
def _extrude(
    builder: MeshBuilder, origin: np.ndarray, poly: FootprintPolygon, z0: float, z1: float, name: str
) -> None:
    """Walls (two triangles per vertical quad), flat roof and ground of one footprint polygon, in world
    coordinates."""
    quads = []
    for ring in (poly.outer, *poly.holes):  # holes run clockwise: their walls face into the courtyard
        p, q = ring, np.roll(ring, -1, axis=0)
        quads.append(np.stack([p, q, q, p], axis=1))  # (n, 4, 2): bottom p, bottom q, top q, top p
    xy = np.concatenate(quads)
    z = np.array([z0, z0, z1, z1])
    corners = np.concatenate([xy, np.broadcast_to(z[None, :, None], (len(xy), 4, 1))], axis=2) + origin
    first = 4 * np.arange(len(xy))[:, None]
    tris = np.concatenate([first + [0, 1, 2], first + [0, 2, 3]])  # two triangles per wall quad
    wall, index = np.full(len(tris), int(SemanticClass.WALL)), np.full(len(tris), builder.building(name))
    builder.add_mesh(corners.reshape(-1, 3), tris, wall, index, 1)

    def lift(ring: np.ndarray, z: float) -> np.ndarray:
        return np.column_stack([ring, np.full(len(ring), z)]) + origin

    builder.add_polygon(
        lift(poly.outer, z1), [lift(h, z1) for h in poly.holes], int(SemanticClass.ROOF), name, 1
    )
    builder.add_polygon(
        lift(poly.outer[::-1], z0),
        [lift(h[::-1], z0) for h in poly.holes],
        int(SemanticClass.GROUND),
        name,
        1,
    )

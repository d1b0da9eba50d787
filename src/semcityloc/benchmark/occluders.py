"""The simulated "reality" a benchmark drone sees: the city model plus what no LoD model describes.

Why: a query rendered from the very map it is localized against would be a perfect match. Real UAV
images differ from any LoD model in three ways, simulated here once per simulator (``build_reality``,
deterministic from the seed):

1. Model errors. Each building of the reality model is shifted in x, y by a random vector of length
   uniform in [0, ``shift_xy_max_m``] (0.3 m) and its height (top minus bottom) changed by a signed
   amount of magnitude uniform in [0, ``height_change_max_m``] (0.5 m; the building is stretched
   vertically about its lowest point, so it stays on the ground).
2. Roof structures missing from LoD2 (chimneys, AC boxes, stair / lift housings on flat roofs;
   chimneys and dormers on sloped roofs), about one per ``roof_structure_m2`` (80 m²) of roof. They ARE
   building parts, so they keep building semantics, as a LoD3 model would give them (CityGML
   BuildingInstallation surfaces): their tops are ROOF and their sides WALL, and they belong to their
   host building. Their bases are sunk 0.3 m into the roof.
3. Occluders: trees 4-15 m tall (a trunk with an ellipsoid crown, or a cone for 30 % conifers) in the
   open ground between buildings, about one per ``tree_m2`` (300 m²) of open ground, at least 0.7 x the
   crown radius from a facade (crowns may overhang streets and facades a little); cars (boxes
   3.8-5.0 x 1.7-2.0 x 1.4-1.9 m) 1.5-15 m from a facade, parked parallel to it, about one per
   ``car_m2`` (300 m²) of that band. Both are BACKGROUND (class 0): a perfect segmentation labels them
   background, while their depth still comes from the render (a depth network sees trees).

The reality's ground is the terrain TIN of ``semcityloc.render.terrain`` built from the perturbed
buildings and added as an explicit GROUND mesh (the renderer runs with ``ground=False``), so occluders
do not change the terrain. Open ground is found on a ``grid_cell_m`` raster of the building footprints
(every non-vertical building triangle projected to x, y) covering the buildings' extent plus
``margin_m``; a roof structure is kept only if its four corners lie on its host building's cells.

Everything is in the MAP model's local frame (a reality model with another origin is shifted in float64
first), rounded to the millimetre: numpy's vectorised sin / cos may differ by an ulp between CPUs (SIMD
code paths), and rounding keeps the rendered reality bit-identical on every machine.
``RealityScene.terrain_height`` gives the ground height at any x, y.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from scipy.spatial import Delaunay, cKDTree

from semcityloc.citymodel.model import CityModel
from semcityloc.classes import BUILDING_CLASSES, SemanticClass
from semcityloc.errors import CRSError, EmptyModelError
from semcityloc.render import Renderer
from semcityloc.render.terrain import build_terrain

TERRAIN_ID, TREES_ID, CARS_ID = "__terrain__", "__trees__", "__cars__"
_MAX_RASTER_PAIRS = 4_000_000  # (triangle, cell) pairs per vectorised rasterisation chunk


@dataclass(frozen=True)
class RealityParams:
    """Magnitudes of the reality's differences from the map (module docstring)."""

    shift_xy_max_m: float = 0.3
    height_change_max_m: float = 0.5
    roof_structure_m2: float = 80.0  # one roof structure per this much roof area (0 = none)
    tree_m2: float = 300.0  # one tree per this much open ground (0 = none)
    car_m2: float = 300.0  # one car per this much ground 1.5-15 m from a facade (0 = none)
    tree_height_m: tuple[float, float] = (4.0, 15.0)
    car_band_m: tuple[float, float] = (1.5, 15.0)
    grid_cell_m: float = 0.5
    margin_m: float = 20.0


@dataclass
class RealityScene:
    """The rendered reality (module docstring). ``model`` holds buildings, roof structures, terrain and
    occluders in the map's local frame; ``renderer`` draws it (numba engine, no extra terrain)."""

    model: CityModel
    renderer: Renderer
    terrain_height: TerrainHeight
    building_shift_xy: np.ndarray  # (B, 2) per reality building
    building_height_change: np.ndarray  # (B,)
    counts: dict[str, int] = field(default_factory=dict)

    @property
    def occluder_triangles(self) -> np.ndarray:
        """(T,) bool: the trees' and cars' triangles of ``model``."""
        return self.model.classes == SemanticClass.BACKGROUND


class TerrainHeight:
    """Ground height (local z) at x, y: linear on a Delaunay triangulation of the terrain TIN's vertices
    (the TIN is itself a Delaunay triangulation of them), nearest vertex outside it.

    Points are located by a vectorised walk from a triangle at their nearest vertex (no LAPACK: scipy's
    ``find_simplex`` builds its barycentric transforms with one LAPACK call per triangle, which takes
    seconds on a busy multi-threaded BLAS)."""

    MAX_WALK = 500

    def __init__(self, vertices: np.ndarray):
        v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        if len(v) < 3:
            raise EmptyModelError("no terrain: the model has no building footprints to lay a ground under")
        self._xy = v[:, :2]
        self._z = v[:, 2]
        tri = Delaunay(self._xy)
        self._simplices = tri.simplices
        self._neighbors = tri.neighbors  # [i, k]: the triangle opposite vertex k of triangle i (-1: none)
        self._tree = cKDTree(self._xy)
        start = np.zeros(len(v), dtype=np.int64)
        start[self._simplices.reshape(-1)] = np.repeat(np.arange(len(self._simplices)), 3)
        self._start = start

    def _barycentric(self, t: np.ndarray, p: np.ndarray) -> np.ndarray:
        c = self._xy[self._simplices[t]]  # (n, 3, 2)
        e1, e2, q = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0], p - c[:, 0]
        den = e1[:, 0] * e2[:, 1] - e2[:, 0] * e1[:, 1]
        l1 = (q[:, 0] * e2[:, 1] - e2[:, 0] * q[:, 1]) / den
        l2 = (e1[:, 0] * q[:, 1] - q[:, 0] * e1[:, 1]) / den
        return np.column_stack([1.0 - l1 - l2, l1, l2])

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64)
        flat = xy.reshape(-1, 2)
        _, nearest = self._tree.query(flat)
        z = self._z[nearest].astype(np.float64)
        t = self._start[nearest]
        todo = np.arange(len(flat))
        for _ in range(self.MAX_WALK):
            if len(todo) == 0:
                break
            bary = self._barycentric(t[todo], flat[todo])
            k = np.argmin(bary, axis=1)
            inside = bary[np.arange(len(todo)), k] >= -1e-12
            hit = todo[inside]
            z[hit] = (bary[inside] * self._z[self._simplices[t[hit]]]).sum(1)
            nxt = self._neighbors[t[todo[~inside]], k[~inside]]
            walking = todo[~inside]
            t[walking] = np.maximum(nxt, 0)
            todo = walking[nxt >= 0]  # a step out of the hull: keep the nearest vertex's height
        return z.reshape(xy.shape[:-1])


# ------------------------------------------------------------------------------------------ meshes
def _box_mesh(centre: np.ndarray, half: np.ndarray, angle: np.ndarray, z0: np.ndarray, z1: np.ndarray):
    """N oriented boxes without bottoms: vertices (8N, 3), triangles (10N, 3), is_top (10N,) bool."""
    n = len(centre)
    sx = np.array([-1, 1, 1, -1], dtype=np.float64)
    sy = np.array([-1, -1, 1, 1], dtype=np.float64)
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    lx, ly = sx[None] * half[:, :1], sy[None] * half[:, 1:2]
    x = centre[:, :1] + c * lx - s * ly
    y = centre[:, 1:2] + s * lx + c * ly
    ring = np.stack([x, y], -1)  # (N, 4, 2)
    bottom = np.concatenate([ring, np.broadcast_to(z0[:, None, None], (n, 4, 1))], -1)
    top = np.concatenate([ring, np.broadcast_to(z1[:, None, None], (n, 4, 1))], -1)
    verts = np.concatenate([bottom, top], 1)  # (N, 8, 3): 0-3 bottom, 4-7 top (counter-clockwise)
    faces = [(4, 5, 6), (4, 6, 7)]
    for k in range(4):
        a, b = k, (k + 1) % 4
        faces += [(a, b, b + 4), (a, b + 4, a + 4)]
    f = np.array(faces, dtype=np.int64)
    tris = (f[None] + 8 * np.arange(n)[:, None, None]).reshape(-1, 3)
    is_top = np.tile(np.array([True, True] + [False] * 8), n)
    return verts.reshape(-1, 3), tris, is_top


def _unit_ellipsoid(n_az: int = 8, n_lat: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """A closed UV sphere of radius 1: poles plus ``n_lat`` rings of ``n_az`` vertices."""
    lat = np.linspace(-np.pi / 2, np.pi / 2, n_lat + 2)[1:-1]
    az = np.arange(n_az) * 2 * np.pi / n_az
    ring = np.stack(
        [
            np.cos(lat)[:, None] * np.cos(az)[None],
            np.cos(lat)[:, None] * np.sin(az)[None],
            np.sin(lat)[:, None] * np.ones(n_az)[None],
        ],
        -1,
    ).reshape(-1, 3)
    verts = np.concatenate([[[0, 0, -1.0]], ring, [[0, 0, 1.0]]])
    top = len(verts) - 1
    faces = []
    for j in range(n_az):
        k = (j + 1) % n_az
        faces.append((0, 1 + k, 1 + j))
        faces.append((top, 1 + (n_lat - 1) * n_az + j, 1 + (n_lat - 1) * n_az + k))
        for r in range(n_lat - 1):
            a, b = 1 + r * n_az + j, 1 + r * n_az + k
            faces += [(a, b, b + n_az), (a, b + n_az, a + n_az)]
    return verts, np.array(faces, dtype=np.int64)


def _unit_cone(n_az: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Cone of base radius 1 from z = 0 to apex z = 1 (side only: its base is never seen from above)."""
    az = np.arange(n_az) * 2 * np.pi / n_az
    verts = np.concatenate([np.stack([np.cos(az), np.sin(az), np.zeros(n_az)], 1), [[0, 0, 1.0]]])
    faces = [(j, (j + 1) % n_az, n_az) for j in range(n_az)]
    return verts, np.array(faces, dtype=np.int64)


def _instances(
    unit_v: np.ndarray, unit_f: np.ndarray, scale: np.ndarray, offset: np.ndarray, angle: np.ndarray
):
    """N copies of a unit mesh: scaled (N, 3), turned about z by ``angle``, moved by ``offset`` (N, 3)."""
    n = len(scale)
    v = unit_v[None] * scale[:, None, :]
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    x = c * v[..., 0] - s * v[..., 1]
    y = s * v[..., 0] + c * v[..., 1]
    v = np.stack([x, y, v[..., 2]], -1) + offset[:, None, :]
    f = unit_f[None] + len(unit_v) * np.arange(n)[:, None, None]
    return v.reshape(-1, 3), f.reshape(-1, 3)


# ------------------------------------------------------------------------------------------ raster
@dataclass
class FootprintGrid:
    """Building index per ``cell`` x ``cell`` m cell (-1 = open), cell (i, j) centred at
    ``lo + ((j + 0.5) cell, (i + 0.5) cell)``."""

    ids: np.ndarray  # (ny, nx) int32
    lo: np.ndarray  # (2,) float64
    cell: float

    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(row, col, inside-grid mask) of points (N, 2)."""
        ij = np.floor((np.asarray(xy) - self.lo) / self.cell).astype(np.int64)
        ny, nx = self.ids.shape
        ok = (ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)
        return np.clip(ij[:, 1], 0, ny - 1), np.clip(ij[:, 0], 0, nx - 1), ok

    def centres(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        return self.lo + (np.stack([cols, rows], -1) + 0.5) * self.cell


def footprint_grid(corners: np.ndarray, values: np.ndarray, lo: np.ndarray, hi: np.ndarray, cell: float):
    """Rasterise triangles (T, 3, 3) projected to x, y: each cell whose centre is in a triangle gets that
    triangle's value (later triangles win). Steep triangles (walls: |n_z| < 0.2) are skipped: they add
    slivers along the roof outlines at the cost of many cells."""
    lo = np.asarray(lo, dtype=np.float64)
    nx = max(int(np.ceil((hi[0] - lo[0]) / cell)), 1)
    ny = max(int(np.ceil((hi[1] - lo[1]) / cell)), 1)
    ids = np.full((ny, nx), -1, dtype=np.int32)
    p = (corners[:, :, :2] - lo) / cell - 0.5  # cell-centre units: centre of cell j at j
    area2 = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 1, 1] - p[:, 0, 1]) * (
        p[:, 2, 0] - p[:, 0, 0]
    )
    n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    steep = np.abs(n[:, 2]) < 0.2 * np.linalg.norm(n, axis=1)
    keep = (np.abs(area2) > 1e-9) & ~steep
    p, vals, sign = p[keep], np.asarray(values)[keep], np.sign(area2[keep])
    j0 = np.clip(np.ceil(p[:, :, 0].min(1)), 0, nx).astype(np.int64)
    j1 = np.clip(np.floor(p[:, :, 0].max(1)), -1, nx - 1).astype(np.int64)
    i0 = np.clip(np.ceil(p[:, :, 1].min(1)), 0, ny).astype(np.int64)
    i1 = np.clip(np.floor(p[:, :, 1].max(1)), -1, ny - 1).astype(np.int64)
    nj, ni = np.maximum(j1 - j0 + 1, 0), np.maximum(i1 - i0 + 1, 0)
    counts = nj * ni
    start = 0
    while start < len(p):
        cum = np.cumsum(counts[start:])
        stop = start + max(int(np.searchsorted(cum, _MAX_RASTER_PAIRS)), 1)
        sl = slice(start, stop)
        rep = np.repeat(np.arange(start, stop), counts[sl])
        if len(rep):
            first = np.repeat(np.cumsum(counts[sl]) - counts[sl], counts[sl])
            k = np.arange(len(rep)) - first
            jj = j0[rep] + k % nj[rep]
            ii = i0[rep] + k // nj[rep]
            inside = np.ones(len(rep), dtype=bool)
            for e in range(3):
                a, b = p[rep, e], p[rep, (e + 1) % 3]
                edge = (b[:, 0] - a[:, 0]) * (ii - a[:, 1]) - (b[:, 1] - a[:, 1]) * (jj - a[:, 0])
                inside &= edge * sign[rep] >= -1e-9
            ids[ii[inside], jj[inside]] = vals[rep[inside]]
        start = stop
    return FootprintGrid(ids, lo, float(cell))


# ------------------------------------------------------------------------------------------ pieces
def _in_map_frame(map_model: CityModel, reality: CityModel) -> np.ndarray:
    """Triangle corners (T, 3, 3) float64 of ``reality`` in the map's local frame."""
    if map_model.crs is not None and reality.crs is not None and not map_model.crs.equals(reality.crs):
        raise CRSError("the reality model and the map model are in different CRSs")
    shift = np.asarray(reality.origin, dtype=np.float64) - map_model.origin
    return reality.vertices[reality.triangles].astype(np.float64) + shift


def perturb_buildings(
    corners: np.ndarray,
    building: np.ndarray,
    n_buildings: int,
    params: RealityParams,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-building xy shift and height change (module docstring, item 1): (corners, shift, dh)."""
    r = rng.uniform(0.0, params.shift_xy_max_m, n_buildings)
    phi = rng.uniform(0.0, 2 * np.pi, n_buildings)
    shift = np.stack([r * np.cos(phi), r * np.sin(phi)], 1)
    dh = rng.uniform(0.0, params.height_change_max_m, n_buildings) * rng.choice([-1.0, 1.0], n_buildings)
    z = corners[:, :, 2]
    base = np.full(n_buildings, np.inf)
    top = np.full(n_buildings, -np.inf)
    np.minimum.at(base, building, z.min(1))
    np.maximum.at(top, building, z.max(1))
    height = top - base
    factor = np.where(height > 1.0, (height + dh) / np.where(height > 1.0, height, 1.0), 1.0)
    out = corners.copy()
    out[:, :, :2] += shift[building][:, None, :]
    b0 = base[building][:, None]
    out[:, :, 2] = b0 + (z - b0) * factor[building][:, None]
    return out, shift, np.where(height > 1.0, dh, 0.0)


def roof_structures(
    corners: np.ndarray,
    classes: np.ndarray,
    building: np.ndarray,
    grid: FootprintGrid,
    params: RealityParams,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Boxes on the roofs (module docstring, item 2): vertices, triangles, classes, building per triangle."""
    empty = (np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.uint8), np.zeros(0, np.int64))
    roof = np.flatnonzero(classes == SemanticClass.ROOF)
    if params.roof_structure_m2 <= 0 or len(roof) == 0:
        return empty
    c = corners[roof]
    normal = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    area = 0.5 * np.linalg.norm(normal, axis=1)
    unit = normal / np.maximum(2 * area, 1e-12)[:, None]
    up = unit[:, 2] > 0.2
    if not up.any():
        return empty
    roof, c, area, unit = roof[up], c[up], area[up], unit[up]
    n = int(round(area.sum() / params.roof_structure_m2))
    if n == 0:
        return empty
    pick = rng.choice(len(roof), n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s1 = np.sqrt(r1)
    pt = (
        (1 - s1)[:, None] * c[pick, 0]
        + (s1 * (1 - r2))[:, None] * c[pick, 1]
        + (s1 * r2)[:, None] * c[pick, 2]
    )
    nrm = unit[pick]
    flat = nrm[:, 2] > 0.97
    u = rng.random(n)
    # kinds: 0 chimney, 1 AC box, 2 stair/lift housing, 3 dormer
    kind = np.where(flat, np.where(u < 0.5, 1, np.where(u < 0.7, 0, 2)), np.where(u < 0.6, 0, 3))
    lo_size = np.array([[0.5, 0.5], [1.0, 0.8], [2.5, 2.5], [1.5, 2.0]])
    hi_size = np.array([[1.0, 1.0], [2.5, 2.0], [4.5, 4.5], [3.0, 3.0]])
    size = rng.uniform(lo_size[kind], hi_size[kind])  # (across slope, along slope)
    lo_h = np.array([0.8, 0.6, 2.2, 0.1])
    hi_h = np.array([2.0, 1.8, 3.0, 0.1])
    extra = rng.uniform(lo_h[kind], hi_h[kind])
    # Orientation: along the slope on sloped roofs, along the triangle's longest edge on flat ones.
    slope_dir = np.arctan2(nrm[:, 1], nrm[:, 0])
    e = c[pick][:, [1, 2, 0]] - c[pick]
    longest = np.argmax(np.linalg.norm(e[:, :, :2], axis=2), axis=1)
    edge = e[np.arange(n), longest]
    angle = np.where(flat, np.arctan2(edge[:, 1], edge[:, 0]), slope_dir - np.pi / 2)

    half = size / 2
    ca, sa = np.cos(angle)[:, None], np.sin(angle)[:, None]
    sx, sy = np.array([-1, 1, 1, -1.0]), np.array([-1, -1, 1, 1.0])
    lx, ly = sx[None] * half[:, :1], sy[None] * half[:, 1:2]
    cx = pt[:, :1] + ca * lx - sa * ly
    cy = pt[:, 1:2] + sa * lx + ca * ly
    host = building[roof[pick]]
    ok = np.ones(n, dtype=bool)
    for k in range(4):
        rows, cols, inside = grid.cells(np.stack([cx[:, k], cy[:, k]], 1))
        ok &= inside & (grid.ids[rows, cols] == host)
    # Roof plane height at the four corners (the plane of the picked triangle).
    p0 = c[pick, 0]
    zc = p0[:, 2:3] - (nrm[:, :1] * (cx - p0[:, :1]) + nrm[:, 1:2] * (cy - p0[:, 1:2])) / nrm[:, 2:3]
    z0 = zc.min(1) - 0.3
    z1 = zc.max(1) + extra
    if not ok.any():
        return empty
    v, t, is_top = _box_mesh(pt[ok, :2], half[ok], angle[ok], z0[ok], z1[ok])
    cls = np.where(is_top, SemanticClass.ROOF, SemanticClass.WALL).astype(np.uint8)
    return v, t, cls, np.repeat(host[ok], 10)


def _open_ground_samples(
    dist: np.ndarray, eligible: np.ndarray, grid: FootprintGrid, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """n candidate points uniformly on the eligible cells: (xy (n, 2), distance to a facade (n,))."""
    cells = np.flatnonzero(eligible.reshape(-1))
    if len(cells) == 0 or n == 0:
        return np.zeros((0, 2)), np.zeros(0)
    pick = cells[rng.integers(0, len(cells), n)]
    rows, cols = np.divmod(pick, eligible.shape[1])
    xy = grid.centres(rows, cols) + rng.uniform(-0.5, 0.5, (n, 2)) * grid.cell
    return xy, dist.reshape(-1)[pick]


def trees(
    dist: np.ndarray,
    grid: FootprintGrid,
    terrain: TerrainHeight,
    params: RealityParams,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Tree meshes on open ground (module docstring, item 3): vertices, triangles, number of trees."""
    open_cells = dist > 0
    n = int(round(open_cells.sum() * grid.cell**2 / params.tree_m2)) if params.tree_m2 > 0 else 0
    if n == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), 0
    xy, d = _open_ground_samples(dist, open_cells, grid, 3 * n, rng)
    h = rng.uniform(*params.tree_height_m, len(xy))
    conifer = rng.random(len(xy)) < 0.3
    radius = np.clip(h * rng.uniform(0.25, 0.45, len(xy)), 1.2, 5.0)
    radius = np.where(conifer, np.clip(h * rng.uniform(0.18, 0.28, len(xy)), 1.0, 3.5), radius)
    angle = rng.uniform(0, 2 * np.pi, len(xy))
    keep = np.flatnonzero(d >= 0.7 * radius)[:n]
    xy, h, conifer, radius, angle = xy[keep], h[keep], conifer[keep], radius[keep], angle[keep]
    z = terrain(xy)
    crown_half = np.where(conifer, 0.0, h * rng.uniform(0.3, 0.4, len(keep)))
    trunk_top = np.where(conifer, z + 0.25 * h, z + h - crown_half)
    trunk_r = np.full(len(keep), 0.2)
    parts_v, parts_f, count = [], [], 0

    def add(v, f):
        nonlocal count
        parts_v.append(v)
        parts_f.append(f + count)
        count += len(v)

    tv, tt, _ = _box_mesh(xy, np.stack([trunk_r, trunk_r], 1), angle, z - 0.2, trunk_top + 0.3)
    add(tv, tt)
    dec = ~conifer
    if dec.any():
        uv, uf = _unit_ellipsoid()
        scale = np.stack([radius[dec], radius[dec], crown_half[dec]], 1)
        centre = np.column_stack([xy[dec], (z + h - crown_half)[dec]])
        add(*_instances(uv, uf, scale, centre, angle[dec]))
    if conifer.any():
        uv, uf = _unit_cone()
        scale = np.stack([radius[conifer], radius[conifer], 0.75 * h[conifer]], 1)
        base = np.column_stack([xy[conifer], (z + 0.25 * h)[conifer]])
        add(*_instances(uv, uf, scale, base, angle[conifer]))
    return np.concatenate(parts_v), np.concatenate(parts_f), len(keep)


def cars(
    dist: np.ndarray,
    grid: FootprintGrid,
    terrain: TerrainHeight,
    params: RealityParams,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Car boxes near facades, parallel to them (module docstring, item 3)."""
    lo, hi = params.car_band_m
    band = (dist >= lo) & (dist <= hi)
    n = int(round(band.sum() * grid.cell**2 / params.car_m2)) if params.car_m2 > 0 else 0
    if n == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), 0
    xy, _ = _open_ground_samples(dist, band, grid, n, rng)
    gy, gx = np.gradient(dist)
    rows, cols, _ = grid.cells(xy)
    facing = np.arctan2(gy[rows, cols], gx[rows, cols])  # away from the nearest facade
    angle = facing + np.pi / 2 + rng.normal(0.0, 0.05, n)
    size = np.stack([rng.uniform(3.8, 5.0, n), rng.uniform(1.7, 2.0, n)], 1)
    z = terrain(xy)
    v, t, _ = _box_mesh(xy, size / 2, angle, z - 0.1, z + rng.uniform(1.4, 1.9, n))
    return v, t, n


# ------------------------------------------------------------------------------------------ public
def build_reality(
    map_model: CityModel,
    reality_model: CityModel | None = None,
    seed: int = 0,
    params: RealityParams | None = None,
) -> RealityScene:
    """The reality scene of ``reality_model`` (default: the map itself) in the map's local frame.

    Deterministic: the same models, ``seed`` and ``params`` give the same scene on any machine.
    """
    params = params or RealityParams()
    reality = reality_model if reality_model is not None else map_model
    rng = np.random.default_rng([int(seed), 0x5EA1])  # the reality's own stream (queries use 3+ keys)
    corners = _in_map_frame(map_model, reality)
    building = reality.building_index.astype(np.int64)
    n_b = len(reality.building_ids)
    corners, shift, dh = perturb_buildings(
        corners, building, n_b, params, np.random.default_rng([int(seed), 0x5EA1, 1])
    )
    classes = reality.classes
    is_building = np.isin(classes, BUILDING_CLASSES)
    if not is_building.any():
        raise EmptyModelError("the reality model has no walls or roofs: nothing to fly over")

    def model_of(
        c: np.ndarray, cls: np.ndarray, b: np.ndarray, lods: np.ndarray, ids: list[str]
    ) -> CityModel:
        return CityModel(
            origin=map_model.origin.copy(),
            vertices=c.reshape(-1, 3).astype(np.float32),
            triangles=np.arange(3 * len(c)).reshape(-1, 3),
            classes=cls,
            building_index=b,
            lods=lods,
            building_ids=ids,
            crs=map_model.crs,
            source_crs=reality.source_crs,
            source=f"simulated reality of {reality.source or 'the map'}",
        )

    buildings_only = model_of(corners, classes, building, reality.lods, list(reality.building_ids))
    tv, tt = build_terrain(buildings_only)
    if len(tt) == 0:
        raise EmptyModelError(
            "no terrain: the reality model has no building footprints to lay a ground under"
        )
    terrain = TerrainHeight(tv)

    bc = corners[is_building]
    lo = bc[:, :, :2].reshape(-1, 2).min(0) - params.margin_m
    hi = bc[:, :, :2].reshape(-1, 2).max(0) + params.margin_m
    grid = footprint_grid(bc, building[is_building], lo, hi, params.grid_cell_m)
    built = grid.ids >= 0
    dist = ndimage.distance_transform_edt(~built) * grid.cell if built.any() else np.full(built.shape, 1e9)

    rv, rt, rcls, rb = roof_structures(corners, classes, building, grid, params, rng)
    trv, trt, n_trees = trees(dist, grid, terrain, params, rng)
    cv, ct, n_cars = cars(dist, grid, terrain, params, rng)

    ids = list(reality.building_ids) + [TERRAIN_ID, TREES_ID, CARS_ID]
    pieces = [
        (corners, classes, building, reality.lods),
        (tv[tt], np.full(len(tt), SemanticClass.GROUND), np.full(len(tt), n_b), np.zeros(len(tt))),
        (rv[rt], rcls, rb, np.zeros(len(rt))),
        (trv[trt], np.zeros(len(trt)), np.full(len(trt), n_b + 1), np.zeros(len(trt))),
        (cv[ct], np.zeros(len(ct)), np.full(len(ct), n_b + 2), np.zeros(len(ct))),
    ]
    # Millimetre coordinates (module docstring): the same scene on every machine.
    model = model_of(
        np.round(np.concatenate([p[0].reshape(-1, 3, 3) for p in pieces]), 3),
        np.concatenate([p[1] for p in pieces]).astype(np.uint8),
        np.concatenate([p[2] for p in pieces]).astype(np.int32),
        np.concatenate([p[3] for p in pieces]).astype(np.uint8),
        ids,
    )
    renderer = Renderer(model, engine="numba", ground=False)
    counts = {
        "buildings": int(n_b),
        "roof_structures": int(len(rt) // 10),
        "trees": int(n_trees),
        "cars": int(n_cars),
        "occluder_triangles": int(len(trt) + len(ct)),
        "triangles": int(model.num_triangles),
    }
    return RealityScene(model, renderer, terrain, shift, np.asarray(dh), counts)

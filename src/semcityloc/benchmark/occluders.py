"""The simulated "reality" a benchmark drone sees: the city model plus what no LoD model describes.

Why: a query rendered from the very map it is localized against would be a perfect match. Real UAV
images differ from any LoD model in the ways below, simulated here once per simulator (``build_reality``,
deterministic from the seed; applied in the order 1, 6 (missing), 5, 4, 7, 6 (new), 2, 3, 5 (dormers)):

1. Model errors. Each building of the reality model is shifted in x, y by a random vector of length
   uniform in [0, ``shift_xy_max_m``] (0.3 m) and its height (top minus bottom) changed by a signed
   amount of magnitude uniform in [0, ``height_change_max_m``] (0.5 m; the building is stretched
   vertically about its lowest point, so it stays on the ground). With ``model_error_spread="normal"``
   both magnitudes are |N(0, max / 3)| clipped to the max instead (most buildings off by little, a tail
   up to the bound: the way cadastral footprints and LiDAR heights err).
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
   background, while their depth still comes from the render (a depth network sees trees). Trees are
   ``tree_height_m`` tall and stand ``tree_facade_clearance`` x their crown radius or more from a facade
   (0.2: the crowns overhang facades and low roofs).

Reality != map (issue 12; every knob off by default, ``REALISTIC_REALITY`` turns them on). Each draws
from its own generator (keys ``[seed, 0x5EA1, k]``, k = 2..7) and only when on, so a knob that is off
leaves the scene exactly as it was without it:

4. Roof overhangs (``overhang_m``, e.g. 0.3-1 m): per building an amount o uniform in the range; the roof
   outline moves o outward horizontally while the walls stay at the footprint (``overhang_roofs``: the
   roof's boundary edges that lie on its walls are offset by o, or by 0 along a wall shared with another
   building; corners take the miter, capped at 2 o; each moved vertex follows its roof planes, so an eave
   drops by o x the slope). With ``overhang_flat_roofs=False`` a building whose roof is mostly flat
   (more than half its area within 10 deg of horizontal) gets none: flat roofs end in parapets, not
   eaves. ``RealityScene.building_overhang_m``.
5. Roof shapes that differ (``roof_change_fraction`` of the buildings with a roof, e.g. 0.15, drawn among
   the eligible ones): a flat roof (>= 95 % of its area flat, one level) whose footprint fills >= 85 % of
   its minimum-area oriented box gets a gable (60 %) or hip roof over that box, ridge 2-5 m above the old
   roof, slopes ROOF, gable ends WALL; a sloped roof (< 50 % flat, rising <= 8 m) is flattened to its
   eaves (its lowest roof point: every vertex of the building is clamped to it) or, for half of them,
   keeps its shape and gets 2-4 extra dormers (2-4 m wide, 2-3 m deep boxes on the slope).
   ``RealityScene.building_roof_change`` (index into ``ROOF_CHANGES``).
6. Missing and new buildings: ``missing_fraction`` of the map's buildings are left out of the reality
   (their footprint becomes open ground: the terrain, trees and cars); ``new_fraction`` x the building
   count of buildings the map lacks are added: 8-20 x 8-20 m boxes, 4-15 m from the ground to the top,
   flat or (half) gable roofed, turned at random, on open ground at least 3 m from every other building
   and inside the footprint grid, sunk 0.3 m under the lowest terrain point of their corners. They get
   building indices after the reality model's (``__new_building_k__``) and are part of the footprint grid
   that places roof structures, trees and cars.
7. Terrain relief (``terrain_relief_m``, e.g. 3 m, wavelength ``terrain_wavelength_m`` 250 m): a
   ``terrain_grid_m`` grid of extra terrain vertices whose heights are the footprint TIN's plus a smooth
   random field (``relief_points``), zero within 3 m of a footprint and faded in by ``terrain_fade_m``
   (15 m), so walls neither float nor sink. ``RealityScene.terrain_height`` follows it, so trees, cars,
   new buildings and the queries' cameras stand on it.
8. Model errors (item 1) at the issue's bounds: ``shift_xy_max_m`` 1 m, ``height_change_max_m`` 2 m,
   spread "normal" in ``REALISTIC_REALITY`` (docs/benchmark.md gives the judgement).

The reality's ground is the terrain TIN of ``semcityloc.render.terrain`` built from the perturbed
buildings (with item 7's relief vertices when on) and added as an explicit GROUND mesh (the renderer
runs with ``ground=False``), so occluders do not change the terrain. Open ground is found on a
``grid_cell_m`` raster of the building footprints (every non-vertical building triangle projected to
x, y) covering the buildings' extent plus ``margin_m``; a roof structure is kept only if its four
corners lie on its host building's cells.

Everything is in the MAP model's local frame (a reality model with another origin is shifted in float64
first), rounded to the millimetre: numpy's vectorised sin / cos may differ by an ulp between CPUs (SIMD
code paths), and rounding keeps the rendered reality bit-identical on every machine.
``RealityScene.terrain_height`` gives the ground height at any x, y.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from scipy.spatial import ConvexHull, Delaunay, QhullError, cKDTree

from semcityloc.citymodel.eaves import FLAT_NZ, overhang_roofs
from semcityloc.citymodel.eaves import area_normal as _area_normal
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import BUILDING_CLASSES, SemanticClass
from semcityloc.errors import BenchmarkConfigError, CRSError, EmptyModelError
from semcityloc.render import Renderer
from semcityloc.render.terrain import build_terrain

TERRAIN_ID, TREES_ID, CARS_ID = "__terrain__", "__trees__", "__cars__"
_MAX_RASTER_PAIRS = 4_000_000  # (triangle, cell) pairs per vectorised rasterisation chunk
RELIEF_ZERO_M = 3.0  # no terrain relief within this distance of a footprint (the fade runs from here)


@dataclass(frozen=True)
class RealityParams:
    """Magnitudes of the reality's differences from the map (module docstring). The defaults are the
    ``clean`` scenario's reality (the first benchmark's); every knob added since is off by default, and
    ``REALISTIC_REALITY`` sets them to the issue-12 values (docs/benchmark.md)."""

    shift_xy_max_m: float = 0.3
    height_change_max_m: float = 0.5
    roof_structure_m2: float = 80.0  # one roof structure per this much roof area (0 = none)
    tree_m2: float = 300.0  # one tree per this much open ground (0 = none)
    car_m2: float = 300.0  # one car per this much ground 1.5-15 m from a facade (0 = none)
    tree_height_m: tuple[float, float] = (4.0, 15.0)
    car_band_m: tuple[float, float] = (1.5, 15.0)
    grid_cell_m: float = 0.5
    margin_m: float = 20.0
    # --- reality != map (issue 12; module docstring, items 4-8). Defaults: off.
    overhang_m: tuple[float, float] | None = None  # per-building roof overhang range (None = none)
    roof_change_fraction: float = 0.0  # share of buildings whose roof shape differs from the map's
    missing_fraction: float = 0.0  # share of map buildings gone in reality
    new_fraction: float = 0.0  # buildings missing from the map, as a share of the map's building count
    terrain_relief_m: float = 0.0  # peak height of the smooth terrain relief (0 = the map's footprint TIN)
    terrain_wavelength_m: float = 250.0  # typical wavelength of that relief
    terrain_grid_m: float = 8.0  # spacing of the relief's terrain vertices
    terrain_fade_m: float = 15.0  # the relief fades to 0 within this distance of a footprint (<= margin_m)
    tree_facade_clearance: float = 0.7  # a tree stands >= this x its crown radius from a facade
    model_error_spread: str = "uniform"  # item 1: magnitudes uniform in [0, max], or "normal" (max/3)
    overhang_flat_roofs: bool = True  # False: mostly flat roofs (parapets) get no overhang (item 4)

    def __post_init__(self) -> None:
        def bad(name: str, rule: str) -> BenchmarkConfigError:
            return BenchmarkConfigError(f"RealityParams.{name} must be {rule}, got {getattr(self, name)!r}")

        for name in ("tree_height_m", "car_band_m", "overhang_m"):
            value = getattr(self, name)
            if value is None and name == "overhang_m":
                continue
            try:
                pair = tuple(float(v) for v in value)
            except (TypeError, ValueError):
                raise bad(name, "a (low, high) pair") from None
            if len(pair) != 2 or not (0.0 <= pair[0] <= pair[1] < np.inf):
                raise bad(name, "a pair 0 <= low <= high")
            object.__setattr__(self, name, pair)
        for name in ("roof_change_fraction", "missing_fraction", "new_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise bad(name, "in [0, 1]")
        for name in ("shift_xy_max_m", "height_change_max_m", "roof_structure_m2", "tree_m2", "car_m2"):
            if not 0.0 <= getattr(self, name) < np.inf:
                raise bad(name, ">= 0")
        for name in ("margin_m", "terrain_relief_m", "tree_facade_clearance"):
            if not 0.0 <= getattr(self, name) < np.inf:
                raise bad(name, ">= 0")
        for name in ("grid_cell_m", "terrain_wavelength_m", "terrain_grid_m"):
            if not 0.0 < getattr(self, name) < np.inf:
                raise bad(name, "> 0")
        if self.model_error_spread not in MODEL_ERROR_SPREADS:
            raise bad("model_error_spread", f"one of {', '.join(MODEL_ERROR_SPREADS)}")
        if not RELIEF_ZERO_M < self.terrain_fade_m <= self.margin_m:
            raise bad("terrain_fade_m", f"in ({RELIEF_ZERO_M}, margin_m = {self.margin_m}]")
        if self.tree_height_m[0] <= 0.0:
            raise bad("tree_height_m", "positive")


MODEL_ERROR_SPREADS = ("uniform", "normal")

# The issue-12 "reality != map" (docs/benchmark.md gives the judgement behind each value).
REALISTIC_REALITY = RealityParams(
    shift_xy_max_m=1.0,
    height_change_max_m=2.0,
    overhang_m=(0.3, 1.0),
    roof_change_fraction=0.15,
    missing_fraction=0.03,
    new_fraction=0.03,
    terrain_relief_m=3.0,
    terrain_wavelength_m=250.0,
    tree_height_m=(4.0, 20.0),
    tree_facade_clearance=0.2,
    model_error_spread="normal",
    overhang_flat_roofs=False,
)

# Per-building roof changes (``RealityScene.building_roof_change`` holds the index).
ROOF_CHANGES = ("none", "gable", "hip", "flattened", "dormers")


@dataclass
class RealityScene:
    """The rendered reality (module docstring). ``model`` holds buildings, roof structures, terrain and
    occluders in the map's local frame; ``renderer`` draws it (numba engine, no extra terrain).

    Per-building arrays are indexed like the reality model's ``building_ids`` (B,); the new buildings
    (module docstring, item 6) follow them in ``model.building_ids`` (indices B .. B + new - 1), then the
    terrain, trees and cars."""

    model: CityModel
    renderer: Renderer
    terrain_height: TerrainHeight
    building_shift_xy: np.ndarray  # (B, 2) per reality building
    building_height_change: np.ndarray  # (B,)
    counts: dict[str, int] = field(default_factory=dict)
    building_missing: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # (B,)
    building_roof_change: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int8))  # (B,)
    building_overhang_m: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (B,), 0 = none

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


def _magnitude(rng: np.random.Generator, bound: float, n: int, spread: str) -> np.ndarray:
    """(n,) error magnitudes <= ``bound``: uniform in [0, bound], or |N(0, bound / 3)| clipped to it."""
    if spread == "normal":
        return np.minimum(np.abs(rng.normal(0.0, bound / 3.0, n)), bound)
    return rng.uniform(0.0, bound, n)


def perturb_buildings(
    corners: np.ndarray,
    building: np.ndarray,
    n_buildings: int,
    params: RealityParams,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-building xy shift and height change (module docstring, item 1): (corners, shift, dh)."""
    r = _magnitude(rng, params.shift_xy_max_m, n_buildings, params.model_error_spread)
    phi = rng.uniform(0.0, 2 * np.pi, n_buildings)
    shift = np.stack([r * np.cos(phi), r * np.sin(phi)], 1)
    dh = _magnitude(rng, params.height_change_max_m, n_buildings, params.model_error_spread)
    dh = dh * rng.choice([-1.0, 1.0], n_buildings)
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

    return _roof_boxes(pt, size / 2, angle, nrm, c[pick, 0], extra, building[roof[pick]], grid)


def _roof_boxes(
    pt: np.ndarray,
    half: np.ndarray,
    angle: np.ndarray,
    nrm: np.ndarray,
    p0: np.ndarray,
    extra: np.ndarray,
    host: np.ndarray,
    grid: FootprintGrid,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Boxes centred at ``pt`` (n, 3) on roof planes (unit normal ``nrm`` through ``p0``), half sizes
    (n, 2), turned by ``angle``, from 0.3 m under the plane to ``extra`` above its highest corner; a box
    is kept only if its four corners lie on ``host``'s cells. (vertices, triangles, classes, building)."""
    empty = (np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.uint8), np.zeros(0, np.int64))
    n = len(pt)
    ca, sa = np.cos(angle)[:, None], np.sin(angle)[:, None]
    sx, sy = np.array([-1, 1, 1, -1.0]), np.array([-1, -1, 1, 1.0])
    lx, ly = sx[None] * half[:, :1], sy[None] * half[:, 1:2]
    cx = pt[:, :1] + ca * lx - sa * ly
    cy = pt[:, 1:2] + sa * lx + ca * ly
    ok = np.ones(n, dtype=bool)
    for k in range(4):
        rows, cols, inside = grid.cells(np.stack([cx[:, k], cy[:, k]], 1))
        ok &= inside & (grid.ids[rows, cols] == host)
    # Roof plane height at the four corners (the plane of the picked triangle).
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
    keep = np.flatnonzero(d >= params.tree_facade_clearance * radius)[:n]
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


# ------------------------------------------------------------------------------------------ reality != map
RIDGE_RISE_M = (2.0, 5.0)  # ridge height above the eaves of a roof changed to gable / hip
GABLE_SHARE = 0.6  # of the flat roofs changed to a pitched one, the share made gable (the rest hip)
FLATTEN_SHARE = 0.5  # of the sloped roofs changed, the share flattened (the rest get dormers)
DORMERS_PER_ROOF = (2, 4)  # extra dormers on a changed sloped roof (inclusive)
MIN_BOX_FILL = 0.85  # a flat roof becomes pitched only when it fills this much of its oriented box
MAX_FLATTEN_RISE_M = 8.0  # a sloped roof is flattened only when it rises at most this much
NEW_SIZE_M = (8.0, 20.0)  # side lengths of a new building
NEW_HEIGHT_M = (4.0, 15.0)  # ground to top of a new building
NEW_CLEARANCE_M = 3.0  # a new building stands this far at least from any other building
RELIEF_WAVES = 8  # plane waves summed into the relief field
RELIEF_BORDER_M = 50.0  # the relief also fades to 0 over this much at the terrain's outer border


def _oriented_box(xy: np.ndarray) -> tuple[np.ndarray, float, float, np.ndarray] | None:
    """Minimum-area oriented rectangle of points (N, 2): (centre, length, width, long-axis unit vector),
    length >= width; None for fewer than 3 non-collinear points."""
    try:
        hull = xy[ConvexHull(xy).vertices]
    except (QhullError, ValueError):
        return None
    e = np.roll(hull, -1, 0) - hull
    ang = np.arctan2(e[:, 1], e[:, 0])
    u = np.stack([np.cos(ang), np.sin(ang)], 1)
    v = np.stack([-u[:, 1], u[:, 0]], 1)
    pu, pv = hull @ u.T, hull @ v.T  # (H, E)
    area = (pu.max(0) - pu.min(0)) * (pv.max(0) - pv.min(0))
    k = int(np.argmin(area))
    lu, lv = pu[:, k].max() - pu[:, k].min(), pv[:, k].max() - pv[:, k].min()
    centre = u[k] * (pu[:, k].max() + pu[:, k].min()) / 2 + v[k] * (pv[:, k].max() + pv[:, k].min()) / 2
    if lu >= lv:
        return centre, float(lu), float(lv), u[k]
    return centre, float(lv), float(lu), v[k]


def _house(
    centre: np.ndarray,
    length: float,
    width: float,
    axis: np.ndarray,
    z0: float,
    eaves: float,
    rise: float,
    kind: str,
    walls: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """A rectangular building, long side along ``axis``: (triangles (T, 3, 3), classes (T,)).

    ``kind``: "flat" (a roof at ``eaves``), "gable" (ridge along the long axis ``rise`` above the eaves,
    gable ends WALL) or "hip" (45-degree hips in plan). ``walls``: with the four walls from ``z0`` to the
    eaves (False: the roof only, for an existing building's walls)."""
    u = np.asarray(axis, dtype=np.float64)
    v = np.array([-u[1], u[0]])
    hl, hw = length / 2, width / 2
    r = [centre + sl * hl * u + sw * hw * v for sl, sw in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    e = [np.array([p[0], p[1], eaves]) for p in r]  # counter-clockwise seen from above
    tris, cls = [], []
    if walls:
        for k in range(4):
            a, b = r[k], r[(k + 1) % 4]
            a0, b0 = np.array([a[0], a[1], z0]), np.array([b[0], b[1], z0])
            tris += [(a0, b0, e[(k + 1) % 4]), (a0, e[(k + 1) % 4], e[k])]
            cls += [SemanticClass.WALL] * 2
    if kind == "flat":
        tris += [(e[0], e[1], e[2]), (e[0], e[2], e[3])]
        cls += [SemanticClass.ROOF] * 2
    else:
        inset = min(hw, hl) if kind == "hip" else 0.0
        ridge_z = eaves + rise
        ra = np.append(centre - (hl - inset) * u, ridge_z)  # ridge end over the short side r3-r0
        rb = np.append(centre + (hl - inset) * u, ridge_z)  # ... over r1-r2
        tris += [(e[0], e[1], rb), (e[0], rb, ra), (e[2], e[3], ra), (e[2], ra, rb)]
        cls += [SemanticClass.ROOF] * 4
        end = SemanticClass.ROOF if kind == "hip" else SemanticClass.WALL
        tris += [(e[1], e[2], rb), (e[3], e[0], ra)]
        cls += [end] * 2
    t = np.array(tris, dtype=np.float64)
    area, _ = _area_normal(t)
    keep = area > 1e-6  # a square hip roof's ridge has length 0
    return t[keep], np.array(cls, dtype=np.uint8)[keep]


def change_roofs(
    corners: np.ndarray,
    classes: np.ndarray,
    building: np.ndarray,
    lods: np.ndarray,
    n_buildings: int,
    fraction: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Roof shapes that differ from the map's (module docstring, item 5).

    Returns (corners, classes, building, lods, change (B,) int8 index into ``ROOF_CHANGES``, dormers (B,)
    int: the number of extra dormers to place on each building's sloped roof)."""
    change = np.zeros(n_buildings, dtype=np.int8)
    dormers = np.zeros(n_buildings, dtype=np.int64)
    roof = np.flatnonzero(classes == SemanticClass.ROOF)
    if fraction <= 0 or len(roof) == 0:
        return corners, classes, building, lods, change, dormers
    c = corners[roof]
    b = building[roof]
    area, unit = _area_normal(c)
    flat_tri = np.abs(unit[:, 2]) > FLAT_NZ
    roof_area = np.bincount(b, area, n_buildings)
    flat_area = np.bincount(b, area * flat_tri, n_buildings)
    zmin = np.full(n_buildings, np.inf)
    zmax = np.full(n_buildings, -np.inf)
    np.minimum.at(zmin, b, c[:, :, 2].min(1))
    np.maximum.at(zmax, b, c[:, :, 2].max(1))
    has_roof = roof_area > 0
    share = flat_area / np.maximum(roof_area, 1e-12)
    flat_b = has_roof & (share >= 0.95) & (zmax - zmin < 0.5)
    sloped_b = has_roof & (share < 0.5)
    boxes: dict[int, tuple] = {}
    e1, e2 = c[:, 1, :2] - c[:, 0, :2], c[:, 2, :2] - c[:, 0, :2]
    proj = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e2[:, 0] * e1[:, 1])  # area in x, y
    order = np.argsort(b, kind="stable")
    starts = np.searchsorted(b[order], np.arange(n_buildings + 1))
    for i in np.flatnonzero(flat_b):
        rows = order[starts[i] : starts[i + 1]]
        box = _oriented_box(c[rows, :, :2].reshape(-1, 2))
        if box is None or box[2] < 4.0:
            flat_b[i] = False
            continue
        fill = proj[rows].sum() / (box[1] * box[2])
        if not MIN_BOX_FILL <= fill <= 1.05:
            flat_b[i] = False
            continue
        boxes[int(i)] = box
    sloped_b &= zmax - zmin <= MAX_FLATTEN_RISE_M
    eligible = np.flatnonzero(flat_b | sloped_b)
    n = min(int(round(fraction * has_roof.sum())), len(eligible))
    if n == 0:
        return corners, classes, building, lods, change, dormers
    chosen = np.sort(rng.choice(eligible, n, replace=False))
    u = rng.random(n)
    rise = rng.uniform(*RIDGE_RISE_M, n)
    n_dormers = rng.integers(DORMERS_PER_ROOF[0], DORMERS_PER_ROOF[1] + 1, n)
    corners = corners.copy()
    drop = np.zeros(len(corners), dtype=bool)
    add_c, add_cls, add_b, add_l = [], [], [], []
    for k, i in enumerate(chosen):
        rows = order[starts[i] : starts[i + 1]]
        if flat_b[i]:
            kind = "gable" if u[k] < GABLE_SHARE else "hip"
            centre, length, width, axis = boxes[int(i)]
            t, cl = _house(centre, length, width, axis, 0.0, zmax[i], rise[k], kind, walls=False)
            drop[roof[rows]] = True
            add_c.append(t)
            add_cls.append(cl)
            add_b.append(np.full(len(t), i))
            add_l.append(np.full(len(t), lods[roof[rows[0]]]))
            change[i] = ROOF_CHANGES.index(kind)
        elif u[k] < FLATTEN_SHARE:
            tri = np.flatnonzero(building == i)
            corners[tri, :, 2] = np.minimum(corners[tri, :, 2], zmin[i])
            drop[tri[_area_normal(corners[tri])[0] < 1e-6]] = True  # gable ends squashed to nothing
            change[i] = ROOF_CHANGES.index("flattened")
        else:
            dormers[i] = n_dormers[k]
            change[i] = ROOF_CHANGES.index("dormers")
    keep = ~drop
    corners = np.concatenate([corners[keep]] + add_c)
    classes = np.concatenate([classes[keep]] + add_cls).astype(np.uint8)
    building = np.concatenate([building[keep]] + add_b).astype(np.int64)
    lods = np.concatenate([lods[keep]] + add_l).astype(np.uint8)
    return corners, classes, building, lods, change, dormers


def extra_dormers(
    corners: np.ndarray,
    classes: np.ndarray,
    building: np.ndarray,
    dormers: np.ndarray,
    grid: FootprintGrid,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``dormers[b]`` dormers (2-4 m wide, 2-3 m deep, on the slope) on building b's sloped roof
    triangles, area-weighted, kept where they fit the building's cells (vertices, triangles, classes,
    building per triangle)."""
    roof = np.flatnonzero((classes == SemanticClass.ROOF) & (dormers[building] > 0))
    c = corners[roof]
    area, unit = _area_normal(c)
    up = (unit[:, 2] > 0.3) & (unit[:, 2] <= FLAT_NZ)
    roof, c, area, unit = roof[up], c[up], area[up], unit[up]
    b = building[roof]
    picks = []
    for i in np.flatnonzero(dormers):
        rows = np.flatnonzero(b == i)
        if len(rows):
            w = area[rows] / area[rows].sum()
            picks.append(rows[rng.choice(len(rows), dormers[i], p=w)])
    if not picks:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.uint8), np.zeros(0, np.int64)
    pick = np.concatenate(picks)
    n = len(pick)
    r1, r2 = rng.random(n), rng.random(n)
    s1 = np.sqrt(r1)
    pt = (
        (1 - s1)[:, None] * c[pick, 0]
        + (s1 * (1 - r2))[:, None] * c[pick, 1]
        + (s1 * r2)[:, None] * c[pick, 2]
    )
    nrm = unit[pick]
    half = np.stack([rng.uniform(2.0, 4.0, n), rng.uniform(2.0, 3.0, n)], 1) / 2
    angle = np.arctan2(nrm[:, 1], nrm[:, 0]) - np.pi / 2
    return _roof_boxes(pt, half, angle, nrm, c[pick, 0], np.full(n, 0.2), b[pick], grid)


def relief_points(
    terrain_vertices: np.ndarray,
    terrain: TerrainHeight,
    grid: FootprintGrid,
    dist: np.ndarray,
    params: RealityParams,
    rng: np.random.Generator,
) -> np.ndarray:
    """Terrain points with a smooth relief (module docstring, item 7): (K, 3).

    A ``terrain_grid_m`` grid over the terrain's extent (inset by half a step) at the footprint TIN's
    height plus ``terrain_relief_m`` x f(x, y) x w, where f is a sum of ``RELIEF_WAVES`` plane waves
    (random directions and phases, wavelengths 0.7-1.4 x ``terrain_wavelength_m``) scaled so that max |f|
    over the grid is 1, and w a smoothstep of the distance to the nearest footprint cell over
    ``terrain_fade_m`` (times one over the outer ``RELIEF_BORDER_M``, where the TIN's border ring keeps
    the footprint heights). Points within 1 m of a footprint are left out."""
    lo, hi = terrain_vertices[:, :2].min(0), terrain_vertices[:, :2].max(0)
    s = params.terrain_grid_m
    xs = np.arange(lo[0] + s / 2, hi[0] - s / 4, s)
    ys = np.arange(lo[1] + s / 2, hi[1] - s / 4, s)
    gx, gy = np.meshgrid(xs, ys)
    p = np.column_stack([gx.reshape(-1), gy.reshape(-1)])
    rows, cols, inside = grid.cells(p)
    d = np.where(inside, dist[rows, cols], np.inf)  # outside the grid: >= margin_m >= terrain_fade_m
    p, d = p[d >= 1.0], d[d >= 1.0]
    if len(p) == 0:
        return np.zeros((0, 3))
    theta = rng.uniform(0, 2 * np.pi, RELIEF_WAVES)
    k = 2 * np.pi / (params.terrain_wavelength_m * rng.uniform(0.7, 1.4, RELIEF_WAVES))
    phase = rng.uniform(0, 2 * np.pi, RELIEF_WAVES)
    amp = rng.uniform(0.5, 1.0, RELIEF_WAVES)
    wave = np.stack([np.cos(theta), np.sin(theta)], 1) * k[:, None]  # (W, 2)
    f = (amp[None] * np.cos(p @ wave.T + phase[None])).sum(1)
    f /= max(float(np.abs(f).max()), 1e-12)

    def smooth(x):
        x = np.clip(x, 0.0, 1.0)
        return x * x * (3 - 2 * x)

    edge = np.minimum(p - lo, hi - p).min(1)
    fade = max(params.terrain_fade_m - RELIEF_ZERO_M, 1e-9)
    w = smooth((d - RELIEF_ZERO_M) / fade) * smooth(edge / RELIEF_BORDER_M)
    return np.column_stack([p, terrain(p) + params.terrain_relief_m * f * w])


def new_buildings(
    dist: np.ndarray,
    grid: FootprintGrid,
    terrain: TerrainHeight,
    n: int,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Up to n buildings the map lacks (module docstring, item 6): (triangles (T, 3, 3), classes (T,),
    which new building (T,))."""
    empty = np.zeros((0, 3, 3)), np.zeros(0, np.uint8), np.zeros(0, np.int64)
    if n == 0:
        return empty
    m = 40 * n
    size = np.sort(rng.uniform(*NEW_SIZE_M, (m, 2)), axis=1)[:, ::-1]  # (length, width)
    radius = 0.5 * np.linalg.norm(size, axis=1)
    ok_cells = dist >= NEW_CLEARANCE_M + NEW_SIZE_M[0] / np.sqrt(2)
    xy, d = _open_ground_samples(dist, ok_cells, grid, m, rng)
    if len(xy) == 0:
        return empty
    angle = rng.uniform(0, np.pi, m)
    height = rng.uniform(*NEW_HEIGHT_M, m)
    gable = rng.random(m) < 0.5
    rise = np.minimum(rng.uniform(*RIDGE_RISE_M, m), height - 3.0)
    ny, nx = dist.shape
    span = grid.lo + np.array([nx, ny]) * grid.cell
    placed: list[int] = []
    for i in range(m):
        if len(placed) == n:
            break
        if d[i] < NEW_CLEARANCE_M + radius[i] + grid.cell:
            continue
        if np.any(xy[i] - radius[i] < grid.lo) or np.any(xy[i] + radius[i] > span):
            continue
        if any(np.linalg.norm(xy[i] - xy[j]) < radius[i] + radius[j] + NEW_CLEARANCE_M for j in placed):
            continue
        placed.append(i)
    tris, cls, which = [], [], []
    for k, i in enumerate(placed):
        axis = np.array([np.cos(angle[i]), np.sin(angle[i])])
        v = np.array([-axis[1], axis[0]])
        signs = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1], [0, 0]], dtype=np.float64)
        z = terrain(xy[i] + (signs * size[i] / 2) @ np.stack([axis, v]))  # corners and centre
        r = rise[i] if gable[i] and rise[i] >= 1.0 else 0.0
        kind = "gable" if r > 0 else "flat"
        eaves = z.max() + height[i] - r
        t, c = _house(xy[i], size[i, 0], size[i, 1], axis, z.min() - 0.3, eaves, r, kind, walls=True)
        tris.append(t)
        cls.append(c)
        which.append(np.full(len(t), k))
    if not tris:
        return empty
    return np.concatenate(tris), np.concatenate(cls), np.concatenate(which)


# ------------------------------------------------------------------------------------------ public
def build_reality(
    map_model: CityModel,
    reality_model: CityModel | None = None,
    seed: int = 0,
    params: RealityParams | None = None,
) -> RealityScene:
    """The reality scene of ``reality_model`` (default: the map itself) in the map's local frame.

    Deterministic: the same models, ``seed`` and ``params`` give the same scene on any machine. Each
    "reality != map" knob draws from its own generator, and only when it is on, so the knobs that are
    off leave the scene as it was without them.
    """
    params = params or RealityParams()
    reality = reality_model if reality_model is not None else map_model
    rng = np.random.default_rng([int(seed), 0x5EA1])  # the reality's own stream (queries use 3+ keys)

    def knob_rng(k: int) -> np.random.Generator:
        return np.random.default_rng([int(seed), 0x5EA1, k])

    corners = _in_map_frame(map_model, reality)
    building = reality.building_index.astype(np.int64)
    n_b = len(reality.building_ids)
    corners, shift, dh = perturb_buildings(corners, building, n_b, params, knob_rng(1))
    classes = reality.classes
    lods = reality.lods
    is_building = np.isin(classes, BUILDING_CLASSES)
    if not is_building.any():
        raise EmptyModelError("the reality model has no walls or roofs: nothing to fly over")
    present = np.zeros(n_b, dtype=bool)
    present[building[is_building]] = True

    missing = np.zeros(n_b, dtype=bool)
    n_missing = min(int(round(params.missing_fraction * present.sum())), int(present.sum()) - 1)
    if n_missing > 0:
        missing[knob_rng(2).choice(np.flatnonzero(present), n_missing, replace=False)] = True
        keep = ~missing[building]
        corners, classes, building, lods = corners[keep], classes[keep], building[keep], lods[keep]
    roof_change = np.zeros(n_b, dtype=np.int8)
    n_dormers = np.zeros(n_b, dtype=np.int64)
    if params.roof_change_fraction > 0:
        corners, classes, building, lods, roof_change, n_dormers = change_roofs(
            corners, classes, building, lods, n_b, params.roof_change_fraction, knob_rng(3)
        )
    overhang = np.zeros(n_b)
    if params.overhang_m is not None:
        amount = knob_rng(4).uniform(params.overhang_m[0], params.overhang_m[1], n_b)
        corners, overhang = overhang_roofs(corners, classes, building, amount, params.overhang_flat_roofs)
    if n_missing > 0 or params.roof_change_fraction > 0:
        is_building = np.isin(classes, BUILDING_CLASSES)

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

    buildings_only = model_of(corners, classes, building, lods, list(reality.building_ids))
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

    if params.terrain_relief_m > 0:
        extra = relief_points(tv, terrain, grid, dist, params, knob_rng(5))
        tv, tt = build_terrain(buildings_only, extra_points=extra)
        terrain = TerrainHeight(tv)
    ids = list(reality.building_ids)
    n_new = int(round(params.new_fraction * present.sum()))
    if n_new > 0:
        nt, ncls, which = new_buildings(dist, grid, terrain, n_new, knob_rng(6))
        n_new = int(which.max()) + 1 if len(which) else 0
        if n_new:
            ids += [f"__new_building_{k}__" for k in range(n_new)]
            corners = np.concatenate([corners, nt])
            classes = np.concatenate([classes, ncls]).astype(np.uint8)
            building = np.concatenate([building, n_b + which])
            lods = np.concatenate([lods, np.zeros(len(nt), np.uint8)])
            # Rasterise them on a window of the grid (same cell lattice) and add them to it.
            j0, i0 = np.floor((nt[:, :, :2].reshape(-1, 2).min(0) - grid.lo) / grid.cell).astype(int)
            sub = footprint_grid(
                nt,
                n_b + which,
                grid.lo + np.array([j0, i0]) * grid.cell,
                nt[:, :, :2].reshape(-1, 2).max(0),
                grid.cell,
            ).ids
            window = grid.ids[i0 : i0 + sub.shape[0], j0 : j0 + sub.shape[1]]
            sub = sub[: window.shape[0], : window.shape[1]]
            window[sub >= 0] = sub[sub >= 0]
            built = grid.ids >= 0
            dist = ndimage.distance_transform_edt(~built) * grid.cell
    n_all = n_b + n_new

    rv, rt, rcls, rb = roof_structures(corners, classes, building, grid, params, rng)
    trv, trt, n_trees = trees(dist, grid, terrain, params, rng)
    cv, ct, n_cars = cars(dist, grid, terrain, params, rng)

    ids += [TERRAIN_ID, TREES_ID, CARS_ID]
    pieces = [
        (corners, classes, building, lods),
        (tv[tt], np.full(len(tt), SemanticClass.GROUND), np.full(len(tt), n_all), np.zeros(len(tt))),
        (rv[rt], rcls, rb, np.zeros(len(rt))),
        (trv[trt], np.zeros(len(trt)), np.full(len(trt), n_all + 1), np.zeros(len(trt))),
        (cv[ct], np.zeros(len(ct)), np.full(len(ct), n_all + 2), np.zeros(len(ct))),
    ]
    n_extra_dormers = 0
    if n_dormers.any():
        per_building = np.concatenate([n_dormers, np.zeros(n_new, dtype=np.int64)])
        dv, dt, dcls, db = extra_dormers(corners, classes, building, per_building, grid, knob_rng(7))
        pieces.insert(3, (dv[dt], dcls, db, np.zeros(len(dt))))
        n_extra_dormers = len(dt) // 10
    # Millimetre coordinates (module docstring): the same scene on every machine.
    model = model_of(
        np.round(np.concatenate([p[0].reshape(-1, 3, 3) for p in pieces]), 3),
        np.concatenate([p[1] for p in pieces]).astype(np.uint8),
        np.concatenate([p[2] for p in pieces]).astype(np.int32),
        np.concatenate([p[3] for p in pieces]).astype(np.uint8),
        ids,
    )
    renderer = Renderer(model, engine="numba", ground=False)
    changed = roof_change > 0
    counts = {
        "buildings": int(n_b),
        "roof_structures": int(len(rt) // 10),
        "trees": int(n_trees),
        "cars": int(n_cars),
        "occluder_triangles": int(len(trt) + len(ct)),
        "triangles": int(model.num_triangles),
        "missing_buildings": int(missing.sum()),
        "new_buildings": int(n_new),
        "roof_changes": int(changed.sum()),
        **{f"roof_changes_{name}": int((roof_change == k).sum()) for k, name in enumerate(ROOF_CHANGES) if k},
        "extra_dormers": int(n_extra_dormers),
        "overhang_buildings": int((overhang > 0).sum()),
        "terrain_vertices": int(len(tv)),
    }
    return RealityScene(
        model, renderer, terrain, shift, np.asarray(dh), counts, missing, roof_change, overhang
    )

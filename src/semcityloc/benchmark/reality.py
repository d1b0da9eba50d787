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

This module holds the knobs (``RealityParams``), the scene and ``build_reality``, which applies the
items in the order above; the pieces are in ``building_changes`` (items 1, 2, 5 and 6), ``occluders``
(item 3: trees and cars), ``citymodel.eaves`` (item 4), ``terrain_relief`` (item 7 and
``TerrainHeight``), ``footprints`` (the footprint raster and the open ground samples) and ``meshes`` (the
boxes, crowns and their copies).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np
from scipy import ndimage

from semcityloc.benchmark.building_changes import (
    ROOF_CHANGES,
    change_roofs,
    extra_dormers,
    new_buildings,
    perturb_buildings,
    roof_structures,
)
from semcityloc.benchmark.footprints import footprint_grid
from semcityloc.benchmark.occluders import cars, trees
from semcityloc.benchmark.terrain_relief import RELIEF_ZERO_M, TerrainHeight, relief_points
from semcityloc.citymodel.eaves import overhang_roofs
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import BUILDING_CLASSES, SemanticClass
from semcityloc.errors import BenchmarkConfigError, CRSError, EmptyModelError, finite_number, true_or_false
from semcityloc.render import Renderer
from semcityloc.render.terrain import build_terrain

TERRAIN_ID, TREES_ID, CARS_ID = "__terrain__", "__trees__", "__cars__"


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

        # Every field's type first, in one place (by its annotation), then the ranges: text from ``--set``
        # ('False', 'abc', 'nan') compared as a number or taken as a bool ran or failed obscurely.
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type == "bool":
                object.__setattr__(
                    self, f.name, true_or_false(value, f"RealityParams.{f.name}", BenchmarkConfigError)
                )
            elif f.type == "float":
                if not finite_number(value):
                    raise bad(f.name, "a finite number")
                object.__setattr__(self, f.name, float(value))
            elif f.type.startswith("tuple[float, float]") and value is not None:
                items = list(value) if isinstance(value, (tuple, list, np.ndarray)) else []
                if len(items) != 2 or not all(map(finite_number, items)):
                    raise bad(f.name, "a (low, high) pair of numbers")
                object.__setattr__(self, f.name, tuple(float(v) for v in items))
        for name in ("tree_height_m", "car_band_m", "overhang_m"):
            pair = getattr(self, name)
            if pair is not None and not 0.0 <= pair[0] <= pair[1]:
                raise bad(name, "a pair 0 <= low <= high")
        for name in ("roof_change_fraction", "missing_fraction", "new_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise bad(name, "in [0, 1]")
        # Upper bounds: what a map or a city can differ by, not what memory holds (a 1e9 m shift or one
        # tree per 0.001 m2 ran a one-query benchmark to 18 GB before any check).
        for name, high in REALITY_BOUNDS.items():
            if not 0.0 <= getattr(self, name) <= high:
                raise bad(name, f"in [0, {high:g}]")
        for name, low in REALITY_DENSITY_FLOORS_M2.items():
            if getattr(self, name) != 0.0 and not low <= getattr(self, name) < np.inf:
                raise bad(name, f"0 (none) or at least {low:g} m2 per object")
        for name in ("grid_cell_m", "terrain_wavelength_m", "terrain_grid_m"):
            if not 0.1 <= getattr(self, name) <= 10_000.0:
                raise bad(name, "in [0.1, 10000] m")
        for name in ("overhang_m", "car_band_m", "tree_height_m"):
            pair = getattr(self, name)
            if pair is not None and pair[1] > REALITY_PAIR_BOUNDS[name]:
                raise bad(name, f"a pair up to {REALITY_PAIR_BOUNDS[name]:g} m")
        if self.model_error_spread not in MODEL_ERROR_SPREADS:
            raise bad("model_error_spread", f"one of {', '.join(MODEL_ERROR_SPREADS)}")
        if not RELIEF_ZERO_M < self.terrain_fade_m <= self.margin_m:
            raise bad("terrain_fade_m", f"in ({RELIEF_ZERO_M}, margin_m = {self.margin_m}]")
        if self.tree_height_m[0] <= 0.0:
            raise bad("tree_height_m", "positive")


MODEL_ERROR_SPREADS = ("uniform", "normal")
# The knobs' ranges (``RealityParams.__post_init__``): far beyond any map's error or any city, short of what
# exhausts a machine.
REALITY_BOUNDS = {
    "shift_xy_max_m": 50.0,
    "height_change_max_m": 50.0,
    "margin_m": 2_000.0,
    "terrain_relief_m": 200.0,
    "tree_facade_clearance": 10.0,
}
REALITY_DENSITY_FLOORS_M2 = {"roof_structure_m2": 1.0, "tree_m2": 1.0, "car_m2": 1.0}
REALITY_PAIR_BOUNDS = {"overhang_m": 5.0, "car_band_m": 50.0, "tree_height_m": 100.0}

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


def _in_map_frame(map_model: CityModel, reality: CityModel) -> np.ndarray:
    """Triangle corners (T, 3, 3) float64 of ``reality`` in the map's local frame."""
    if map_model.crs is not None and reality.crs is not None and not map_model.crs.equals(reality.crs):
        raise CRSError("the reality model and the map model are in different CRSs")
    shift = np.asarray(reality.origin, dtype=np.float64) - map_model.origin
    return reality.vertices[reality.triangles].astype(np.float64) + shift


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

"""Segmentation errors structured the way real networks err, from what a view really contains.

Why (issue 12): random blobs and wobbly boundaries are errors no real network makes, and a localizer
tuned against them is tuned against the wrong thing. Real heads, trained on labels projected from the
map (the paper's automatic labelling) or used zero-shot, err where the image is ambiguous: at depth
discontinuities and eaves, on steep roofs (seen like facades) and low walls (seen like roof edges), in
cast shadows, under trees and cars (labelled as what lies behind them, since the training labels come
from the map that has no trees), on small buildings and courtyards; zero-shot models (CLIP + SAM)
additionally call whole segments the wrong class. This module computes the per-pixel truth those
errors need (``ViewTruth``, ``view_truth``) and applies them (``structured_errors``, called by
``perception_sim.simulate_segmentation(clean, preset, rng, truth=...)``).

``ViewTruth`` (all (H, W)): ``labels`` the reality's clean labels; ``depth`` true z-depth (+inf = sky);
``normal_z`` |z| of the hit surface's unit normal (NaN = nothing hit); ``building`` the reality
building index (-1 for terrain, trees, cars, sky); ``behind`` the labels of the reality rendered without
its trees and cars; ``occluder`` tree / car pixels (clean label 0 with a finite depth); ``shadow`` cast
shadow on surfaces facing the sun (``shadows.shadow_mask(..., attached=False)``: a facade's own shade is
not counted); ``wall_height`` the height (m) of the planar facade
segment hit (NaN where no facade: WALL, WINDOW, DOOR): all facade triangles of one building on one plane
(normal azimuth to 2 deg, offset to 0.5 m, two staggered binnings, the larger height kept), so a tall
wall split around its windows counts as tall and a chimney's side as low.

Structured errors (``SegPreset`` fields, every one 0 / off by default; applied in this order to the
"stuff" map, the clean labels with windows and doors as wall; each step draws from its own generator
spawned from the one ``simulate_segmentation`` passes, so switching one step off leaves the others'
draws unchanged):

1. occluders (``occluder_to_behind``): each tree / car (8-connected component of ``occluder``) is
   labelled with ``behind`` (ground, roof where it hangs over a roof, wall in front of a facade) with
   this probability; else it stays background;
2. steep roofs (``steep_roof_nz``, ``steep_roof_to_wall``): each 8-connected component of roof pixels
   with ``normal_z`` below the threshold becomes wall with the probability;
3. low walls (``low_wall_m``, ``low_wall_to_roof``): each component of wall pixels whose
   ``wall_height`` is below ``low_wall_m`` (roof-structure sides, dormer fronts, low buildings) becomes
   roof with the probability;
4. courtyards (``courtyard_share``, ``courtyard_fill``): each 4-connected component of non-building
   pixels that does not touch the image border (enclosed by building) and covers less than
   ``courtyard_share`` of the image becomes roof with the probability;
5. small and missed buildings: each 8-connected component of building pixels (wall, roof) covering less
   than ``small_building_share`` of the image is missed with probability ``small_building_miss``
   (labelled as the most common class around it: ground, mostly); each visible reality building is
   missed whole (its wall and roof pixels become ground) with probability ``building_miss``;
6. segment swaps (``segment_swaps``: (from, to, probability) triples; ``segment_cell_px``): the image is
   cut into segments, one per (class, building, cell of a warped ``segment_cell_px`` grid), the way SAM
   proposes regions; each segment of class ``from`` becomes ``to`` with the probability (triples of the
   same ``from`` are exclusive: one uniform draw per segment);
7. cast shadows (``shadow_error``, ``shadow_cell_px``, ``shadow_to_background``): smooth random regions
   (correlation length ``shadow_cell_px``) covering ``shadow_error`` of the shadowed ground / wall / roof
   pixels; each connected part becomes background (dark = "unknown") with probability
   ``shadow_to_background``, else the most common other class around it (shadowed ground next to a
   facade called wall, a shaded roof part called ground);
8. depth discontinuities and eaves (``bleed_px``): where the true depth jumps (a 4-neighbour nearer by
   more than ``BLEED_JUMP_REL`` x depth and ``BLEED_JUMP_M``), the nearer surface's label grows over the
   farther one by 1..``bleed_px`` pixels (a smooth random width, ``BLEED_CELL_PX``), foreground fattening
   of roofs over ground and walls, of buildings over sky.

Windows and doors of the clean labels stay where their facade is still wall; ``simulate_segmentation``
then runs its usual steps (openings, confusions, blobs, boundary warp, dilation, patch blur).

``REALISTIC_SEG_PRESETS`` are the paper's three qualities built on these errors; their numbers were tuned
on the generated city and Fuerth (``benchmarks/calibrate_segmentation.py``) against the paper's
measure: the MAP's own labels at the true pose by the automatic labelling rules, pooled over queries
(docs/benchmark.md, "Segmentation errors (realistic)").
"""

from __future__ import annotations

import dataclasses
import weakref
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.special import ndtr

from semcityloc.benchmark.perception_sim import SegPreset, smooth_field
from semcityloc.benchmark.shadows import shadow_mask, sun_direction
from semcityloc.classes import NUM_CLASSES, SemanticClass
from semcityloc.errors import ArgumentTypeError, ShapeError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.render import Renderer

__all__ = [
    "REALISTIC_SEG_PRESETS",
    "SEG_TARGETS",
    "fold_to_map_classes",
    "ViewTruth",
    "structured_errors",
    "sun_direction",
    "view_truth",
]

_B, _G, _W, _R = 0, int(SemanticClass.GROUND), int(SemanticClass.WALL), int(SemanticClass.ROOF)
_WIN, _DOOR = int(SemanticClass.WINDOW), int(SemanticClass.DOOR)
_FACADE = (_W, _WIN, _DOOR)
_EIGHT = np.ones((3, 3), dtype=bool)
BLEED_JUMP_REL = 0.03  # a depth jump: the neighbour is nearer by more than 3 % of the depth ...
BLEED_JUMP_M = 1.0  # ... and more than 1 m
BLEED_CELL_PX = 24  # correlation length of the bleed width along a boundary
WALL_PLANE_AZ_DEG = 2.0
WALL_PLANE_OFFSET_M = 0.5
N_STEPS = 8


@dataclass
class ViewTruth:
    """What a view really contains, per pixel (module docstring). All arrays (H, W)."""

    labels: np.ndarray  # uint8 clean reality labels
    depth: np.ndarray  # float32 z-depth, +inf = nothing
    normal_z: np.ndarray  # float32 |n_z| of the hit surface, NaN = nothing
    building: np.ndarray  # int32 reality building index, -1 = none / terrain / occluder
    behind: np.ndarray  # uint8 labels without trees and cars
    occluder: np.ndarray  # bool tree / car pixels
    shadow: np.ndarray  # bool in cast / attached shadow
    wall_height: np.ndarray  # float32 height of the facade segment hit, NaN = not a facade

    def __post_init__(self) -> None:
        shape = np.shape(self.labels)
        if len(shape) != 2:
            raise ShapeError(f"ViewTruth.labels must be (H, W), got {shape}")
        for f in dataclasses.fields(self):
            if np.shape(getattr(self, f.name)) != shape:
                raise ShapeError(
                    f"ViewTruth.{f.name} has shape {np.shape(getattr(self, f.name))}, not {shape}"
                )

    def structured_errors(self, clean: np.ndarray, preset: SegPreset, rng: np.random.Generator) -> np.ndarray:
        """``structured_errors(clean, self, preset, rng)`` (the hook ``simulate_segmentation`` calls)."""
        return structured_errors(clean, self, preset, rng)

    @classmethod
    def plain(cls, labels: np.ndarray, depth: np.ndarray | None = None, **fields) -> ViewTruth:
        """A truth from ``labels`` (and ``depth``) with neutral values for every field not given: flat
        surfaces, no building, nothing behind occluders, no shadow (for tests and callers without a
        scene)."""
        labels = np.asarray(labels, dtype=np.uint8)
        shape = labels.shape
        if depth is None:
            depth = np.where(labels > 0, 100.0, np.inf).astype(np.float32)
        base = {
            "labels": labels,
            "depth": np.asarray(depth, dtype=np.float32),
            "normal_z": np.ones(shape, dtype=np.float32),
            "building": np.full(shape, -1, dtype=np.int32),
            "behind": labels.copy(),
            "occluder": np.zeros(shape, dtype=bool),
            "shadow": np.zeros(shape, dtype=bool),
            "wall_height": np.where(np.isin(labels, _FACADE), 10.0, np.nan).astype(np.float32),
        }
        base.update(fields)
        return cls(**base)


# ------------------------------------------------------------------------------------------ truth
@dataclass
class _RealityExtras:
    behind: Renderer  # the reality without trees and cars
    wall_height: np.ndarray  # (T,) per triangle of the reality renderer's scene, NaN = not a facade
    building: np.ndarray  # (T,) reality building index per scene triangle, -1 = not a building part
    normals: np.ndarray  # (T, 3) float64 unit normal per scene triangle (the source winding's sign)


_CACHE: dict[int, _RealityExtras] = {}


def _facade_heights(corners: np.ndarray, classes: np.ndarray, building: np.ndarray) -> np.ndarray:
    """(T,) height of the planar facade segment of each facade triangle (module docstring), NaN else."""
    out = np.full(len(classes), np.nan, dtype=np.float32)
    facade = np.flatnonzero(np.isin(classes, _FACADE) & (building >= 0))
    if len(facade) == 0:
        return out
    c = corners[facade].astype(np.float64)
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    az = np.degrees(np.arctan2(n[:, 1], n[:, 0])) % 180.0  # a plane's two orientations are one plane
    sign = np.where(np.degrees(np.arctan2(n[:, 1], n[:, 0])) % 360.0 >= 180.0, -1.0, 1.0)
    offset = sign * np.einsum("ij,ij->i", n, c[:, 0])
    zlo, zhi = c[:, :, 2].min(1), c[:, :, 2].max(1)
    best = np.zeros(len(facade))
    for shift in (0.0, 0.5):
        ka = np.floor(az / WALL_PLANE_AZ_DEG + shift).astype(np.int64)
        ko = np.floor(offset / WALL_PLANE_OFFSET_M + shift).astype(np.int64)
        key = np.stack([building[facade].astype(np.int64), ka, ko], 1)
        _, inv = np.unique(key, axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        lo = np.full(inv.max() + 1, np.inf)
        hi = np.full(inv.max() + 1, -np.inf)
        np.minimum.at(lo, inv, zlo)
        np.maximum.at(hi, inv, zhi)
        best = np.maximum(best, (hi - lo)[inv])
    out[facade] = best
    return out


def _extras(reality) -> _RealityExtras:
    """The behind renderer and per-triangle facade heights of a reality, built once and cached."""
    key = id(reality)
    got = _CACHE.get(key)
    if got is not None:
        return got
    model = reality.model
    scene = reality.renderer.scene
    no_occluders = model.select(model.classes != SemanticClass.BACKGROUND)
    behind = Renderer(no_occluders, engine=reality.renderer.engine_name, ground=False)
    src = scene.source_triangle
    part = np.where(src >= 0, model.building_index[np.maximum(src, 0)], -1).astype(np.int64)
    is_building = np.isin(scene.classes, (_W, _R, _WIN, _DOOR))
    part = np.where(is_building, part, -1)
    c = scene.corners.astype(np.float64)
    normals = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    extras = _RealityExtras(behind, _facade_heights(scene.corners, scene.classes, part), part, normals)
    _CACHE[key] = extras
    weakref.finalize(reality, _CACHE.pop, key, None)
    return extras


def view_truth(reality, camera: Camera, pose_local: Pose, sun_dir: np.ndarray | None = None) -> ViewTruth:
    """The ``ViewTruth`` of ``reality`` (a ``reality.RealityScene``) seen by ``camera`` at
    ``pose_local`` (cam_from_world, the map's local frame), with shadows cast by a sun in direction
    ``sun_dir`` (toward the sun, ``sun_direction``; None = no shadows)."""
    extras = _extras(reality)
    view = reality.renderer.render(camera, pose_local, depth=True, face_ids=True)
    labels, depth, faces = view.labels[0], view.depth[0], view.face_ids[0]
    hit = faces >= 0
    safe = np.maximum(faces, 0)
    n = extras.normals[safe]  # (H, W, 3)
    n[~hit] = np.nan
    normal_z = np.abs(n[..., 2]).astype(np.float32)
    building = np.where(hit, extras.building[safe], -1).astype(np.int32)
    wall_height = np.where(hit, extras.wall_height[safe], np.nan).astype(np.float32)
    behind = extras.behind.render(camera, pose_local).labels[0]
    occluder = (labels == _B) & np.isfinite(depth)
    if sun_dir is None:
        shadow = np.zeros(labels.shape, dtype=bool)
    else:
        shadow = shadow_mask(reality.renderer, camera, pose_local, depth, sun_dir, normals=n, attached=False)
    return ViewTruth(labels, depth, normal_z, building, behind, occluder, shadow, wall_height)


# ------------------------------------------------------------------------------------------ errors
def _check_truth(clean: np.ndarray, truth: ViewTruth) -> None:
    if not isinstance(truth, ViewTruth):
        raise ArgumentTypeError(
            f"truth must be a ViewTruth (view_truth(...) or ViewTruth.plain(labels)), got "
            f"{type(truth).__name__}"
        )
    if truth.labels.shape != clean.shape:
        raise ShapeError(f"truth {truth.labels.shape} and clean labels {clean.shape} differ in shape")


def _pick_components(
    mask: np.ndarray, p: float, rng: np.random.Generator, split: np.ndarray | None = None
) -> np.ndarray:
    """The union of the 8-connected components of ``mask`` (cut further by the values of ``split``, e.g.
    the building index: one roof face per building) each drawn with probability ``p``."""
    comp, n = ndimage.label(mask, structure=_EIGHT)
    if n and split is not None:
        inside = comp > 0
        key = comp[inside].astype(np.int64) * (int(split.max()) + 2) + (split[inside].astype(np.int64) + 1)
        uniq, inv = np.unique(key, return_inverse=True)
        comp = np.zeros(mask.shape, dtype=np.int64)
        comp[inside] = inv.reshape(-1) + 1
        n = len(uniq)
    draw = rng.random(n)
    if n == 0 or p <= 0:
        return np.zeros(mask.shape, dtype=bool)
    return np.concatenate([[False], draw < p])[comp]


def _ring_mode(labels: np.ndarray, comp: np.ndarray, ids: np.ndarray, exclude=()) -> np.ndarray:
    """Per component id in ``ids``: the most common label on its 1-px outer ring (8-neighbours), among
    labels not in ``exclude``; -1 when there is none."""
    out = np.full(len(ids), -1, dtype=np.int64)
    if len(ids) == 0:
        return out
    lut = np.full(int(comp.max()) + 1, -1, dtype=np.int64)
    lut[ids] = np.arange(len(ids))
    counts = np.zeros((len(ids), NUM_CLASSES), dtype=np.int64)
    h, w = labels.shape
    padc = np.pad(comp, 1)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            if di == 0 and dj == 0:
                continue
            nb = padc[1 + di : 1 + di + h, 1 + dj : 1 + dj + w]  # comp of the neighbour (i+di, j+dj)
            sel = (nb > 0) & (comp != nb)
            k = lut[nb[sel]]
            ok = k >= 0
            np.add.at(counts, (k[ok], labels[sel][ok].astype(np.int64)), 1)
    for c in exclude:
        counts[:, c] = 0
    has = counts.sum(1) > 0
    out[has] = np.argmax(counts[has], axis=1)
    return out


def _occluders(stuff, truth, p, rng) -> None:
    if p <= 0:
        return
    pick = _pick_components(truth.occluder, p, rng)
    behind = truth.behind.astype(np.uint8)
    behind = np.where(np.isin(behind, (_WIN, _DOOR)), _W, behind).astype(np.uint8)
    stuff[pick] = behind[pick]


def _steep_roofs(stuff, truth, preset, rng) -> None:
    if preset.steep_roof_to_wall <= 0 or preset.steep_roof_nz <= 0:
        return
    steep = (stuff == _R) & ~truth.occluder & (np.nan_to_num(truth.normal_z, nan=1.0) < preset.steep_roof_nz)
    stuff[_pick_components(steep, preset.steep_roof_to_wall, rng, truth.building)] = _W


def _low_walls(stuff, truth, preset, rng) -> None:
    if preset.low_wall_to_roof <= 0 or preset.low_wall_m <= 0:
        return
    low = (stuff == _W) & ~truth.occluder & (np.nan_to_num(truth.wall_height, nan=np.inf) < preset.low_wall_m)
    stuff[_pick_components(low, preset.low_wall_to_roof, rng, truth.building)] = _R


def _courtyards(stuff, preset, rng) -> None:
    if preset.courtyard_fill <= 0 or preset.courtyard_share <= 0:
        return
    open_ = ~np.isin(stuff, (_W, _R))
    comp, n = ndimage.label(open_)  # 4-connected (the building is 8-connected around it)
    draw = rng.random(n)
    if n == 0:
        return
    area = np.bincount(comp.reshape(-1), minlength=n + 1)
    border = np.unique(np.concatenate([comp[0], comp[-1], comp[:, 0], comp[:, -1]]))
    small = area < preset.courtyard_share * stuff.size
    small[border] = False
    small[0] = False
    fill = small & np.concatenate([[False], draw < preset.courtyard_fill])
    stuff[fill[comp]] = _R


def _buildings(stuff, truth, preset, rng) -> None:
    rng_small, rng_whole = (np.random.default_rng(s) for s in rng.integers(2**63, size=2))
    if preset.small_building_miss > 0 and preset.small_building_share > 0:
        comp, n = ndimage.label(np.isin(stuff, (_W, _R)), structure=_EIGHT)
        draw = rng_small.random(n)
        if n:
            area = np.bincount(comp.reshape(-1), minlength=n + 1)
            miss = (area < preset.small_building_share * stuff.size) & np.concatenate(
                [[False], draw < preset.small_building_miss]
            )
            miss[0] = False
            ids = np.flatnonzero(miss)
            to = _ring_mode(stuff, comp, ids, exclude=(_W, _R))
            to[to < 0] = _G
            lut = np.full(n + 1, -1, dtype=np.int64)
            lut[ids] = to
            new = lut[comp]
            sel = new >= 0
            stuff[sel] = new[sel]
    if preset.building_miss > 0:
        ids = np.unique(truth.building[truth.building >= 0])
        draw = rng_whole.random(len(ids))
        gone = ids[draw < preset.building_miss]
        if len(gone):
            sel = np.isin(truth.building, gone) & np.isin(stuff, (_W, _R))
            stuff[sel] = _G


def _cells(shape, cell_px: float, rng) -> np.ndarray:
    """(H, W) int64 cell index of a ``cell_px`` grid warped by a smooth displacement (irregular cells)."""
    h, w = shape
    amp = 0.35 * cell_px
    dy = smooth_field(rng, h, w, cell_px) * np.float32(amp)
    dx = smooth_field(rng, h, w, cell_px) * np.float32(amp)
    oy, ox = rng.uniform(0, cell_px, 2)
    rows = np.floor((np.arange(h)[:, None] + dy + oy) / cell_px).astype(np.int64)
    cols = np.floor((np.arange(w)[None, :] + dx + ox) / cell_px).astype(np.int64)
    return (rows + 2) * (w // max(int(cell_px), 1) + 8) + cols + 2


def _segment_swaps(stuff, truth, preset, rng) -> None:
    if not preset.segment_swaps:
        return
    cells = _cells(stuff.shape, float(preset.segment_cell_px), rng)
    key = (stuff.astype(np.int64) * (int(truth.building.max()) + 2) + truth.building + 1) * (
        int(cells.max()) + 1
    ) + cells
    uniq, inv = np.unique(key.reshape(-1), return_inverse=True)
    seg_cls = stuff.reshape(-1)[np.unique(inv, return_index=True)[1]]
    draw = rng.random(len(uniq))
    to = seg_cls.astype(np.int64).copy()
    for src in {s for s, _, _ in preset.segment_swaps}:
        acc = 0.0
        mine = seg_cls == src
        for s, d, prob in preset.segment_swaps:
            if s != src:
                continue
            sel = mine & (draw >= acc) & (draw < acc + prob)
            to[sel] = d
            acc += prob
    stuff[:] = to[inv].reshape(stuff.shape).astype(np.uint8)


def _shadows(stuff, truth, preset, rng) -> None:
    if preset.shadow_error <= 0:
        return
    h, w = stuff.shape
    field = smooth_field(rng, h, w, preset.shadow_cell_px)
    lit_ok = truth.shadow & np.isin(stuff, (_G, _W, _R))
    if not lit_ok.any():
        return
    thr = np.quantile(field[lit_ok], 1.0 - min(preset.shadow_error, 1.0))
    region = lit_ok & (field >= thr)
    comp, n = ndimage.label(region, structure=_EIGHT)
    if n == 0:
        return
    draw = rng.random(n)
    ids = np.arange(1, n + 1)
    own = np.zeros((n + 1, NUM_CLASSES), dtype=np.int64)
    np.add.at(own, (comp[region], stuff[region].astype(np.int64)), 1)
    majority = np.argmax(own[1:], axis=1)
    to = np.full(n, _B, dtype=np.int64)
    neighbour = draw >= preset.shadow_to_background
    if neighbour.any():
        # The most common class around each part other than its own majority class.
        around = np.full(n, -1, dtype=np.int64)
        for k in np.unique(majority[neighbour]):
            sel = neighbour & (majority == k)
            around[sel] = _ring_mode(stuff, comp, ids[sel], exclude=(k, _B))
        to = np.where(neighbour & (around >= 0), around, to)
    lut = np.concatenate([[-1], to])
    new = lut[comp]
    stuff[region] = new[region].astype(np.uint8)


def _bleed(stuff, truth, preset, rng) -> None:
    k = int(preset.bleed_px)
    if k <= 0:
        return
    h, w = stuff.shape
    width = np.clip(np.ceil(ndtr(smooth_field(rng, h, w, BLEED_CELL_PX) * 1.5) * k), 1, k).astype(np.int64)
    d0 = np.asarray(truth.depth, dtype=np.float64)
    d0 = np.where(np.isfinite(d0), d0, np.inf)
    need = np.maximum(BLEED_JUMP_REL * np.where(np.isfinite(d0), d0, 1e9), BLEED_JUMP_M)
    lab = stuff.copy()
    dep = d0.copy()
    for it in range(k):
        pd = np.pad(dep, 1, constant_values=np.inf)
        pl = np.pad(lab, 1)
        best_d = dep.copy()
        best_l = lab.copy()
        for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            nd = pd[1 + di : 1 + di + h, 1 + dj : 1 + dj + w]
            nl = pl[1 + di : 1 + di + h, 1 + dj : 1 + dj + w]
            take = (nd < best_d) & (nd < d0 - need) & (width > it)
            best_d = np.where(take, nd, best_d)
            best_l = np.where(take, nl, best_l)
        dep, lab = best_d, best_l
    stuff[:] = lab


def structured_errors(
    clean: np.ndarray, truth: ViewTruth, preset: SegPreset, rng: np.random.Generator
) -> np.ndarray:
    """(H, W) uint8: ``clean`` with the structured errors of ``preset`` (module docstring, steps 1-8).
    Windows and doors stay where their facade is still wall."""
    _check_truth(clean, truth)
    seeds = rng.integers(2**63, size=N_STEPS)
    r = [np.random.default_rng(int(s)) for s in seeds]
    stuff = np.where(np.isin(clean, (_WIN, _DOOR)), _W, clean).astype(np.uint8)
    _occluders(stuff, truth, preset.occluder_to_behind, r[0])
    _steep_roofs(stuff, truth, preset, r[1])
    _low_walls(stuff, truth, preset, r[2])
    _courtyards(stuff, preset, r[3])
    _buildings(stuff, truth, preset, r[4])
    _segment_swaps(stuff, truth, preset, r[5])
    _shadows(stuff, truth, preset, r[6])
    _bleed(stuff, truth, preset, r[7])
    opening = np.isin(clean, (_WIN, _DOOR)) & (stuff == _W)
    stuff[opening] = clean[opening]
    return stuff


def structured(preset: SegPreset) -> bool:
    """Whether any structured-error knob of ``preset`` is on."""
    return bool(
        preset.occluder_to_behind > 0
        or (preset.steep_roof_to_wall > 0 and preset.steep_roof_nz > 0)
        or (preset.low_wall_to_roof > 0 and preset.low_wall_m > 0)
        or (preset.courtyard_fill > 0 and preset.courtyard_share > 0)
        or (preset.small_building_miss > 0 and preset.small_building_share > 0)
        or preset.building_miss > 0
        or preset.segment_swaps
        or preset.shadow_error > 0
        or preset.bleed_px > 0
    )


def fold_to_map_classes(labels: np.ndarray, map_classes) -> np.ndarray:
    """``labels`` with windows and doors folded into wall when the map has none of that class (an LoD2
    map): a network trained on the map's labels never outputs a class the map does not have."""
    present = set(int(c) for c in np.asarray(map_classes).reshape(-1))
    absent = [c for c in (_WIN, _DOOR) if c not in present]
    if not absent:
        return labels
    out = np.array(labels, dtype=np.uint8, copy=True)
    out[np.isin(out, absent)] = _W
    return out


# The paper's mIoU of each quality (SemCityLockeD: trained DINOv3 head 88 %; Swiss-EPFL 78 %;
# zero-shot CLIP + Semantic-SAM 32 %, Grounded-SAM2 37 %).
SEG_TARGETS: dict[str, tuple[float, float]] = {
    "trained": (88.0, 88.0),
    "medium": (78.0, 78.0),
    "zero-shot": (32.0, 37.0),
}

REALISTIC_SEG_PRESETS: dict[str, SegPreset] = {
    "perfect": SegPreset("perfect", noise=False),
    # A head trained on the map's labels (paper: 88 % on SemCityLockeD): trees and cars mostly labelled as
    # what is behind them (the map has none), a few low walls and steep roofs swapped, small sheds and
    # courtyards sometimes missed, more errors in shadow, eaves bled 1 px, boundaries off by about a pixel.
    "trained": SegPreset(
        "trained",
        opening_to_wall=0.08,
        opening_warp=0.0,
        confusions=((_W, _R, 0.01, 40), (_R, _W, 0.01, 40), (_R, _G, 0.01, 48), (_G, _R, 0.01, 48)),
        blobs=0.3,
        blob_radius=(0.015, 0.04),
        boundary_px=0.75,
        dilate_px=0,
        patch_px=16,
        patch_detail=0.45,
        occluder_to_behind=0.95,
        steep_roof_nz=0.5,
        steep_roof_to_wall=0.3,
        low_wall_m=2.0,
        low_wall_to_roof=0.5,
        courtyard_share=0.003,
        courtyard_fill=0.3,
        small_building_share=0.001,
        small_building_miss=0.3,
        shadow_error=0.08,
        bleed_px=1,
    ),
    # A weaker trained head (paper: 78 % on Swiss-EPFL): more ground / roof confusion and shadow errors,
    # more steep roofs called wall and low walls called roof.
    "medium": SegPreset(
        "medium",
        opening_to_wall=0.12,
        opening_warp=0.0,
        confusions=((_W, _R, 0.01, 48), (_R, _W, 0.01, 48), (_R, _G, 0.05, 56), (_G, _R, 0.05, 56)),
        blobs=1.0,
        blob_radius=(0.02, 0.06),
        boundary_px=0.75,
        dilate_px=0,
        patch_px=16,
        patch_detail=0.45,
        occluder_to_behind=0.8,
        steep_roof_nz=0.6,
        steep_roof_to_wall=0.5,
        low_wall_m=2.0,
        low_wall_to_roof=0.5,
        courtyard_share=0.006,
        courtyard_fill=0.5,
        small_building_share=0.001,
        small_building_miss=0.3,
        shadow_error=0.28,
        bleed_px=1,
    ),
    # Zero-shot CLIP + Semantic-SAM / Grounded-SAM2 (paper: 32-37 %): whole SAM-like segments of the
    # wrong class (roofs called ground or wall, facades called roof or nothing, ground called roof),
    # 15 % of the buildings missed whole, small ones mostly, half the shadowed pixels wrong, 1-5 px bleed.
    "zero-shot": SegPreset(
        "zero-shot",
        opening_to_wall=0.4,
        opening_warp=0.0,
        blobs=1.0,
        blob_radius=(0.05, 0.15),
        boundary_px=3.0,
        dilate_px=2,
        patch_px=16,
        patch_detail=0.0,
        occluder_to_behind=0.5,
        steep_roof_nz=0.7,
        steep_roof_to_wall=0.7,
        low_wall_m=4.0,
        low_wall_to_roof=0.9,
        courtyard_share=0.02,
        courtyard_fill=0.7,
        small_building_share=0.005,
        small_building_miss=0.8,
        building_miss=0.15,
        segment_swaps=(
            (_R, _G, 0.25),
            (_R, _W, 0.2),
            (_W, _R, 0.25),
            (_W, _B, 0.15),
            (_G, _R, 0.15),
            (_G, _B, 0.15),
        ),
        segment_cell_px=128,
        shadow_error=0.5,
        bleed_px=5,
    ),
}

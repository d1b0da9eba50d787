"""How the simulated reality's buildings differ from the map's: per-building model errors (item 1 of the
``reality`` module docstring), roof structures missing from LoD2 (item 2), roof shapes that differ and
extra dormers (item 5), and buildings the map lacks (item 6).

Why a module of its own: these are the reality's changes to the buildings themselves, each a function of
the triangles (corners, classes, building per triangle) and its own random generator, called in the
documented order by ``reality.build_reality``. Missing buildings are a mask there; eaves overhangs
(item 4) are ``citymodel.eaves.overhang_roofs``, shared with the localizer's map.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from semcityloc.benchmark.footprints import FootprintGrid, open_ground_samples
from semcityloc.benchmark.meshes import box_corners, box_mesh
from semcityloc.benchmark.terrain_relief import TerrainHeight
from semcityloc.citymodel.eaves import FLAT_NZ
from semcityloc.citymodel.eaves import area_normal as _area_normal
from semcityloc.classes import SemanticClass

if TYPE_CHECKING:
    # for annotations only: ``reality`` imports this module, so importing it back would be a cycle
    from semcityloc.benchmark.reality import RealityParams

# Per-building roof changes (``RealityScene.building_roof_change`` holds the index).
ROOF_CHANGES = ("none", "gable", "hip", "flattened", "dormers")

RIDGE_RISE_M = (2.0, 5.0)  # ridge height above the eaves of a roof changed to gable / hip
GABLE_SHARE = 0.6  # of the flat roofs changed to a pitched one, the share made gable (the rest hip)
FLATTEN_SHARE = 0.5  # of the sloped roofs changed, the share flattened (the rest get dormers)
DORMERS_PER_ROOF = (2, 4)  # extra dormers on a changed sloped roof (inclusive)
MIN_BOX_FILL = 0.85  # a flat roof becomes pitched only when it fills this much of its oriented box
MAX_FLATTEN_RISE_M = 8.0  # a sloped roof is flattened only when it rises at most this much
NEW_SIZE_M = (8.0, 20.0)  # side lengths of a new building
NEW_HEIGHT_M = (4.0, 15.0)  # ground to top of a new building
NEW_CLEARANCE_M = 3.0  # a new building stands this far at least from any other building


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
    """Per-building xy shift and height change (``reality`` docstring, item 1): (corners, shift, dh)."""
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


def _points_in_triangles(rng: np.random.Generator, corners: np.ndarray) -> np.ndarray:
    """(n, 3): one point drawn uniformly in each of the (n, 3, 3) triangles ``corners`` (two uniforms each,
    drawn as two arrays of n, in that order)."""
    n = len(corners)
    r1, r2 = rng.random(n), rng.random(n)
    s1 = np.sqrt(r1)
    return (
        (1 - s1)[:, None] * corners[:, 0]
        + (s1 * (1 - r2))[:, None] * corners[:, 1]
        + (s1 * r2)[:, None] * corners[:, 2]
    )


def roof_structures(
    corners: np.ndarray,
    classes: np.ndarray,
    building: np.ndarray,
    grid: FootprintGrid,
    params: RealityParams,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Boxes on the roofs (``reality`` docstring, item 2): vertices, triangles, classes, building per
    triangle."""
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
    pt = _points_in_triangles(rng, c[pick])
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
    cx, cy = box_corners(pt, half, angle)
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
    v, t, is_top = box_mesh(pt[ok, :2], half[ok], angle[ok], z0[ok], z1[ok])
    cls = np.where(is_top, SemanticClass.ROOF, SemanticClass.WALL).astype(np.uint8)
    return v, t, cls, np.repeat(host[ok], 10)


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
    """Roof shapes that differ from the map's (``reality`` docstring, item 5).

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
    pt = _points_in_triangles(rng, c[pick])
    nrm = unit[pick]
    half = np.stack([rng.uniform(2.0, 4.0, n), rng.uniform(2.0, 3.0, n)], 1) / 2
    angle = np.arctan2(nrm[:, 1], nrm[:, 0]) - np.pi / 2
    return _roof_boxes(pt, half, angle, nrm, c[pick, 0], np.full(n, 0.2), b[pick], grid)


def new_buildings(
    dist: np.ndarray,
    grid: FootprintGrid,
    terrain: TerrainHeight,
    n: int,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Up to n buildings the map lacks (``reality`` docstring, item 6): (triangles (T, 3, 3), classes (T,),
    which new building (T,))."""
    empty = np.zeros((0, 3, 3)), np.zeros(0, np.uint8), np.zeros(0, np.int64)
    if n == 0:
        return empty
    m = 40 * n
    size = np.sort(rng.uniform(*NEW_SIZE_M, (m, 2)), axis=1)[:, ::-1]  # (length, width)
    radius = 0.5 * np.linalg.norm(size, axis=1)
    ok_cells = dist >= NEW_CLEARANCE_M + NEW_SIZE_M[0] / np.sqrt(2)
    xy, d = open_ground_samples(dist, ok_cells, grid, m, rng)
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

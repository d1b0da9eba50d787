"""Roof eaves: pitched roofs moved out over their walls, for the simulated reality and the localizer's map.

Why: LoD2 models (the German states' among them) cut a roof at its walls, while a real pitched roof
overhangs them by 0.3-1 m. Seen from the air the eaves hide the top of the walls and move every roof
outline outward; a map without them is biased at exactly the scale a localizer is judged at. The
simulated reality adds them (``benchmark.reality``, item 4: a random amount per building); the
localizer can add a fixed, stated amount to its map (``LocalizerConfig.map_eaves_m``, ``with_eaves``).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from semcityloc.citymodel.model import CityModel
from semcityloc.classes import BUILDING_CLASSES, SemanticClass

KEY_M = 0.01  # roof vertices closer than this are one vertex
FLAT_NZ = np.cos(np.radians(10.0))  # a roof triangle within 10 deg of horizontal is flat


def area_normal(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(area (T,), unit normal (T, 3)) of triangles (T, 3, 3)."""
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    norm = np.linalg.norm(n, axis=1)
    return 0.5 * norm, n / np.maximum(norm, 1e-12)[:, None]


def _unique_rows(key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(index of each distinct row's first occurrence, in the rows' lexicographic order; the distinct
    row's number for every row) of an int (N, K) array: ``np.unique(key, axis=0, return_index=True,
    return_inverse=True)[1:]`` by a stable lexsort, several times faster on large models."""
    if not len(key):
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    order = np.lexsort(key.T[::-1])
    ordered = key[order]
    starts = np.ones(len(key), dtype=bool)
    starts[1:] = np.any(ordered[1:] != ordered[:-1], axis=1)
    inverse = np.empty(len(key), dtype=np.intp)
    inverse[order] = np.cumsum(starts) - 1
    return order[starts], inverse


def overhang_roofs(
    corners: np.ndarray,
    classes: np.ndarray,
    building: np.ndarray,
    overhang_m: np.ndarray,
    flat_roofs: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Roof overhangs of ``overhang_m`` (B,) metres per building (``building`` indexes it): (corners,
    overhang (B,) m, 0 where nothing moved). ``flat_roofs=False``: a building whose roof is more than
    half flat (within 10 deg of horizontal) gets none.

    Roof vertices closer than 1 cm are one vertex; a roof edge used by one roof triangle only whose two
    ends lie on the building's walls (within 3 cm in x, y) is an outline edge, its outward normal the one
    pointing away from its triangle. Each outline vertex moves horizontally by d solving d . n = o for
    the normals n of its outline edges (least squares: the miter at a corner, capped at 2 o), where o is
    the building's overhang, or 0 on an edge shared with another building (a party wall: the roof
    slides along it, it does not grow into the neighbour); its height follows the adjacent roof planes
    (an eave drops by o x the slope), so the roof keeps its planes and meets the walls where it did."""
    over = np.asarray(overhang_m, dtype=np.float64)
    n_buildings = len(over)
    roof = np.flatnonzero(classes == SemanticClass.ROOF)
    if len(roof) == 0 or not np.any(over > 0):
        return corners, np.zeros(n_buildings)
    c = corners[roof]
    rb = building[roof]
    if not flat_roofs:
        area, unit = area_normal(c)
        flat = np.bincount(rb, area * (np.abs(unit[:, 2]) > FLAT_NZ), n_buildings)
        total = np.bincount(rb, area, n_buildings)
        over = np.where(flat > 0.5 * np.maximum(total, 1e-12), 0.0, over)
    pts = c.reshape(-1, 3)
    pb = np.repeat(rb, 3)
    key = np.column_stack([pb, np.round(pts / KEY_M).astype(np.int64)])
    first, vid = _unique_rows(key)
    vid = vid.reshape(-1, 3)
    vpos, vb = pts[first], pb[first]
    nv = len(first)
    ea, eb, et = vid.reshape(-1), vid[:, [1, 2, 0]].reshape(-1), vid[:, [2, 0, 1]].reshape(-1)
    ekey = np.minimum(ea, eb) * nv + np.maximum(ea, eb)
    _, einv, ecount = np.unique(ekey, return_inverse=True, return_counts=True)
    outline = (ecount[einv] == 1) & (ea != eb)

    # Which roof vertices lie on the building's walls / on another building (x, y within 3 cm).
    walls = np.isin(classes, (SemanticClass.WALL, SemanticClass.WINDOW, SemanticClass.DOOR))
    wxy = corners[walls][:, :, :2].reshape(-1, 2)
    wb = np.repeat(building[walls], 3)
    sep = 1e6  # buildings apart in the tree's third coordinate
    on_wall = np.zeros(nv, dtype=bool)
    if len(wxy):
        d, _ = cKDTree(np.column_stack([wxy, wb * sep])).query(np.column_stack([vpos[:, :2], vb * sep]))
        on_wall = d <= 0.03
    bmask = np.isin(classes, BUILDING_CLASSES)
    axy = corners[bmask][:, :, :2].reshape(-1, 2)
    ab = np.repeat(building[bmask], 3)
    akey = np.column_stack([ab, np.round(axy / KEY_M).astype(np.int64)])
    akey = akey[_unique_rows(akey)[0]]
    pairs = cKDTree(vpos[:, :2]).sparse_distance_matrix(
        cKDTree(akey[:, 1:] * KEY_M), 0.03, output_type="ndarray"
    )
    shared = np.zeros(nv, dtype=bool)
    shared[pairs["i"][akey[pairs["j"], 0] != vb[pairs["i"]]]] = True

    e = outline & on_wall[ea] & on_wall[eb]
    a, b, t = ea[e], eb[e], et[e]
    dxy = vpos[b, :2] - vpos[a, :2]
    n = np.stack([dxy[:, 1], -dxy[:, 0]], 1) / np.linalg.norm(dxy, axis=1)[:, None]
    n *= np.where(((vpos[t, :2] - vpos[a, :2]) * n).sum(1) > 0, -1.0, 1.0)[:, None]
    target = np.where(shared[a] & shared[b], 0.0, over[vb[a]])
    axx, axy_, ayy, bx, by = (np.zeros(nv) for _ in range(5))
    for end in (a, b):
        np.add.at(axx, end, n[:, 0] ** 2)
        np.add.at(axy_, end, n[:, 0] * n[:, 1])
        np.add.at(ayy, end, n[:, 1] ** 2)
        np.add.at(bx, end, target * n[:, 0])
        np.add.at(by, end, target * n[:, 1])
    eps = 1e-9
    det = (axx + eps) * (ayy + eps) - axy_**2
    move = np.stack([((ayy + eps) * bx - axy_ * by) / det, ((axx + eps) * by - axy_ * bx) / det], 1)
    length = np.linalg.norm(move, axis=1)
    cap = 2.0 * over[vb]
    move *= np.where(length > cap, cap / np.maximum(length, 1e-12), 1.0)[:, None]
    # Height: the mean over the vertex's roof triangles of their planes' rise along the move.
    _, unit = area_normal(c)
    nz = unit[:, 2:3]
    slope = np.where(np.abs(nz) > 0.2, -unit[:, :2] / np.where(np.abs(nz) > 0.2, nz, 1.0), 0.0)
    slope = np.clip(slope, -np.tan(np.radians(60)), np.tan(np.radians(60)))
    gsum = np.zeros((nv, 2))
    gcnt = np.zeros(nv)
    for k in range(3):
        np.add.at(gsum, vid[:, k], slope)
        np.add.at(gcnt, vid[:, k], 1.0)
    dz = (move * gsum).sum(1) / np.maximum(gcnt, 1.0)
    out = corners.copy()
    out[roof, :, :2] += move[vid]
    out[roof, :, 2] += dz[vid]
    moved = np.zeros(n_buildings, dtype=bool)
    moved[vb[length > 1e-9]] = True
    return out, np.where(moved, over, 0.0)


def with_eaves(model: CityModel, overhang_m: float, flat_roofs: bool = False) -> CityModel:
    """``model`` with every pitched roof moved out by ``overhang_m`` over its walls (``overhang_roofs``
    with a fixed amount; mostly flat roofs end in parapets and keep their outline unless ``flat_roofs``;
    an edge on a party wall does not grow into the neighbour). Walls, ground and everything else
    unchanged; same origin, CRS, classes and building indices. ``overhang_m`` <= 0 returns ``model``
    itself."""
    if not overhang_m > 0.0 or model.num_triangles == 0:
        return model
    corners = model.vertices[model.triangles].astype(np.float64)
    amount = np.full(len(model.building_ids), float(overhang_m))
    moved, _ = overhang_roofs(
        corners, model.classes, model.building_index.astype(np.int64), amount, flat_roofs=flat_roofs
    )
    return CityModel(
        origin=model.origin.copy(),
        vertices=moved.reshape(-1, 3).astype(np.float32),
        triangles=np.arange(3 * len(moved)).reshape(-1, 3),
        classes=model.classes,
        building_index=model.building_index,
        lods=model.lods,
        building_ids=model.building_ids,
        crs=model.crs,
        source_crs=model.source_crs,
        source=f"{model.source or 'model'} with {overhang_m:g} m eaves{' on flat roofs too' * flat_roofs}",
    )

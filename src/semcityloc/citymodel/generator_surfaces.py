"""A generated building's planar polygons at LoD 1, 2 or 3 (``Surface``): the geometry shared by the
generated city's CityGML files (``citymodel.citygml_writer``) and its ``CityModel``
(``citymodel.generator.footprints_to_model``), so both hold exactly the same buildings.

- LoD1: the footprint extruded from its ground height to ``Footprint.lod1_z`` = eaves + half the roof
  height (the volume-equivalent height of gable and mono-pitch roofs): ground, one wall per footprint
  edge, a flat top;
- LoD2: ground, one wall per footprint edge up to the roof (gable ends up to the ridge, mono-pitch walls
  along the slope) and the roof planes (flat and mono-pitch 1, gable 2, hip 4);
- LoD3: the LoD2 shapes with Window (1.2 x 1.5 m, sills 0.9 m above each 3 m floor, columns every 3 m)
  and Door (1.0 x 2.1 m on a 0.1 m step, on the street side) openings; each wall polygon carries the
  matching interior rings. Party walls (a neighbour directly behind) get no openings.
All polygons are counter-clockwise seen from outside (CityGML rule); interior rings run the other way.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from semcityloc.citymodel.generator_footprints import STOREY_M, Footprint
from semcityloc.errors import ParameterError

WINDOW_W_M, WINDOW_H_M, WINDOW_SILL_M = 1.2, 1.5, 0.9
WINDOW_PITCH_M = 3.0  # distance between window columns
WINDOW_END_MARGIN_M = 0.8  # free wall at both ends of a facade
WINDOW_TOP_CLEARANCE_M = 0.3  # free wall between a window top and the eaves / gable edge
DOOR_W_M, DOOR_H_M, DOOR_STEP_M = 1.0, 2.1, 0.1
PARTY_WALL_PROBE_M = 0.3  # a wall point pushed this far outward inside a neighbour = party wall
SECOND_DOOR_PERIMETER_M = 60.0  # buildings with a longer perimeter get a second door


@dataclass(eq=False)
class Surface:
    """One planar polygon of a building: ``kind`` is a CityGML name (WallSurface, RoofSurface,
    GroundSurface, Window, Door); rings are (n, 3) world coordinates without closing point, the exterior
    counter-clockwise seen from outside, interiors the other way round."""

    kind: str
    exterior: np.ndarray
    interiors: list[np.ndarray] = field(default_factory=list)
    openings: list[Surface] = field(default_factory=list)


def _with_z(xy: np.ndarray, z) -> np.ndarray:
    z = np.broadcast_to(np.asarray(z, dtype=np.float64), (len(xy),))
    return np.column_stack([xy, z])


def _mono_z(fp: Footprint, xy: np.ndarray) -> np.ndarray:
    """Height of the mono-pitch roof plane at xy: eaves at the low edge, ridge at the high edge."""
    axis = np.array(fp.roof_axis)
    d = fp.polygon @ axis
    t = (np.asarray(xy) @ axis - d.min()) / max(float(np.ptp(d)), 1e-9)
    return fp.eaves_z + (fp.ridge_z - fp.eaves_z) * t


def _wall_profiles(fp: Footprint) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per footprint edge p -> q: (p, q, top profile (k, 2) of (distance from p, height), ascending)."""
    poly = fp.polygon
    out = []
    for i in range(len(poly)):
        p, q = poly[i], poly[(i + 1) % len(poly)]
        length = float(np.linalg.norm(q - p))
        if fp.roof_type == "mono":
            prof = [(0.0, float(_mono_z(fp, p))), (length, float(_mono_z(fp, q)))]
        elif fp.roof_type == "gable" and i in (1, 3):  # the gable ends of a rectangle
            prof = [(0.0, fp.eaves_z), (length / 2.0, fp.ridge_z), (length, fp.eaves_z)]
        else:
            prof = [(0.0, fp.eaves_z), (length, fp.eaves_z)]
        out.append((p, q, np.array(prof)))
    return out


def _wall_ring(p: np.ndarray, q: np.ndarray, ground_z: float, profile: np.ndarray) -> np.ndarray:
    """Wall polygon: bottom p, bottom q, then the top profile back from q to p (CCW seen from outside)."""
    t = (q - p) / np.linalg.norm(q - p)
    top = [np.array([*(p + t * s), z]) for s, z in profile[::-1]]
    return np.array([[*p, ground_z], [*q, ground_z], *top])


def _roof_surfaces(fp: Footprint) -> list[np.ndarray]:
    poly, e, r = fp.polygon, fp.eaves_z, fp.ridge_z
    if fp.roof_type == "flat":
        return [_with_z(poly, e)]
    if fp.roof_type == "mono":
        return [_with_z(poly, _mono_z(fp, poly))]
    p0, p1, p2, p3 = (_with_z(poly[i : i + 1], e)[0] for i in range(4))
    m12 = np.array([*(poly[1] + poly[2]) / 2.0, r])
    m30 = np.array([*(poly[3] + poly[0]) / 2.0, r])
    if fp.roof_type == "gable":
        return [np.array([p0, p1, m12, m30]), np.array([p2, p3, m30, m12])]
    # hip: ridge shortened by half the width at each end (45-degree hips in plan)
    u = (poly[1] - poly[0]) / np.linalg.norm(poly[1] - poly[0])
    half_w = 0.5 * float(np.linalg.norm(poly[2] - poly[1]))
    h1 = np.array([*(m12[:2] - u * half_w), r])
    h0 = np.array([*(m30[:2] + u * half_w), r])
    return [
        np.array([p0, p1, h1, h0]),
        np.array([p2, p3, h0, h1]),
        np.array([p1, p2, h1]),
        np.array([p3, p0, h0]),
    ]


def _inside(pts: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd point in polygon test: (k, 2) points -> (k,) bool."""
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    x, y = poly[:, 0], poly[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    py, px = pts[:, 1:2], pts[:, 0:1]
    cross = (y > py) != (yn > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        xs = x + (py - y) * (xn - x) / (yn - y)
    return np.count_nonzero(cross & (px < xs), axis=1) % 2 == 1


def _window_columns(length: float) -> np.ndarray:
    """Distances from the wall start of the window column centres, centred on the facade."""
    usable = length - 2.0 * WINDOW_END_MARGIN_M
    if usable < WINDOW_W_M:
        return np.zeros(0)
    n = int((usable - WINDOW_W_M) // WINDOW_PITCH_M) + 1
    return length / 2.0 + (np.arange(n) - (n - 1) / 2.0) * WINDOW_PITCH_M


def _opening_ring(p, t, s0, s1, z0, z1) -> np.ndarray:
    """Rectangle on the wall through p with direction t: CCW seen from outside."""
    return np.array([[*(p + t * s0), z0], [*(p + t * s1), z0], [*(p + t * s1), z1], [*(p + t * s0), z1]])


def _openings(fp: Footprint, profiles, neighbours) -> list[list[Surface]]:
    """Windows and doors per wall (LoD3)."""
    lo, hi = fp.polygon.min(0) - 1.0, fp.polygon.max(0) + 1.0
    others = [
        n.polygon
        for n in neighbours
        if n.id != fp.id and np.all(n.polygon.max(0) >= lo) and np.all(n.polygon.min(0) <= hi)
    ]
    centre = np.array(fp.block_centre)
    columns: list[list[float]] = []
    candidates = []  # (facing the street, length, wall index) of walls with a free column
    for w, (p, q, _prof) in enumerate(profiles):
        length = float(np.linalg.norm(q - p))
        t = (q - p) / length
        out = np.array([t[1], -t[0]])
        cols = _window_columns(length)
        probes = p + np.outer(cols, t) + out * PARTY_WALL_PROBE_M
        party = np.zeros(len(cols), dtype=bool)
        for o in others:
            party |= _inside(probes, o)
        free = [float(s) for s in cols[~party]]
        columns.append(free)
        mid = (p + q) / 2.0
        away = mid - centre
        facing = float(out @ away / max(np.linalg.norm(away), 1e-9))
        if free:
            candidates.append((facing >= 0.5, length, -w, w))
    candidates.sort(reverse=True)
    perimeter = float(np.sum(np.linalg.norm(np.roll(fp.polygon, -1, 0) - fp.polygon, axis=1)))
    n_doors = 2 if perimeter > SECOND_DOOR_PERIMETER_M else 1
    doors: dict[int, float] = {}
    for cand in candidates[:n_doors]:
        free = columns[cand[3]]
        doors[cand[3]] = free[len(free) // 2]

    result = []
    for w, (p, q, prof) in enumerate(profiles):
        t = (q - p) / np.linalg.norm(q - p)
        items: list[Surface] = []
        for s in columns[w]:
            half = WINDOW_W_M / 2.0
            top = float(
                min(np.interp(s - half, prof[:, 0], prof[:, 1]), np.interp(s + half, prof[:, 0], prof[:, 1]))
            )
            if doors.get(w) == s:
                z0 = fp.ground_z + DOOR_STEP_M
                ring = _opening_ring(p, t, s - DOOR_W_M / 2.0, s + DOOR_W_M / 2.0, z0, z0 + DOOR_H_M)
                items.append(Surface("Door", ring))
                first_floor = 1
            else:
                first_floor = 0
            floor = first_floor
            while True:
                z0 = fp.ground_z + floor * STOREY_M + WINDOW_SILL_M
                if z0 + WINDOW_H_M + WINDOW_TOP_CLEARANCE_M > top:
                    break
                items.append(Surface("Window", _opening_ring(p, t, s - half, s + half, z0, z0 + WINDOW_H_M)))
                floor += 1
        result.append(items)
    return result


def building_surfaces(fp: Footprint, lod: int, neighbours: list[Footprint] | tuple = ()) -> list[Surface]:
    """The polygons of one building at ``lod`` (1, 2 or 3); ``neighbours`` (its block's footprints)
    decide which walls are party walls without openings (LoD3 only)."""
    lod = check_lod(lod)
    ring = fp.polygon
    ground = Surface("GroundSurface", _with_z(ring[::-1], fp.ground_z))
    if lod == 1:
        top = fp.lod1_z
        walls = [
            Surface(
                "WallSurface",
                _wall_ring(p, q, fp.ground_z, np.array([(0.0, top), (np.linalg.norm(q - p), top)])),
            )
            for p, q in zip(ring, np.roll(ring, -1, axis=0), strict=True)
        ]
        return [ground, *walls, Surface("RoofSurface", _with_z(ring, top))]
    profiles = _wall_profiles(fp)
    walls = [Surface("WallSurface", _wall_ring(p, q, fp.ground_z, prof)) for p, q, prof in profiles]
    if lod == 3:
        for wall, items in zip(walls, _openings(fp, profiles, neighbours), strict=True):
            wall.openings = items
            wall.interiors = [o.exterior[::-1] for o in items]
    roofs = [Surface("RoofSurface", r) for r in _roof_surfaces(fp)]
    return [ground, *walls, *roofs]


def check_lod(lod) -> int:
    """``lod`` as an int if it is 1, 2 or 3; anything else a ParameterError."""
    if lod not in (1, 2, 3) or isinstance(lod, bool):
        raise ParameterError(f"the generator writes LoD 1, 2 or 3, not {lod!r}")
    return int(lod)


def _by_block(footprints: list[Footprint]) -> dict[tuple[int, int], list[Footprint]]:
    groups: dict[tuple[int, int], list[Footprint]] = {}
    for fp in footprints:
        groups.setdefault(fp.block, []).append(fp)
    return groups


def city_surfaces(footprints: list[Footprint], lod: int) -> list[tuple[Footprint, list[Surface]]]:
    """Every building with its polygons at ``lod``, in footprint order; its block's other buildings are the
    neighbours that make party walls."""
    groups = _by_block(footprints)
    return [(fp, building_surfaces(fp, lod, groups[fp.block])) for fp in footprints]

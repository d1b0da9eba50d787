"""Procedural city district written as CityGML 2.0: the embedded default city of semcityloc.

Why: the demo and every test that must run without ``../shared`` need a realistic semantic city with
known ground truth. ``generate_city`` writes ``generated_lod1.gml``, ``generated_lod2.gml`` and
``generated_lod3.gml`` from the SAME footprints (same building ids), deterministically for a seed (the
files are byte-identical across runs: one seeded ``numpy`` generator, every coordinate rounded to the
millimetre and printed with three decimals).

The district (``generate_footprints``):
- a street grid (streets 12-20 m wide) around ``blocks`` = (columns, rows) blocks of 60-100 m, its
  south-west corner at ``origin``; three block styles: *perimeter* (touching buildings along the block
  edges, L-shaped corner buildings, a courtyard, occasional passages), *detached* (houses on lots, some
  rotated a few degrees) and *towers* (a 36-45 m tower beside a lower tower or a low L-shaped hall);
- rectangular and L-shaped footprints of 8-40 m, heights 6-45 m, eaves heights varying per building;
- roofs: flat, gable (ridge along the long axis, in x or y), hip (45-degree hips in plan) and mono-pitch;
  L-shaped footprints get flat or mono-pitch roofs only;
- the ground is a tilted plane (1-2 % slope, seeded direction) around ``BASE_GROUND_Z`` at the district
  centre; a building's ground floor lies at the lowest terrain height under its footprint, so a
  flat-ground assumption is wrong by up to several metres across the district.

The files:
- LoD1: every footprint extruded from its ground height to ``Footprint.lod1_z`` = eaves + half the roof
  height (the volume-equivalent height of gable and mono-pitch roofs) as ``bldg:lod1Solid`` WITHOUT
  semantics, as real LoD1 products are: readers classify those faces by their normals;
- LoD2: ``bldg:boundedBy`` Roof/Wall/GroundSurface features (one polygon each) and a ``bldg:lod2Solid``
  whose surface members xlink (``xlink:href="#id"``) to those polygons, as state LoD2 products do;
- LoD3: the LoD2 shapes with ``bldg:opening`` Window (1.2 x 1.5 m, sills 0.9 m above each 3 m floor,
  columns every 3 m) and Door (1.0 x 2.1 m on a 0.1 m step, on the street side) features; each wall
  polygon carries the matching interior rings, and a ``bldg:lod3Solid`` xlinks the walls, roofs, ground
  and openings (a closed shell). Party walls (a neighbour directly behind) get no openings.
All polygons are counter-clockwise seen from outside (CityGML rule); interior rings run the other way.

``footprints_to_model`` turns the same surfaces straight into a ``CityModel`` (no XML round trip) -- the
one generated city of the library (tests, benchmarks, demo); ``tile_model`` repeats a model side by side
for a bigger one; ``default_city_path`` generates the default district once into a user cache directory.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from lxml import etree

from semcityloc.cache import cache_root
from semcityloc.citymodel.builder import MeshBuilder
from semcityloc.citymodel.crs import parse_crs_name
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import SURFACE_CLASS
from semcityloc.errors import CRSError, InputFileError, ParameterError

GENERATOR_VERSION = 1  # bump whenever the output of the same parameters changes (cache key)

DEFAULT_SEED = 0
DEFAULT_BLOCKS = (4, 3)
DEFAULT_LODS = (1, 2, 3)
DEFAULT_CRS = "EPSG:25832"
DEFAULT_ORIGIN = (690000.0, 5336000.0)
MAX_BLOCKS_PER_AXIS = 30

BASE_GROUND_Z = 520.0  # terrain height at the district centre (metres, roughly Munich)
STREET_WIDTH_M = (12.0, 20.0)
BLOCK_SIZE_M = (60.0, 100.0)
STOREY_M = 3.0
WINDOW_W_M, WINDOW_H_M, WINDOW_SILL_M = 1.2, 1.5, 0.9
WINDOW_PITCH_M = 3.0  # distance between window columns
WINDOW_END_MARGIN_M = 0.8  # free wall at both ends of a facade
WINDOW_TOP_CLEARANCE_M = 0.3  # free wall between a window top and the eaves / gable edge
DOOR_W_M, DOOR_H_M, DOOR_STEP_M = 1.0, 2.1, 0.1
PARTY_WALL_PROBE_M = 0.3  # a wall point pushed this far outward inside a neighbour = party wall
SECOND_DOOR_PERIMETER_M = 60.0  # buildings with a longer perimeter get a second door

ROOF_TYPES = ("flat", "gable", "hip", "mono")
ROOF_TYPE_CODES = {"flat": "1000", "mono": "1010", "gable": "1030", "hip": "1040"}  # AdV roofType codes
ROOF_TYPE_CODESPACE = "http://www.sig3d.org/codelists/citygml/2.0/building/2.0/_AbstractBuilding_roofType.xml"

CORE_NS = "http://www.opengis.net/citygml/2.0"
BLDG_NS = "http://www.opengis.net/citygml/building/2.0"
GML_NS = "http://www.opengis.net/gml"
XLINK_NS = "http://www.w3.org/1999/xlink"
XSI_NS = "http://www.w3.org/2001/XMLSchema-instance"
SCHEMA_LOCATION = (
    "http://www.opengis.net/citygml/2.0 http://schemas.opengis.net/citygml/2.0/cityGMLBase.xsd "
    "http://www.opengis.net/citygml/building/2.0 http://schemas.opengis.net/citygml/building/2.0/building.xsd"
)


GeneratorParameterError = ParameterError  # kept as a name for callers; the class lives in semcityloc.errors


@dataclass(eq=False)
class Footprint:
    """One generated building, enough to rebuild every LoD.

    ``polygon``: (n, 2) float64 world x, y (millimetre-rounded), counter-clockwise seen from above, no
    closing point. For rectangles the edge ``polygon[0] -> polygon[1]`` is a long side (the ridge of a
    gable or hip roof runs along it). ``roof_axis``: unit xy vector, the ridge direction of gable/hip
    roofs, the up-slope direction of mono-pitch roofs, the long axis for flat roofs.
    """

    id: str
    polygon: np.ndarray
    ground_z: float
    eaves_z: float
    ridge_z: float  # highest roof point; equals eaves_z for flat roofs
    roof_type: str
    roof_axis: tuple[float, float]
    block: tuple[int, int]
    block_style: str
    block_centre: tuple[float, float]  # doors face away from it (the street side)

    @property
    def height(self) -> float:
        """Measured height: ground to the highest roof point."""
        return self.ridge_z - self.ground_z

    @property
    def lod1_z(self) -> float:
        """Top of the LoD1 block: eaves + half the roof height (volume-equivalent for gable/mono)."""
        return round(self.eaves_z + 0.5 * (self.ridge_z - self.eaves_z), 3)

    @property
    def is_rectangle(self) -> bool:
        return len(self.polygon) == 4

    @property
    def area(self) -> float:
        x, y = self.polygon[:, 0], self.polygon[:, 1]
        return float(0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))

    @property
    def storeys(self) -> int:
        return max(1, int((self.eaves_z - self.ground_z) // STOREY_M))


@dataclass(eq=False)
class Surface:
    """One planar polygon of a building: ``kind`` is a CityGML name (WallSurface, RoofSurface,
    GroundSurface, Window, Door); rings are (n, 3) world coordinates without closing point, the exterior
    counter-clockwise seen from outside, interiors the other way round."""

    kind: str
    exterior: np.ndarray
    interiors: list[np.ndarray] = field(default_factory=list)
    openings: list[Surface] = field(default_factory=list)


# ---------------------------------------------------------------------------------------------- layout
def _q(value: float, step: float) -> float:
    """Round to a multiple of ``step`` (layout numbers stay short and exactly reproducible)."""
    return float(round(float(value) / step) * step)


def _rect(cx: float, cy: float, sx: float, sy: float, angle_deg: float = 0.0) -> np.ndarray:
    """Rectangle sx by sy around (cx, cy), counter-clockwise, corner 0 -> 1 along a long side."""
    hx, hy = sx / 2.0, sy / 2.0
    if hx >= hy:
        pts = np.array([(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)])
    else:
        pts = np.array([(hx, -hy), (hx, hy), (-hx, hy), (-hx, -hy)])
    a = math.radians(angle_deg)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    return pts @ rot.T + (cx, cy)


def _l_shape(a: float, b: float, wa: float, wb: float) -> np.ndarray:
    """L with outer box a (x) by b (y) at the origin, arm widths wa (vertical arm) and wb (horizontal)."""
    return np.array([(0, 0), (a, 0), (a, wb), (wa, wb), (wa, b), (0, b)], dtype=np.float64)


def _mirror(poly: np.ndarray, w: float, h: float, flip_x: bool, flip_y: bool) -> np.ndarray:
    """Mirror inside a w by h box; a single mirror reverses the ring to keep it counter-clockwise."""
    out = poly.copy()
    if flip_x:
        out[:, 0] = w - out[:, 0]
    if flip_y:
        out[:, 1] = h - out[:, 1]
    if flip_x != flip_y:
        out = out[::-1]
    return out


def _rotate_quarter(poly: np.ndarray, quarters: int) -> np.ndarray:
    """Rotate by quarters * 90 degrees about the origin (orientation preserved)."""
    out = poly.copy()
    for _ in range(quarters % 4):
        out = np.stack([-out[:, 1], out[:, 0]], axis=1)
    return out


@dataclass
class _Shape:
    polygon: np.ndarray  # block-local
    roof_type: str
    eaves_h: float  # above ground
    roof_h: float  # ridge above eaves
    roof_axis: tuple[float, float]


def _unit(v: np.ndarray) -> tuple[float, float]:
    n = float(np.hypot(v[0], v[1]))
    return (float(v[0]) / n, float(v[1]) / n)


def _rect_roof(rng: np.random.Generator, poly: np.ndarray, eaves_h: float, weights) -> _Shape:
    """A rectangle with a roof drawn from ``weights`` over ROOF_TYPES (hip needs a clearly long side)."""
    long = float(np.linalg.norm(poly[1] - poly[0]))
    short = float(np.linalg.norm(poly[2] - poly[1]))
    roof = str(rng.choice(ROOF_TYPES, p=weights))
    u = _unit(poly[1] - poly[0])
    if roof == "hip" and long - short < 2.0:
        roof = "gable"
    if roof in ("gable", "hip"):
        rise = 0.5 * short * math.tan(math.radians(rng.uniform(30.0, 45.0)))
        return _Shape(poly, roof, eaves_h, _q(rise, 0.01), u)
    if roof == "mono":
        sign = 1.0 if rng.random() < 0.5 else -1.0
        axis = (-u[1] * sign, u[0] * sign)
        rise = short * math.tan(math.radians(rng.uniform(8.0, 18.0)))
        return _Shape(poly, roof, eaves_h, _q(rise, 0.01), axis)
    return _Shape(poly, "flat", eaves_h, 0.0, u)


def _l_roof(rng: np.random.Generator, poly: np.ndarray, eaves_h: float, p_mono: float = 0.4) -> _Shape:
    """An L-shaped footprint with a flat or mono-pitch roof."""
    if rng.random() < p_mono:
        axis = [(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)][int(rng.integers(4))]
        extent = float(np.ptp(poly @ np.array(axis)))
        rise = extent * math.tan(math.radians(rng.uniform(5.0, 10.0)))
        return _Shape(poly, "mono", eaves_h, _q(rise, 0.01), axis)
    return _Shape(poly, "flat", eaves_h, 0.0, (1.0, 0.0))


def _eaves(rng: np.random.Generator, storeys: int) -> float:
    return storeys * STOREY_M + _q(rng.uniform(0.3, 1.2), 0.1)


def _split_side(rng: np.random.Generator, length: float) -> list[float]:
    """Cut a block side into building lengths of 8-40 m (a remainder of >= 8 m guaranteed)."""
    pieces, rest = [], length
    while rest > 40.0:
        p = _q(rng.uniform(10.0, min(30.0, rest - 10.0)), 0.5)
        pieces.append(p)
        rest -= p
    pieces.append(rest)
    return pieces


def _perimeter_block(rng: np.random.Generator, w: float, h: float) -> list[_Shape]:
    """Touching buildings along the four block edges around a courtyard; L-shaped corners."""
    depth = _q(rng.uniform(10.0, 16.0), 0.5)
    storeys = int(rng.integers(4, 8))
    rect_weights = (0.3, 0.4, 0.15, 0.15)

    def storeys_here() -> int:
        return int(np.clip(storeys + int(rng.integers(-1, 2)), 3, 8))

    shapes: list[_Shape] = []
    arms: dict[str, tuple[float, float]] = {}
    for corner in ("sw", "se", "ne", "nw"):
        la = _q(rng.uniform(depth + 6.0, 26.0), 0.5)
        lb = _q(rng.uniform(depth + 6.0, 26.0), 0.5)
        arms[corner] = (la, lb)
        poly = _mirror(_l_shape(la, lb, depth, depth), w, h, corner in ("se", "ne"), corner in ("ne", "nw"))
        shapes.append(_l_roof(rng, poly, _eaves(rng, storeys_here())))

    # (start, end, along-x?, at the far edge?) for south, north, west, east sides
    sides = [
        (arms["sw"][0], w - arms["se"][0], True, False),
        (arms["nw"][0], w - arms["ne"][0], True, True),
        (arms["sw"][1], h - arms["nw"][1], False, False),
        (arms["se"][1], h - arms["ne"][1], False, True),
    ]
    for start, end, along_x, far in sides:
        pos = start
        pieces = _split_side(rng, end - start)
        for k, length in enumerate(pieces):
            a, b = pos, pos + length
            pos = b
            if k < len(pieces) - 1 and length >= 16.0 and rng.random() < 0.2:
                b -= _q(rng.uniform(3.0, 5.0), 0.5)  # a passage into the courtyard
            d = depth + float(rng.choice([-1.0, 0.0, 0.0, 1.0, 2.0]))
            across = (h if along_x else w) - d / 2.0 if far else d / 2.0
            if along_x:
                poly = _rect((a + b) / 2.0, across, b - a, d)
            else:
                poly = _rect(across, (a + b) / 2.0, d, b - a)
            shapes.append(_rect_roof(rng, poly, _eaves(rng, storeys_here()), rect_weights))
    return shapes


def _detached_block(rng: np.random.Generator, w: float, h: float) -> list[_Shape]:
    """Houses on a grid of lots, some L-shaped, rectangles rotated up to 8 degrees."""
    nlx, nly = max(2, int(w // 30.0)), max(2, int(h // 30.0))
    lot_w, lot_h = w / nlx, h / nly
    free_x, free_y = lot_w - 8.0, lot_h - 8.0
    shapes: list[_Shape] = []
    for a in range(nlx):
        for b in range(nly):
            if shapes and rng.random() < 0.1:
                continue  # an empty lot
            cx = (a + 0.5) * lot_w + _q(rng.uniform(-1.5, 1.5), 0.1)
            cy = (b + 0.5) * lot_h + _q(rng.uniform(-1.5, 1.5), 0.1)
            eaves = _eaves(rng, int(rng.integers(2, 4)))
            if rng.random() < 0.25:
                la = _q(rng.uniform(14.0, min(20.0, free_x, free_y)), 0.5)
                lb = _q(rng.uniform(12.0, min(18.0, free_x, free_y)), 0.5)
                poly = _l_shape(la, lb, _q(rng.uniform(7.0, 9.5), 0.5), _q(rng.uniform(7.0, 9.5), 0.5))
                poly = _rotate_quarter(poly - (la / 2.0, lb / 2.0), int(rng.integers(4))) + (cx, cy)
                shapes.append(_l_roof(rng, poly, eaves, p_mono=0.5))
                continue
            long = _q(rng.uniform(10.0, min(20.0, max(free_x, free_y))), 0.5)
            short = _q(rng.uniform(8.0, min(13.0, long)), 0.5)
            sx, sy = (long, short) if rng.random() < 0.5 else (short, long)
            angle = _q(rng.uniform(-8.0, 8.0), 0.5)
            poly = _rect(cx, cy, sx, sy, angle)
            if np.ptp(poly[:, 0]) > free_x or np.ptp(poly[:, 1]) > free_y:
                poly = _rect(cx, cy, min(sx, free_x), min(sy, free_y))
            shapes.append(_rect_roof(rng, poly, eaves, (0.1, 0.45, 0.3, 0.15)))
    return shapes


def _towers_block(rng: np.random.Generator, w: float, h: float) -> list[_Shape]:
    """A 12-14 storey tower in one half of the block; a 7-11 storey tower or a low hall in the other."""
    along_x = w >= h
    half, other = (w / 2.0, h) if along_x else (h / 2.0, w)

    def place(poly_half: np.ndarray, k: int) -> np.ndarray:
        """Half-local (u along the split axis, v across) of half ``k`` -> block-local."""
        p = poly_half + (k * half, 0.0)
        return p if along_x else p[:, ::-1][::-1]  # swapping the axes mirrors: reverse to stay CCW

    shapes: list[_Shape] = []
    su = _q(rng.uniform(18.0, min(30.0, half - 8.0)), 0.5)
    sv = _q(rng.uniform(16.0, min(28.0, other - 10.0)), 0.5)
    jitter_u, jitter_v = max(0.0, (half - su) / 2.0 - 4.0), max(0.0, (other - sv) / 2.0 - 5.0)
    cu = half / 2.0 + _q(rng.uniform(-jitter_u, jitter_u), 0.5)
    cv = other / 2.0 + _q(rng.uniform(-jitter_v, jitter_v), 0.5)
    first = int(rng.integers(2))
    tower = place(_rect(cu, cv, su, sv), first)
    shapes.append(
        _Shape(_rect_reorder(tower), "flat", _eaves(rng, int(rng.integers(12, 15))), 0.0, (1.0, 0.0))
    )

    if rng.random() < 0.6:
        su = _q(rng.uniform(16.0, min(24.0, half - 8.0)), 0.5)
        sv = _q(rng.uniform(16.0, min(24.0, other - 10.0)), 0.5)
        poly = _rect_reorder(place(_rect(half / 2.0, other / 2.0, su, sv), 1 - first))
        shapes.append(_Shape(poly, "flat", _eaves(rng, int(rng.integers(7, 12))), 0.0, (1.0, 0.0)))
    else:
        room = min(40.0, half - 6.0, other - 10.0)  # both extents fit whatever the quarter turn
        a, b = (_q(rng.uniform(16.0, room), 0.5) for _ in range(2))
        poly = _l_shape(a, b, _q(rng.uniform(8.0, 12.0), 0.5), _q(rng.uniform(8.0, 12.0), 0.5))
        poly = _rotate_quarter(poly - (a / 2.0, b / 2.0), int(rng.integers(4)))
        poly = place(poly + (half / 2.0, other / 2.0), 1 - first)
        shapes.append(_l_roof(rng, poly, _eaves(rng, int(rng.integers(2, 4))), p_mono=0.4))
    return shapes


def _rect_reorder(poly: np.ndarray) -> np.ndarray:
    """Start a rectangle at the corner where a long side begins (after axis swaps)."""
    if np.linalg.norm(poly[1] - poly[0]) + 1e-9 < np.linalg.norm(poly[2] - poly[1]):
        return np.roll(poly, -1, axis=0)
    return poly


_BLOCK_STYLES = {"perimeter": _perimeter_block, "detached": _detached_block, "towers": _towers_block}


def _block_styles(rng: np.random.Generator, n: int) -> list[str]:
    """Every style at least once (when n >= 3), the rest mostly perimeter blocks."""
    names = list(_BLOCK_STYLES)
    extra = rng.choice(names, size=max(0, n - len(names)), p=(0.5, 0.3, 0.2)).tolist()
    styles = names[:n] + [str(s) for s in extra]
    return [styles[i] for i in rng.permutation(n)]


def _check_blocks(blocks) -> tuple[int, int]:
    try:
        nx, ny = (int(v) for v in blocks)
    except (TypeError, ValueError) as exc:
        raise GeneratorParameterError(f"blocks must be two integers (columns, rows), got {blocks!r}") from exc
    if not (1 <= nx <= MAX_BLOCKS_PER_AXIS and 1 <= ny <= MAX_BLOCKS_PER_AXIS):
        raise GeneratorParameterError(f"blocks must lie in 1..{MAX_BLOCKS_PER_AXIS} per axis, got {blocks!r}")
    return nx, ny


def _check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise GeneratorParameterError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def generate_footprints(
    seed: int = DEFAULT_SEED,
    blocks: tuple[int, int] = DEFAULT_BLOCKS,
    origin: tuple[float, float] = DEFAULT_ORIGIN,
) -> list[Footprint]:
    """The district's buildings as ``Footprint`` objects (no files). Deterministic for a seed."""
    nx, ny = _check_blocks(blocks)
    ox, oy = (float(v) for v in origin)
    if not (math.isfinite(ox) and math.isfinite(oy)):
        raise GeneratorParameterError(f"origin must be finite, got {origin!r}")
    rng = np.random.default_rng(_check_seed(seed))
    slope = rng.uniform(0.01, 0.02)
    direction = rng.uniform(0.0, 2.0 * math.pi)
    grad = slope * np.array([math.cos(direction), math.sin(direction)])
    street_x = [_q(v, 0.5) for v in rng.uniform(*STREET_WIDTH_M, size=nx + 1)]
    street_y = [_q(v, 0.5) for v in rng.uniform(*STREET_WIDTH_M, size=ny + 1)]
    block_w = [_q(v, 1.0) for v in rng.uniform(*BLOCK_SIZE_M, size=nx)]
    block_h = [_q(v, 1.0) for v in rng.uniform(*BLOCK_SIZE_M, size=ny)]
    centre = np.array([ox + (sum(street_x) + sum(block_w)) / 2.0, oy + (sum(street_y) + sum(block_h)) / 2.0])
    styles = _block_styles(rng, nx * ny)

    footprints: list[Footprint] = []
    for j in range(ny):
        y0 = oy + sum(street_y[: j + 1]) + sum(block_h[:j])
        for i in range(nx):
            x0 = ox + sum(street_x[: i + 1]) + sum(block_w[:i])
            style = styles[j * nx + i]
            w, h = block_w[i], block_h[j]
            block_centre = (round(x0 + w / 2.0, 3), round(y0 + h / 2.0, 3))
            for k, shape in enumerate(_BLOCK_STYLES[style](rng, w, h)):
                poly = np.round(shape.polygon + (x0, y0), 3)
                ground = round(BASE_GROUND_Z + float(np.min((poly - centre) @ grad)), 3)
                eaves = round(ground + shape.eaves_h, 3)
                footprints.append(
                    Footprint(
                        id=f"GEN_B{i:02d}_{j:02d}_{k:02d}",
                        polygon=poly,
                        ground_z=ground,
                        eaves_z=eaves,
                        ridge_z=round(eaves + shape.roof_h, 3),
                        roof_type=shape.roof_type,
                        roof_axis=(round(shape.roof_axis[0], 9), round(shape.roof_axis[1], 9)),
                        block=(i, j),
                        block_style=style,
                        block_centre=block_centre,
                    )
                )
    return footprints


# -------------------------------------------------------------------------------------------- surfaces
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
    lod = _check_lod(lod)
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


def _check_lod(lod) -> int:
    if lod not in (1, 2, 3) or isinstance(lod, bool):
        raise GeneratorParameterError(f"the generator writes LoD 1, 2 or 3, not {lod!r}")
    return int(lod)


def _by_block(footprints: list[Footprint]) -> dict[tuple[int, int], list[Footprint]]:
    groups: dict[tuple[int, int], list[Footprint]] = {}
    for fp in footprints:
        groups.setdefault(fp.block, []).append(fp)
    return groups


def _city_surfaces(footprints: list[Footprint], lod: int) -> list[tuple[Footprint, list[Surface]]]:
    groups = _by_block(footprints)
    return [(fp, building_surfaces(fp, lod, groups[fp.block])) for fp in footprints]


def footprints_to_model(footprints: list[Footprint], lod: int = 2, crs: str = DEFAULT_CRS) -> CityModel:
    """The generated surfaces straight into a ``CityModel`` (no XML). LoD1 surfaces go in unlabelled
    (classified by normals, as a reader of the LoD1 file would), LoD2/3 with their CityGML semantics."""
    lod = _check_lod(lod)
    metric = _metric_crs(crs)
    builder = MeshBuilder()
    for fp, surfaces in _city_surfaces(footprints, lod):
        for s in surfaces:
            sem = None if lod == 1 else int(SURFACE_CLASS[s.kind])
            builder.add_polygon(s.exterior, s.interiors, sem, fp.id, lod)
            for o in s.openings:
                builder.add_polygon(o.exterior, (), int(SURFACE_CLASS[o.kind]), fp.id, lod)
    return builder.build(crs=metric, source_crs=metric, source=f"generated LoD{lod}")


def tile_model(model: CityModel, nx: int, ny: int = 1, gap_m: float = 0.0) -> CityModel:
    """``model`` repeated nx x ny times side by side (x then y), ``gap_m`` apart, sharing its origin: a
    bigger city for scaling tests and benchmarks (array copies with offsets)."""
    ext = model.extent_m
    verts, tris, extras = [], [], []
    nv = len(model.vertices)
    nb = len(model.building_ids)
    ids: list[str] = []
    for a in range(ny):
        for b in range(nx):
            k = a * nx + b
            off = np.array([b * (ext[0] + gap_m), a * (ext[1] + gap_m), 0.0])
            verts.append(model.vertices.astype(np.float64) + off)
            tris.append(model.triangles + k * nv)
            extras.append(model.building_index + k * nb)
            ids.extend(f"{bid}#{k}" for bid in model.building_ids)
    reps = nx * ny
    return CityModel(
        origin=model.origin.copy(),
        vertices=np.concatenate(verts).astype(np.float32),
        triangles=np.concatenate(tris),
        classes=np.tile(model.classes, reps),
        building_index=np.concatenate(extras),
        lods=np.tile(model.lods, reps),
        building_ids=ids,
        crs=model.crs,
        source_crs=model.source_crs,
        source=f"{model.source} x{reps}",
    )


# ---------------------------------------------------------------------------------------------- CityGML
def _metric_crs(crs: str):
    parsed = parse_crs_name(crs)
    if not parsed.is_projected and not (parsed.is_compound and parsed.sub_crs_list[0].is_projected):
        raise CRSError(f"the generator lays out metres: {crs!r} is not a projected CRS")
    return parsed


def srs_name(crs: str) -> str:
    """OGC URN for a CRS string: ``EPSG:25832`` -> ``urn:ogc:def:crs:EPSG::25832``."""
    parsed = _metric_crs(crs)
    m = re.fullmatch(r"\s*EPSG:(\d+)\s*", crs, re.IGNORECASE)
    if m:
        return f"urn:ogc:def:crs:EPSG::{m.group(1)}"
    auth = parsed.to_authority(min_confidence=90)
    if auth and auth[0] == "EPSG":
        return f"urn:ogc:def:crs:EPSG::{auth[1]}"
    return crs.strip()


def _q3(v: float) -> str:
    return f"{v:.3f}"


def _pos_list(ring: np.ndarray) -> str:
    closed = np.vstack([ring, ring[:1]])
    return " ".join(_q3(v) for v in closed.ravel())


class _Writer:
    """Builds one CityGML 2.0 document with lxml (ids unique per file)."""

    def __init__(self, srs: str, name: str):
        self.srs = srs
        nsmap = {None: CORE_NS, "bldg": BLDG_NS, "gml": GML_NS, "xlink": XLINK_NS, "xsi": XSI_NS}
        self.root = etree.Element(f"{{{CORE_NS}}}CityModel", nsmap=nsmap)
        self.root.set(f"{{{XSI_NS}}}schemaLocation", SCHEMA_LOCATION)
        etree.SubElement(self.root, f"{{{GML_NS}}}name").text = name
        self.root_env = etree.SubElement(self.root, f"{{{GML_NS}}}boundedBy")
        self.lo = np.full(3, np.inf)
        self.hi = np.full(3, -np.inf)

    def el(self, parent, ns: str, tag: str, **attrs) -> etree._Element:
        e = etree.SubElement(parent, f"{{{ns}}}{tag}")
        for k, v in attrs.items():
            e.set(k, v)
        return e

    def envelope(self, parent, lo: np.ndarray, hi: np.ndarray) -> None:
        env = self.el(parent, GML_NS, "Envelope", srsName=self.srs, srsDimension="3")
        self.el(env, GML_NS, "lowerCorner").text = " ".join(_q3(v) for v in lo)
        self.el(env, GML_NS, "upperCorner").text = " ".join(_q3(v) for v in hi)

    def polygon(self, parent, pid: str, s: Surface) -> None:
        poly = self.el(parent, GML_NS, "Polygon", **{f"{{{GML_NS}}}id": pid})
        ring = self.el(self.el(poly, GML_NS, "exterior"), GML_NS, "LinearRing")
        self.el(ring, GML_NS, "posList", srsDimension="3").text = _pos_list(s.exterior)
        for hole in s.interiors:
            ring = self.el(self.el(poly, GML_NS, "interior"), GML_NS, "LinearRing")
            self.el(ring, GML_NS, "posList", srsDimension="3").text = _pos_list(hole)

    def multi_surface(self, parent, lod: int, pid: str, s: Surface) -> None:
        ms = self.el(self.el(parent, BLDG_NS, f"lod{lod}MultiSurface"), GML_NS, "MultiSurface")
        self.polygon(self.el(ms, GML_NS, "surfaceMember"), pid, s)

    def solid(self, parent, lod: int, bid: str) -> etree._Element:
        solid = self.el(
            self.el(parent, BLDG_NS, f"lod{lod}Solid"), GML_NS, "Solid", **{f"{{{GML_NS}}}id": f"{bid}_solid"}
        )
        return self.el(
            self.el(solid, GML_NS, "exterior"),
            GML_NS,
            "CompositeSurface",
            **{f"{{{GML_NS}}}id": f"{bid}_shell"},
        )

    def xlink(self, shell, pid: str) -> None:
        self.el(shell, GML_NS, "surfaceMember", **{f"{{{XLINK_NS}}}href": f"#{pid}"})

    def building(self, fp: Footprint, lod: int, surfaces: list[Surface]) -> None:
        member = self.el(self.root, CORE_NS, "cityObjectMember")
        b = self.el(member, BLDG_NS, "Building", **{f"{{{GML_NS}}}id": fp.id})
        pts = np.concatenate([s.exterior for s in surfaces])
        lo, hi = pts.min(0), pts.max(0)
        self.lo, self.hi = np.minimum(self.lo, lo), np.maximum(self.hi, hi)
        self.envelope(self.el(b, GML_NS, "boundedBy"), lo, hi)
        self.el(b, BLDG_NS, "roofType", codeSpace=ROOF_TYPE_CODESPACE).text = ROOF_TYPE_CODES[fp.roof_type]
        self.el(b, BLDG_NS, "measuredHeight", uom="m").text = _q3(fp.height)
        self.el(b, BLDG_NS, "storeysAboveGround").text = str(fp.storeys)
        if lod == 1:  # inline polygons, no semantics (as real LoD1 products)
            shell = self.solid(b, 1, fp.id)
            for n, s in enumerate(surfaces):
                self.polygon(self.el(shell, GML_NS, "surfaceMember"), f"{fp.id}_p{n:03d}", s)
            return
        shell = self.solid(b, 2, fp.id) if lod == 2 else None
        solid_members: list[str] = []
        n_open = 0
        for n, s in enumerate(surfaces):
            pid = f"{fp.id}_p{n:03d}"
            solid_members.append(pid)
            feature = self.el(
                self.el(b, BLDG_NS, "boundedBy"), BLDG_NS, s.kind, **{f"{{{GML_NS}}}id": f"{fp.id}_s{n:03d}"}
            )
            self.multi_surface(feature, lod, pid, s)
            for o in s.openings:
                oid = f"{fp.id}_{'w' if o.kind == 'Window' else 'd'}{n_open:04d}"
                opening = self.el(
                    self.el(feature, BLDG_NS, "opening"), BLDG_NS, o.kind, **{f"{{{GML_NS}}}id": oid}
                )
                self.multi_surface(opening, lod, f"{oid}_p", o)
                solid_members.append(f"{oid}_p")
                n_open += 1
        if shell is None:
            shell = self.solid(b, 3, fp.id)  # lod3Solid comes after boundedBy in the 2.0 schema
        for pid in solid_members:
            self.xlink(shell, pid)

    def write(self, path: Path) -> Path:
        self.envelope(self.root_env, self.lo, self.hi)
        tmp = path.with_name(path.name + ".tmp")
        etree.ElementTree(self.root).write(
            str(tmp), xml_declaration=True, encoding="UTF-8", pretty_print=True
        )
        tmp.replace(path)
        return path


def write_citygml(
    footprints: list[Footprint], lod: int, path: str | Path, crs: str = DEFAULT_CRS, name: str = ""
) -> Path:
    """Write the buildings at one LoD as a CityGML 2.0 file."""
    lod = _check_lod(lod)
    if not footprints:
        raise GeneratorParameterError("no footprints to write")
    writer = _Writer(srs_name(crs), name or f"semcityloc generated district LoD{lod}")
    for fp, surfaces in _city_surfaces(footprints, lod):
        writer.building(fp, lod, surfaces)
    return writer.write(Path(path))


def generate_city(
    out_dir: str | Path,
    seed: int = DEFAULT_SEED,
    blocks: tuple[int, int] = DEFAULT_BLOCKS,
    lods: tuple[int, ...] = DEFAULT_LODS,
    crs: str = DEFAULT_CRS,
    origin: tuple[float, float] = DEFAULT_ORIGIN,
) -> dict[int, Path]:
    """Write ``out_dir/generated_lod{N}.gml`` for each LoD in ``lods`` from the same footprints.

    ``origin``: world x, y of the district's south-west corner (in ``crs``, which must be projected).
    Returns {lod: path}. Deterministic: the same arguments give byte-identical files.
    """
    lods = (lods,) if isinstance(lods, (int, np.integer)) else lods
    lod_list = sorted({_check_lod(v) for v in lods}) if lods else []
    if not lod_list:
        raise GeneratorParameterError("lods must name at least one of 1, 2, 3")
    srs_name(crs)  # fail on a bad CRS before any work
    footprints = generate_footprints(seed, blocks, origin)
    nx, ny = _check_blocks(blocks)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    name = f"semcityloc generated district (v{GENERATOR_VERSION}, seed {int(seed)}, blocks {nx}x{ny})"
    return {
        lod: write_citygml(footprints, lod, out / f"generated_lod{lod}.gml", crs, f"{name} LoD{lod}")
        for lod in lod_list
    }


def default_cache_root() -> Path:
    """``cache.cache_root()`` / ``generated``."""
    return cache_root() / "generated"


def default_city_path(lod: int = 2, cache_dir: str | Path | None = None) -> Path:
    """The default district's CityGML file at ``lod``, generated once (all three LoDs) into
    ``cache_dir`` (default ``default_cache_root()``) under a folder keyed by the generator version and
    the default parameters."""
    lod = _check_lod(lod)
    root = Path(cache_dir) if cache_dir is not None else default_cache_root()
    key = (
        f"v{GENERATOR_VERSION}-seed{DEFAULT_SEED}-blocks{DEFAULT_BLOCKS[0]}x{DEFAULT_BLOCKS[1]}-"
        f"{DEFAULT_CRS.replace(':', '')}-{DEFAULT_ORIGIN[0]:.0f}-{DEFAULT_ORIGIN[1]:.0f}"
    )
    target = root / key
    path = target / f"generated_lod{lod}.gml"
    if path.exists():
        return path
    try:
        root.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{key}-", dir=root))
    except OSError as exc:
        raise InputFileError(f"cannot write the generated city into {root}: {exc.strerror or exc}") from exc
    try:
        generate_city(tmp)
        try:
            tmp.rename(target)  # atomic: a reader never sees a half-written folder
        except OSError:  # another process won the race, or an incomplete folder is in the way
            for f in sorted(tmp.iterdir()):
                if not (target / f.name).exists():
                    os.replace(f, target / f.name)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return path

"""The generated district's layout: the street grid, its blocks and every building's footprint, heights and
roof shape (``Footprint``), all drawn from one seeded ``numpy`` generator.

Why a module of its own: every output of the generated city (``citymodel.generator``: the CityGML file of
each LoD, the ``CityModel``) is built from the same footprints (same building ids), and every random draw
of the generator happens here, in one fixed order: a seed gives the same district, exactly (layout
numbers rounded to fixed steps, coordinates to the millimetre).

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
The layout is in metres: ``origin`` is in a projected CRS (``DEFAULT_CRS`` by default), which
``citymodel.crs.metric_crs`` checks for every output of the district.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from semcityloc.citymodel.triangulate import ring_area_xy
from semcityloc.errors import ParameterError
from semcityloc.geometry.pose import rotation_about_world_z

DEFAULT_SEED = 0
DEFAULT_BLOCKS = (4, 3)
DEFAULT_CRS = "EPSG:25832"
DEFAULT_ORIGIN = (690000.0, 5336000.0)
MAX_BLOCKS_PER_AXIS = 30

BASE_GROUND_Z = 520.0  # terrain height at the district centre (metres, roughly Munich)
STREET_WIDTH_M = (12.0, 20.0)
BLOCK_SIZE_M = (60.0, 100.0)
STOREY_M = 3.0

ROOF_TYPES = ("flat", "gable", "hip", "mono")


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
    def area(self) -> float:
        """Signed area seen from above (positive: counter-clockwise), ``ring_area_xy``."""
        return ring_area_xy(self.polygon)

    @property
    def storeys(self) -> int:
        """Storeys above ground from the eaves height (at least one), for the CityGML attribute."""
        return max(1, int((self.eaves_z - self.ground_z) // STOREY_M))


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
    return pts @ rotation_about_world_z(angle_deg)[:2, :2].T + (cx, cy)


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


def check_blocks(blocks) -> tuple[int, int]:
    """``blocks`` as (columns, rows), each in 1..``MAX_BLOCKS_PER_AXIS``; anything else a ParameterError."""
    try:
        nx, ny = (int(v) for v in blocks)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"blocks must be two integers (columns, rows), got {blocks!r}") from exc
    if not (1 <= nx <= MAX_BLOCKS_PER_AXIS and 1 <= ny <= MAX_BLOCKS_PER_AXIS):
        raise ParameterError(f"blocks must lie in 1..{MAX_BLOCKS_PER_AXIS} per axis, got {blocks!r}")
    return nx, ny


def _check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ParameterError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def generate_footprints(
    seed: int = DEFAULT_SEED,
    blocks: tuple[int, int] = DEFAULT_BLOCKS,
    origin: tuple[float, float] = DEFAULT_ORIGIN,
) -> list[Footprint]:
    """The district's buildings as ``Footprint`` objects (no files). Deterministic for a seed."""
    nx, ny = check_blocks(blocks)
    ox, oy = (float(v) for v in origin)
    if not (math.isfinite(ox) and math.isfinite(oy)):
        raise ParameterError(f"origin must be finite, got {origin!r}")
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


def generated_crs_what(crs: str) -> str:
    """How a message names the CRS given for the generated city (``crs.metric_crs``'s ``what``): its layout
    is in metres."""
    return f"the generated city's CRS {crs!r} (its layout is in metres)"

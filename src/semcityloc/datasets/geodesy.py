"""WGS 84 positions and heights into a city model's CRS: pyproj, and what it could not do said.

Why: a GNSS position (a DJI photo's, a geotag file's) is WGS 84 latitude / longitude / height; a city
model is in a projected CRS, most often with orthometric heights. Getting from one to the other is easy
to get wrong by degrees of yaw and tens of metres of height, and pyproj does parts of it silently or not
at all; these helpers do it once, for ``datasets.dji`` (priors and geotags), ``datasets.geotags`` and
``datasets.geojson``.

- CRS names (``target_crs_of``): ``parse_crs_name``'s forms, ``EPSG:h+v`` compounds kept whole; a
  compound's parts: ``citymodel.crs.vertical_datum`` and ``horizontal_crs``.
  A position more than ``AREA_MARGIN_DEG`` outside the CRS's area of use is a wrong CRS
  (``check_area_of_use``; a model's own coordinates likewise, ``model_outside_crs``: a local frame given a
  CRS without its offset); a CRS that is not projected is refused (``citymodel.crs.check_projected``).
- Heights: city models store orthometric heights (above a geoid: NAP, DHHN2016, EGM96 "MSL", ...), which
  differ from WGS 84 ellipsoidal heights by the local geoid undulation N (-107 m .. +86 m worldwide;
  ``H = h - N``). pyproj applies a geoid only when its grid file is installed (``projsync`` or
  ``PROJ_NETWORK=ON``); otherwise its "ballpark" operation leaves the height unchanged (``is_ballpark``).
  ``geoid_separation`` gives N, or None and a note naming the missing grid; a stated N is checked by
  ``check_geoid_separation``.
- North: a projected CRS's grid north differs from true north by the meridian convergence, measured
  numerically (``grid_convergence_deg``: the grid azimuth of a short step due north). Without it a UTM pose
  is up to ~3 deg off in yaw at the zone edges.
"""

from __future__ import annotations

import functools
import math
import warnings

import numpy as np
import pyproj
from pyproj.transformer import TransformerGroup

from semcityloc.citymodel.crs import horizontal_crs, parse_crs_name
from semcityloc.citymodel.model import CityModel
from semcityloc.errors import CRSError, ParameterError

GEOID_UNDULATION_BOUND_M = 110.0  # |N| <= ~107 m anywhere (EGM2008 extremes: -106.6 / +85.8 m)
EGM96 = "EPSG:4326+5773"  # WGS 84 + EGM96 height: DJI's "MSL", the default orthometric system
WGS84_3D = "EPSG:4979"
EGM96_GRID = "us_nga_egm96_15.tif"
AREA_MARGIN_DEG = 2.0  # tolerance around a CRS's area of use (zones are often used a little beyond)
# pyproj's CRS and transformation objects take 5-500 ms each to make (a geoid's operations the most), and
# a flight's photos all need the same few: made once per process, kept by a hashable name of their CRSs
# (``_crs_key``: a name as given, a CRS object's WKT). pyproj's objects are not changed once made.
_CACHED = 32


def target_crs_of(name: str | pyproj.CRS) -> pyproj.CRS:
    """A CRS from a name (``parse_crs_name``'s forms, ``EPSG:h+v`` compounds kept whole), made once per
    name (an error is raised again each time); a CRS as it is."""
    if isinstance(name, pyproj.CRS):
        return name
    return _crs_of_name(str(name))


_crs_of_name = functools.lru_cache(maxsize=_CACHED)(parse_crs_name)


def _crs_key(crs: str | pyproj.CRS) -> str:
    """A hashable name of ``crs`` for the caches: a name as given, a CRS object's WKT."""
    return crs.to_wkt() if isinstance(crs, pyproj.CRS) else str(crs)


def transformer_group(source: str | pyproj.CRS, target: str | pyproj.CRS) -> TransformerGroup:
    """pyproj's candidate operations (``always_xy``), made once per pair of CRSs (``_transformer_group``)."""
    return _transformer_group(_crs_key(source), _crs_key(target))


@functools.lru_cache(maxsize=_CACHED)
def _transformer_group(source: str, target: str) -> TransformerGroup:
    """``transformer_group`` of two CRS names; pyproj's warning about missing grids is ours to report
    (``is_ballpark``)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Best transformation is not available")
        return TransformerGroup(source, target, always_xy=True)


@functools.lru_cache(maxsize=_CACHED)
def _from_wgs84(target: str) -> pyproj.Transformer:
    """WGS 84 latitude / longitude -> ``target`` (a CRS name, ``always_xy``), made once per CRS."""
    return pyproj.Transformer.from_crs("EPSG:4326", target, always_xy=True)


def is_ballpark(group: TransformerGroup) -> bool:
    """Whether pyproj has no operation, or only a ballpark one (a grid it would need is not installed:
    no geoid, an approximate datum shift)."""
    if not group.transformers:
        return True
    return (not group.best_available) or "ballpark" in group.transformers[0].description.lower()


def check_geoid_separation(value: float | None) -> None:
    """A stated geoid undulation N (None: none stated) is a number of metres the geoid can lie from the
    ellipsoid; ``ParameterError`` naming it otherwise (NaN too)."""
    if value is not None and not (
        isinstance(value, (int, float)) and abs(value) <= GEOID_UNDULATION_BOUND_M
    ):  # NaN fails the comparison too
        raise ParameterError(
            f"geoid separation N must be a number of metres within +-{GEOID_UNDULATION_BOUND_M:g} (the geoid "
            f"lies -107..+86 m from the ellipsoid anywhere), got {value!r}"
        )


def geoid_separation(
    lon: float, lat: float, h: float, target_3d: pyproj.CRS | str
) -> tuple[float | None, str]:
    """N = h - H from pyproj (None when it would only use a ballpark, i.e. no geoid grid) and a note."""
    group = transformer_group(WGS84_3D, target_3d)
    if is_ballpark(group):
        missing = sorted(
            {g.short_name for op in group.unavailable_operations for g in getattr(op, "grids", []) or []}
        )
        grids = ", ".join(missing) or EGM96_GRID
        return None, (
            f"pyproj has no geoid grid for this conversion (missing: {grids}; install with "
            f"'projsync --file <grid>' or set PROJ_NETWORK=ON)"
        )
    H = group.transformers[0].transform(lon, lat, h)[2]
    if not math.isfinite(H):
        return None, "pyproj's geoid grid does not cover this position"
    return h - H, group.transformers[0].description


def grid_convergence_deg(crs: pyproj.CRS, lon: float, lat: float) -> float:
    """Grid azimuth (clockwise from grid north, degrees) of true north at (lon, lat) in ``crs``."""
    t = _from_wgs84(_crs_key(horizontal_crs(crs)))
    step = 1e-4 if lat < 89.9 else -1e-4
    e0, n0 = t.transform(lon, lat)
    e1, n1 = t.transform(lon, lat + step)
    if not all(math.isfinite(v) for v in (e0, n0, e1, n1)):
        raise CRSError(f"{crs.name}: the position (lat {lat}, lon {lon}) is outside its area of use")
    angle = math.degrees(math.atan2(e1 - e0, n1 - n0))
    return angle if step > 0 else angle - math.copysign(180.0, angle)


# A model's coordinates may lie this share of its CRS's projected area of use (each axis's span) beyond it.
MODEL_AREA_MARGIN = 0.05


@functools.lru_cache(maxsize=_CACHED)
def _projected_area(crs: str) -> tuple[float, float, float, float] | None:
    """The area of use of ``crs`` (a name or WKT) in its own x, y: (xmin, ymin, xmax, ymax), or None when
    it states none or spans the antimeridian."""
    whole = pyproj.CRS.from_user_input(crs)
    horizontal = horizontal_crs(whole)
    area = whole.area_of_use or horizontal.area_of_use  # a compound's parts read from WKT state none
    if area is None or area.west > area.east:
        return None
    to_crs = pyproj.Transformer.from_crs("EPSG:4326", horizontal, always_xy=True)
    bounds = to_crs.transform_bounds(area.west, area.south, area.east, area.north, densify_pts=21)
    return bounds if all(math.isfinite(b) for b in bounds) else None


def check_model_in_crs(model: CityModel, offset: np.ndarray | None, remedy: str) -> None:
    """``CRSError`` when ``model``'s coordinates (plus ``offset``: its frame is the CRS minus that) cannot be
    in its CRS (``model_outside_crs``), naming ``remedy``: positions written as CRS coordinates would be
    hundreds of kilometres off. A model without a CRS or without triangles (a tile store's before its
    tiles are chosen) passes."""
    if model.crs is None or not model.num_triangles:
        return
    lo, hi = model.bounds_local
    centre = model.origin + (lo + hi) / 2.0 + (0.0 if offset is None else np.asarray(offset, np.float64))
    reason = model_outside_crs(model.crs, (float(centre[0]), float(centre[1])))
    if reason is not None:
        raise CRSError(f"{reason}: {remedy}")


def model_outside_crs(crs: pyproj.CRS, centre_xy: tuple[float, float]) -> str | None:
    """Why a model whose coordinates centre on ``centre_xy`` (x, y in ``crs``, any offset added) cannot be
    in ``crs``, or None: beyond the CRS's area of use (in its own metres, ``MODEL_AREA_MARGIN`` of its
    span around it), most often a local frame (an OBJ, a model shifted to small numbers) given a CRS
    without the offset that places it. Its positions written as ``crs`` coordinates (a pose record,
    geotags, GeoJSON) would land hundreds of kilometres away (UTM 49N: at the Equator)."""
    if not horizontal_crs(crs).is_projected or (bounds := _projected_area(_crs_key(crs))) is None:
        return None
    xmin, ymin, xmax, ymax = bounds
    mx, my = MODEL_AREA_MARGIN * (xmax - xmin), MODEL_AREA_MARGIN * (ymax - ymin)
    x, y = centre_xy
    if xmin - mx <= x <= xmax + mx and ymin - my <= y <= ymax + my:
        return None
    return (
        f"the model's coordinates (centre {x:.1f}, {y:.1f}) are not in {crs.name}: its area of use spans x "
        f"{xmin:.0f}..{xmax:.0f}, y {ymin:.0f}..{ymax:.0f} (a local frame?)"
    )


def check_area_of_use(crs: pyproj.CRS, lon: float, lat: float) -> None:
    """``CRSError`` when the image lies more than ``AREA_MARGIN_DEG`` outside the CRS's area of use: the
    projection would still give numbers, metres to kilometres distorted, for a CRS that was never meant.
    When the position with latitude and longitude swapped lies inside it, the message asks that instead
    (a geotag table with its columns the other way round) of "wrong target CRS?"."""
    area = crs.area_of_use
    if area is None or _in_area(area, lon, lat):
        return
    if _in_area(area, lat, lon):
        hint = f"latitude and longitude swapped? (lat {lon:.6f}, lon {lat:.6f} lies inside it)"
    else:
        hint = "wrong target CRS?"
    raise CRSError(
        f"the position (lat {lat:.6f}, lon {lon:.6f}) is outside the area of use of {crs.name} "
        f"({area.name}): {hint}"
    )


def _in_area(area: pyproj.aoi.AreaOfUse, lon: float, lat: float) -> bool:
    """Whether (``lon``, ``lat``) lies within ``AREA_MARGIN_DEG`` of ``area``."""
    west, south, east, north = area.bounds
    lon_in = west - AREA_MARGIN_DEG <= lon <= east + AREA_MARGIN_DEG if west <= east else True
    return lon_in and south - AREA_MARGIN_DEG <= lat <= north + AREA_MARGIN_DEG

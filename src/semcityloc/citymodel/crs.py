"""Coordinate reference systems of city models: parse what files say, choose the metric frame.

CityGML writes CRSs in many spellings (OGC URNs, AdV URNs, compound URNs, http URIs); CityJSON writes
``referenceSystem`` URLs. ``parse_crs_name`` turns all of them into a ``pyproj.CRS`` and names the string
in its error when it cannot. ``MetricFrame`` converts a geographic CRS to the UTM zone of the data
(pyproj on whole arrays, ``always_xy=True``, with the axis order of the source handled explicitly).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import pyproj
from pyproj.exceptions import CRSError as PyprojCRSError

from semcityloc.errors import CRSError, parameter, unknown_choice

# AdV (German surveying authorities) names of horizontal CRSs, as written in state CityGML products, and
# of the height systems after the "*" (``ADV_VERTICAL``): a known one makes a compound CRS, so that a GNSS
# height is converted to it (its geoid); an unknown one leaves the horizontal CRS alone.
# What an error about a file's CRS tells the user to do: load_city_model's crs (every command's --crs).
CRS_HINT = f"pass {parameter('crs', 'EPSG:....')}"

ADV_HORIZONTAL = {
    "ETRS89_UTM32": 25832,
    "ETRS89_UTM33": 25833,
    "DE_DHDN_3GK2": 31466,
    "DE_DHDN_3GK3": 31467,
    "DE_DHDN_3GK4": 31468,
    "DE_DHDN_3GK5": 31469,
    "ETRS89_3GK3": 5677,
}

ADV_VERTICAL = {
    "DE_DHHN92_NH": 5783,
    "DE_DHN92_NH": 5783,  # the spelling of Bavaria's products (Fürth's LoD2)
    "DE_DHHN2016_NH": 7837,
    "DE_DHHN85_NH": 5784,
}

_EPSG_CODES = re.compile(r"EPSG(?:/[0-9.]+/|:[0-9.]*:|::|:)(\d+)", re.IGNORECASE)


def parse_crs_name(name: str) -> pyproj.CRS:
    """A pyproj CRS for a CityGML ``srsName`` / CityJSON ``referenceSystem`` / user string.

    Accepted: ``EPSG:25833``, ``urn:ogc:def:crs:EPSG::25833``, ``urn:ogc:def:crs:EPSG:6.12:25833``,
    compound ``urn:ogc:def:crs,crs:EPSG::25832,crs:EPSG::5783``, ``http(s)://www.opengis.net/def/crs/EPSG/0/6697``,
    AdV ``urn:adv:crs:ETRS89_UTM32*DE_DHHN92_NH``, and anything pyproj reads (WKT, PROJ strings).
    Compound names give the horizontal CRS combined with the vertical one when pyproj knows both.
    """
    if not isinstance(name, str) or not name.strip():
        raise CRSError(f"empty CRS name {name!r}")
    text = name.strip()

    adv = re.match(r"urn:adv:crs:([A-Za-z0-9_]+)(?:\*([A-Za-z0-9_]+))?", text)
    if adv:
        key, height = adv.groups()
        if key not in ADV_HORIZONTAL:
            raise unknown_choice("AdV CRS", text, sorted(ADV_HORIZONTAL), CRSError)
        horizontal = pyproj.CRS.from_epsg(ADV_HORIZONTAL[key])
        if height not in ADV_VERTICAL:
            return horizontal
        return _compound(horizontal, pyproj.CRS.from_epsg(ADV_VERTICAL[height]))

    if re.fullmatch(r"EPSG:\d+\+\d+", text, re.IGNORECASE):  # "EPSG:4547+5773": horizontal + vertical
        try:
            return pyproj.CRS.from_user_input(text)
        except PyprojCRSError as exc:
            raise CRSError(f"unknown EPSG code in CRS {text!r}: {exc}") from exc
    codes = _EPSG_CODES.findall(text)
    if codes:
        try:
            if len(codes) == 1:
                return pyproj.CRS.from_epsg(int(codes[0]))
            return _compound(pyproj.CRS.from_epsg(int(codes[0])), pyproj.CRS.from_epsg(int(codes[1])))
        except PyprojCRSError as exc:
            raise CRSError(f"unknown EPSG code in CRS {text!r}: {exc}") from exc
    try:
        return pyproj.CRS.from_user_input(text)
    except PyprojCRSError as exc:
        raise CRSError(f"cannot parse CRS {text!r}") from exc


def _compound(horizontal: pyproj.CRS, vertical: pyproj.CRS) -> pyproj.CRS:
    """The compound CRS of a horizontal and a vertical one (named "horizontal + vertical")."""
    return pyproj.crs.CompoundCRS(
        name=f"{horizontal.name} + {vertical.name}", components=[horizontal, vertical]
    )


def horizontal_crs(crs: pyproj.CRS | str) -> pyproj.CRS:
    """The horizontal part of a CRS or CRS name (``parse_crs_name``): a compound's first part that is not
    vertical, the CRS itself otherwise."""
    if isinstance(crs, str):
        crs = parse_crs_name(crs)
    if crs.is_compound:
        for sub in crs.sub_crs_list:
            if not sub.is_vertical:
                return sub
    return crs


def vertical_datum(crs: pyproj.CRS) -> pyproj.CRS | None:
    """The vertical part (height system) of a compound CRS; None for a CRS without one."""
    if crs.is_compound:
        for sub in crs.sub_crs_list:
            if sub.is_vertical:
                return sub
    return None


def with_heights_of(target: pyproj.CRS, source: pyproj.CRS) -> pyproj.CRS:
    """``target`` with ``source``'s height system: the metric CRS of coordinates converted from ``source``
    horizontally only (``MetricFrame.to_metric`` keeps the heights). A compound source (PLATEAU's EPSG:6697,
    JGD2011 + JGD2011 vertical height) gives ``target`` + its vertical CRS (``EPSG:32654+6695``), so that a
    GNSS height is converted to it (its geoid) rather than taken as z unchanged; a target that has the same
    height system, or a source without one, gives ``target`` as it is. A target with another height system
    is a ``CRSError``: the heights stay the source's, and naming them otherwise would be silently wrong."""
    vertical = vertical_datum(source)
    if vertical is None:
        return target
    own = vertical_datum(target)
    if own is None:
        return _compound(horizontal_crs(target), vertical)
    if own.equals(vertical, ignore_axis_order=True):
        return target
    raise CRSError(
        f"the target CRS {target.name!r} names the height system {own.name!r}, but the coordinates' heights "
        f"are in {vertical.name!r} and are not converted: give a target without a height system (or with "
        "that one)"
    )


def utm_crs_for(lon: float, lat: float) -> pyproj.CRS:
    """The WGS 84 / UTM zone CRS that contains (lon, lat)."""
    zone = int(np.floor((lon + 180.0) / 6.0)) % 60 + 1
    return pyproj.CRS.from_epsg((32600 if lat >= 0 else 32700) + zone)


@dataclass
class MetricFrame:
    """How source coordinates become metric x (east), y (north), z (up) coordinates.

    ``source``: the CRS the file is in (None: unknown, coordinates are taken as metric as they are).
    ``target``: the metric CRS of the mesh; equals ``source`` unless the source is geographic. Heights are
    never converted, so a source's height system stays the target's (``with_heights_of``: a compound
    geographic source becomes its UTM zone + its vertical CRS). A geographic 3D source's heights
    (EPSG:4979) are ellipsoidal: its target is the 2D UTM zone, whose z then is that ellipsoidal height.
    ``lat_first``: the source's first coordinate is latitude (EPSG axis order of e.g. EPSG:6697, 4326).
    """

    source: pyproj.CRS | None
    target: pyproj.CRS | None
    lat_first: bool = False
    _transformer: pyproj.Transformer | None = None

    @classmethod
    def for_source(
        cls,
        source: pyproj.CRS | None,
        sample_xy: np.ndarray | None = None,
        target: pyproj.CRS | None = None,
    ) -> MetricFrame:
        """Metric frame for data in ``source``; ``sample_xy`` ((n, 2) in file order) locates the UTM zone
        of a geographic source. ``target`` overrides the metric CRS (user's choice)."""
        if source is None:
            return cls(None, target)
        horiz = horizontal_crs(source)
        lat_first = False
        if horiz.is_geographic:
            axes = [a.direction.lower() for a in horiz.axis_info[:2]]
            lat_first = axes[:1] == ["north"]
            if target is None:
                if sample_xy is None or len(sample_xy) == 0:
                    raise CRSError(
                        f"geographic CRS {source.name!r} needs sample coordinates to choose a UTM zone"
                    )
                sample = np.asarray(sample_xy, dtype=np.float64)
                lon, lat = (sample[:, 1], sample[:, 0]) if lat_first else (sample[:, 0], sample[:, 1])
                target = utm_crs_for(float(np.mean(lon)), float(np.mean(lat)))
        if target is None or target == source:
            return cls(source, source, lat_first)
        target = with_heights_of(target, source)
        transformer = pyproj.Transformer.from_crs(horiz, horizontal_crs(target), always_xy=True)
        return cls(source, target, lat_first, transformer)

    def to_metric(self, xyz: np.ndarray) -> np.ndarray:
        """(n, 3) source coordinates in file axis order -> (n, 3) metric x, y, z (heights unchanged)."""
        pts = np.asarray(xyz, dtype=np.float64)
        if self._transformer is None and not self.lat_first:
            return pts
        out = pts.copy()
        x, y = (pts[:, 1], pts[:, 0]) if self.lat_first else (pts[:, 0], pts[:, 1])
        if self._transformer is not None:
            x, y = self._transformer.transform(x, y)
        out[:, 0], out[:, 1] = x, y
        return out


def overridden_warning(given: str, stated: str) -> str | None:
    """What a reader says when ``crs_override`` (``crs=``; ``--crs``) puts x, y in another place than the
    CRS the file states (a typo's zone, 25832 for 25833, moves every coordinate hundreds of kilometres,
    silently); None when both agree there (a height system added or dropped) or the file's cannot be read."""
    try:
        if same_horizontal_crs(given, stated):
            return None
    except CRSError:
        return None
    return (
        f"{parameter('crs', given)} overrides the CRS the file states ({stated}): the coordinates are read "
        f"as {given}"
    )


def named_by(crs_override: str | None, name: object, stated_in: str) -> str:
    """Who named the CRS ``name`` a reader took, for ``check_degrees``: the caller (``crs_override``:
    ``given as crs='EPSG:4326'``) or the file (``stated_in``: ``the file's srsName: 'EPSG:4326'``)."""
    if crs_override:
        return f"given as {parameter('crs', crs_override)}"
    return f"{stated_in}: {name!r}"


def check_degrees(source: pyproj.CRS | None, sample_xy: np.ndarray | None, where: str, named_by: str) -> None:
    """Refuse a geographic CRS for coordinates that are no degrees (beyond ±360: metres of a projected CRS,
    e.g. ``--crs EPSG:4326`` given for a file in UTM), naming one; read on, every polygon would be dropped
    as absurd and the error would blame the file. ``sample_xy``: (n, 2) of the geometry itself (not an
    Envelope, which may be stale); most of its points must be beyond, so a stray absurd one is not taken
    for the file's unit. The message starts with ``where`` (the file) and ends with ``named_by`` (who named
    the CRS: ``named_by``)."""
    if source is None or sample_xy is None or not horizontal_crs(source).is_geographic:
        return
    sample = np.asarray(sample_xy, dtype=np.float64).reshape(-1, 2)
    sample = sample[np.isfinite(sample).all(axis=1)]
    if len(sample) == 0:
        return
    beyond = np.abs(sample).max(axis=1) > 360.0
    if beyond.mean() > 0.5:  # most of them: one absurd point is its polygon's to drop (the builder's)
        x, y = sample[np.argmax(beyond)]
        raise CRSError(
            f"{where}: coordinates such as ({x:.1f}, {y:.1f}) are no degrees, but {source.name!r} is "
            f"geographic: they look like metres of a projected CRS: pass that one with "
            f"{parameter('crs', 'EPSG:<code>')} ({named_by})"
        )


# A projected CRS whose map metres differ from metres on the ground by more than this share at a model
# (its point scale factor) is no metric frame for a camera: Web Mercator's is 1.64 at 52 degrees north,
# a transverse Mercator's (UTM, Gauss-Krueger) or a national grid's stays within 0.2 % where it is used.
MAX_SCALE_ERROR = 0.01


def ground_scale_problem(
    crs: pyproj.CRS | None, x: float, y: float, named_by: str = "the file's CRS"
) -> str | None:
    """Why ``crs`` cannot be a camera's metric frame at its point (``x``, ``y``): its point scale factor
    there is more than ``MAX_SCALE_ERROR`` from 1 (a camera would see every distance that much off: the
    height above the roofs, the building sizes). None when it can (or is no projected CRS, or pyproj
    cannot tell). Two causes, both named: the coordinates are not in ``crs`` at all (who named it:
    ``named_by``, e.g. ``--crs EPSG:25832``; Gauss-Krueger metres read as UTM put a Bavarian model at lon
    54, lat 39), said first when that point lies outside the CRS's area of use; or they are, and the CRS
    is no metric frame (Web Mercator), so the model must be reprojected."""
    if crs is None:
        return None
    horizontal = horizontal_crs(crs)
    if not horizontal.is_projected:
        return None
    try:
        to_geographic = pyproj.Transformer.from_crs(horizontal, horizontal.geodetic_crs, always_xy=True)
        lon, lat = to_geographic.transform(x, y)
        factors = pyproj.Proj(horizontal).get_factors(lon, lat)
    except (PyprojCRSError, pyproj.exceptions.ProjError):
        return None
    scale = max(factors.meridional_scale, factors.parallel_scale, key=lambda k: abs(k - 1.0))
    if not np.isfinite(scale) or abs(scale - 1.0) <= MAX_SCALE_ERROR:
        return None
    problem = (
        f"{horizontal.name} is no metric frame here: its point scale factor at the model "
        f"(lon {lon:.3f}, lat {lat:.3f}) is {scale:.3f}, so its metres are {1.0 / scale:.3f} m on the ground "
        "and a camera would see every distance that much off"
    )
    not_in = f"the coordinates are not in {horizontal.name} (is {named_by} right?)"
    give = f"give the CRS they are in ({parameter('crs', 'EPSG:<code>')})"
    reproject = "reproject the model to the UTM zone or the national grid it lies in"
    area = crs.area_of_use or horizontal.area_of_use
    if (
        area is not None
        and area.west <= area.east
        and not (area.west <= lon <= area.east and area.south <= lat <= area.north)
    ):
        return (
            f"{problem}. The model would lie outside the CRS's area of use ({area.name.split(':')[0]}), so "
            f"most likely {not_in}: {give}; else {reproject}"
        )
    return f"{problem}: {reproject}; or, if {not_in}, {give}"


def check_projected(crs: pyproj.CRS | str, what: str, given_as: str = "crs") -> pyproj.CRS:
    """The horizontal part of ``crs`` (a CRS or a name, ``parse_crs_name``) if it is projected (metric,
    z up once a height is added), else a ``CRSError`` naming its kind. The one rule of "is this CRS
    metric?": for a model's coordinates (OBJ, the generated city) and a prior's target CRS alike. Why not
    only "not geographic": an Earth-centred CRS (EPSG:4978) or a local engineering one passes that test,
    and coordinates or a prior put in it are nonsense (x, y geocentric, z the height, a grid convergence
    of -100 degrees) rather than an error. Its axes must be in metres too: a CRS in US survey feet is
    projected, and read as metres every distance is 3.28 times too large. ``given_as``: the parameter
    (``errors.PARAMETERS``) that gave the CRS, named in the message (``dji_prior``'s ``target_crs``)."""
    parsed = parse_crs_name(crs) if isinstance(crs, str) else crs
    horizontal = horizontal_crs(parsed)
    if horizontal.is_projected:
        units = {(a.unit_name, a.unit_conversion_factor) for a in horizontal.axis_info}
        if any(factor != 1.0 for _, factor in units):  # US survey feet (NYC's EPSG:2263): 0.3048... m
            unit = ", ".join(sorted({name for name, _ in units}))
            raise CRSError(
                f"{what} must be in metres, got {parsed.name} in {unit}: every distance would be off by "
                "that unit; reproject the data to a metric CRS (its UTM zone or national grid in metres)"
            )
        return horizontal
    kind = (
        "geographic"
        if horizontal.is_geographic
        else "geocentric"
        if horizontal.is_geocentric
        else horizontal.type_name.lower()
    )
    raise CRSError(
        f"{what} must be metric (projected), got {parsed.name} ({kind}); give the projected CRS the "
        f"coordinates are in ({parameter(given_as, 'EPSG:<code>')})"
    )


def metric_crs(name: str, what: str) -> pyproj.CRS:
    """``parse_crs_name(name)``, whole (a height system kept), if it is projected (``check_projected``
    with ``what`` naming it); for coordinates in metres: an OBJ's, the generated city's."""
    parsed = parse_crs_name(name)
    check_projected(parsed, what)
    return parsed


def same_crs(a: pyproj.CRS | str, b: pyproj.CRS | str, ignore_axis_order: bool = False) -> bool:
    """Whether two CRSs (or names, ``parse_crs_name``: spellings differ, EPSG:25833 vs its URN) are the
    same CRS, height system included; their axis order too unless ``ignore_axis_order`` (a geographic
    CRS's latitude-first order changes what the coordinates of a file mean). The one rule of "same CRS?"
    (``same_horizontal_crs`` is it on the horizontal parts). A name that cannot be read is a ``CRSError``."""
    a = parse_crs_name(a) if isinstance(a, str) else a
    b = parse_crs_name(b) if isinstance(b, str) else b
    return a.equals(b, ignore_axis_order=ignore_axis_order)


def same_horizontal_crs(a: pyproj.CRS | str, b: pyproj.CRS | str) -> bool:
    """Whether two CRSs put x, y in the same place: their horizontal parts the same CRS (``same_crs``, axis
    order aside; a compound CRS's height system does not move a pose sideways)."""
    return same_crs(horizontal_crs(a), horizontal_crs(b), ignore_axis_order=True)

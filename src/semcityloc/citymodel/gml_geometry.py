"""The rings of a GML polygon as float64 point arrays: ``posList``, ``pos`` and GML2 ``coordinates``.

Why a module of its own: this is the one place that turns GML coordinate text into numbers, and every
encoding CityGML writers use (``posList`` with ``srsDimension``, a list of ``pos`` or ``pointProperty``,
GML2 ``coordinates`` with their own separators) is decoded here to (n, 3) points. The CityGML reader's walk
(``citymodel.citygml_walk``) calls ``polygon_rings`` on each Polygon-like element of a city object.

Points with two coordinates are refused (``CoordError(two_d=True)``: no heights, the reader counts and skips
such polygons), as is anything unreadable: a ring missing, a token that is no number, a count of numbers that
does not fit the dimension (``CoordError(two_d=False)``). ``srsDimension`` is inherited from the enclosing
geometry (``dim_attr``); without one, the numbers of the first ``pos`` or GML2 tuple make a point, and a
``posList`` is read as 3D when its count allows it (else as 2D, when even).
"""

from __future__ import annotations

import numpy as np


class CoordError(Exception):
    """A ring that gives no 3D points: ``two_d`` when it has only two coordinates per point."""

    def __init__(self, two_d: bool):
        self.two_d = two_d


def dim_attr(el, inherited: int | None) -> int | None:
    """The element's ``srsDimension``, else the one ``inherited`` from the enclosing geometry."""
    d = el.get("srsDimension")
    if d is None:
        return inherited
    try:
        return int(d)
    except ValueError:
        return inherited


def _coords(numbers: np.ndarray, dim: int | None, tokens_per_point: int | None = None) -> np.ndarray:
    """(n, 3) points from a flat number array; raises CoordError for 2D data or an impossible count."""
    n = numbers.size
    if dim is None:
        dim = tokens_per_point
    if dim is None:
        if n % 3 == 0:
            dim = 3
        elif n % 2 == 0:
            dim = 2
        else:
            raise CoordError(two_d=False)
    if dim == 2:
        raise CoordError(two_d=True)
    if dim < 2 or n % dim:
        raise CoordError(two_d=False)
    pts = numbers.reshape(-1, dim)
    return pts if dim == 3 else pts[:, :3]


def _numbers(text: str | None) -> np.ndarray:
    try:
        return np.array((text or "").split(), dtype=np.float64)
    except ValueError as exc:
        raise CoordError(two_d=False) from exc


def _ring(ring_el, dim: int | None) -> np.ndarray:
    """(n, 3) float64 points of a LinearRing (posList, pos list or GML2 coordinates)."""
    dim = dim_attr(ring_el, dim)
    pos_texts: list[str] = []
    pos_dim: int | None = None
    for c in ring_el:
        tag = c.tag
        if tag.__class__ is not str:
            continue
        local = tag[tag.rfind("}") + 1 :]
        if local == "posList":
            return _coords(_numbers(c.text), dim_attr(c, dim))
        if local == "pos":
            text = c.text or ""
            pos_texts.append(text)
            if pos_dim is None:
                pos_dim = dim_attr(c, None) or len(text.split())
        elif local == "coordinates":
            return _gml2_coordinates(c, dim)
        elif local in ("pointProperty", "pointRep"):
            for p in c.iter("{*}pos"):
                text = p.text or ""
                pos_texts.append(text)
                if pos_dim is None:
                    pos_dim = len(text.split())
    if not pos_texts:
        raise CoordError(two_d=False)
    return _coords(_numbers(" ".join(pos_texts)), dim, pos_dim)


def _gml2_coordinates(el, dim: int | None) -> np.ndarray:
    """GML2 ``<coordinates cs="," ts=" " decimal=".">x,y,z x,y,z</coordinates>``."""
    cs, ts, dec = el.get("cs", ","), el.get("ts", " "), el.get("decimal", ".")
    text = (el.text or "").strip()
    tuples = text.split() if ts.isspace() else [t for t in text.split(ts) if t.strip()]
    if not tuples:
        raise CoordError(two_d=False)
    per_point = len(tuples[0].split(cs))
    flat = " ".join(t.replace(cs, " ") for t in tuples)
    if dec != ".":
        flat = flat.replace(dec, ".")
    return _coords(_numbers(flat), dim, per_point)


def polygon_rings(el, dim: int | None) -> tuple[np.ndarray, list[np.ndarray]]:
    """Exterior and interior rings of a Polygon / PolygonPatch / Triangle / Rectangle element."""
    dim = dim_attr(el, dim)
    exterior = None
    interiors: list[np.ndarray] = []
    for c in el:
        tag = c.tag
        if tag.__class__ is not str:
            continue
        local = tag[tag.rfind("}") + 1 :]
        if local in ("exterior", "outerBoundaryIs", "interior", "innerBoundaryIs"):
            ring_el = next((r for r in c if r.tag.__class__ is str), None)
            if ring_el is None:
                raise CoordError(two_d=False)
            ring = _ring(ring_el, dim)
            if local in ("exterior", "outerBoundaryIs"):
                exterior = ring
            else:
                interiors.append(ring)
    if exterior is None:
        raise CoordError(two_d=False)
    return exterior, interiors

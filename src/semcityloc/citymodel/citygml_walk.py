"""The walk of one CityGML Building: its polygons with part, LoD and class, its XLinks and its gml:ids.

Why a module of its own: this is the reader's inner loop (every element of every building passes through
``CityObjectWalk._walk``), and the one place that knows how CityGML nests geometry: a BuildingPart starts a
part, a boundary surface (``RoofSurface``, ``Window``...) gives its class to what is below it, a ``lodN``
property its LoD, an OrientableSurface with ``orientation="-"`` reverses the rings below it, a Solid is read
by its exterior shell only (interior shells are closed cavities), and ``srsDimension`` is inherited. What an
element is comes from ``citygml_names.classify`` (cached per tag); a polygon's rings from
``gml_geometry.polygon_rings``; every ``srsName`` and Envelope goes to the ``CRSChoice``.

The result (``WalkedBuilding``) is in file coordinates, before XLink resolution (``citygml_xlinks``), LoD
selection (``citygml_lod_choice``) and CRS conversion. Polygons that cannot be meshed are counted where they
are met, in ``CityGMLReport`` (no LoD, 2D, unreadable) or ``ParseStats`` (NaN, infinite or absurd
coordinates: ``builder.usable_polygon``), and dropped.
"""

from __future__ import annotations

from typing import NamedTuple

from semcityloc.citymodel.builder import usable_polygon
from semcityloc.citymodel.citygml_crs import CRSChoice
from semcityloc.citymodel.citygml_names import (
    HREF_FEATURE_PROPERTIES,
    K_DESCEND,
    K_ENVELOPE_PROP,
    K_GML_CONTAINER,
    K_IMPLICIT,
    K_LOD,
    K_LOD_SKIP,
    K_ORIENTABLE,
    K_PART,
    K_POLYGON,
    K_SEMANTIC,
    K_SKIP,
    K_SOLID,
    OPENING_NAMES,
    XLINK_HREF,
    classify,
    local_name,
)
from semcityloc.citymodel.citygml_records import CityGMLReport, SurfaceRecord, SurfaceRef
from semcityloc.citymodel.gml_geometry import CoordError, dim_attr, polygon_rings
from semcityloc.citymodel.model import ParseStats


class WalkedBuilding(NamedTuple):
    """What one Building holds: its polygons, the XLinks met, and the polygons' span per gml:id."""

    records: list[SurfaceRecord]
    refs: list[SurfaceRef]
    ids: dict[str, tuple[int, int]]  # gml:id -> (start, end) of the records below that element


class CityObjectWalk:
    """The walk of every Building of one file: ``gml_id`` is the attribute its ids are in (by CityGML
    version); counts go to ``report`` and ``stats``, CRS names and Envelopes to ``crs_choice``."""

    def __init__(self, gml_id: str, crs_choice: CRSChoice, report: CityGMLReport, stats: ParseStats):
        self._gml_id = gml_id
        self._crs_choice = crs_choice
        self.report = report
        self.stats = stats
        self._kinds: dict[str, tuple[int, int]] = {}
        # per building
        self._recs: list[SurfaceRecord] = []
        self._refs: list[SurfaceRef] = []
        self._ids: dict[str, tuple[int, int]] = {}
        self._n_parts = 0

    def building(self, obj) -> WalkedBuilding:
        """The polygons, XLinks and gml:id spans of the Building element ``obj`` (its parts included)."""
        self._recs, self._refs, self._ids, self._n_parts = [], [], {}, 0
        self._walk(obj, 0, None, None, False, None)
        return WalkedBuilding(self._recs, self._refs, self._ids)

    def _walk(self, el, part: int, sem: int | None, lod: int | None, flip: bool, dim: int | None) -> None:
        kinds = self._kinds
        recs = self._recs
        gml_id = self._gml_id
        for child in el:
            tag = child.tag
            if tag.__class__ is not str:
                continue  # an unexpanded entity reference
            k = kinds.get(tag)
            if k is None:
                k = kinds[tag] = classify(tag)
            kind, arg = k
            if kind == K_SKIP:
                continue
            if kind == K_ENVELOPE_PROP:
                self._crs_choice.read_envelope_prop(child)
                continue
            if kind == K_LOD_SKIP:
                continue
            if kind == K_IMPLICIT:
                self.report.implicit_geometries += 1
                continue
            gid = child.get(gml_id)
            start = len(recs)
            c_part, c_sem, c_lod, c_flip, c_dim = part, sem, lod, flip, dim
            if kind == K_POLYGON:
                self._polygon(child, part, sem, lod, flip, dim, gid)
            elif kind == K_GML_CONTAINER or kind == K_SOLID or kind == K_ORIENTABLE:
                srs = child.get("srsName")
                if srs is not None:
                    self._crs_choice.note_srs(srs)
                c_dim = dim_attr(child, dim)
                if kind == K_ORIENTABLE and child.get("orientation") == "-":
                    c_flip = not flip
            elif kind == K_LOD:
                c_lod = arg
            elif kind == K_SEMANTIC:
                c_sem, c_lod = arg, None
                local = local_name(tag)
                if local in OPENING_NAMES:
                    self.report.openings[local] += 1
            elif kind == K_PART:
                self._n_parts += 1
                self.report.building_parts += 1
                c_part, c_sem, c_lod, c_flip = self._n_parts, None, None, False
            if kind != K_POLYGON:
                href = child.get(XLINK_HREF)
                if href is not None:
                    if c_lod is not None or (
                        kind == K_DESCEND and local_name(tag) in HREF_FEATURE_PROPERTIES
                    ):
                        self._refs.append(SurfaceRef(href.lstrip("#"), c_part, c_lod, c_sem, c_flip))
                elif kind == K_SOLID:
                    for sub in child:  # exterior shell only: interior shells are closed cavities
                        if sub.tag.__class__ is str and local_name(sub.tag) == "exterior":
                            self._walk(sub, c_part, c_sem, c_lod, c_flip, c_dim)
                else:
                    self._walk(child, c_part, c_sem, c_lod, c_flip, c_dim)
            if gid is not None and len(recs) > start:
                self._ids[gid] = (start, len(recs))

    def _polygon(self, el, part, sem, lod, flip, dim, gid) -> None:
        if lod is None:
            self.report.polygons_without_lod += 1
            return
        srs = el.get("srsName")
        if srs is not None:
            self._crs_choice.note_srs(srs)
        try:
            ext, holes = polygon_rings(el, dim)
        except CoordError as exc:
            if exc.two_d:
                self.report.polygons_2d += 1
            else:
                self.report.malformed_polygons += 1
            return
        if not usable_polygon(ext, holes):
            self.stats.invalid_coordinate_polygons += 1
            return
        if flip:
            ext, holes = ext[::-1], [h[::-1] for h in holes]
        self.report.lod_polygons[lod] += 1
        self._recs.append(SurfaceRecord(part, lod, sem, ext, holes, gid, False))

"""Read the buildings of a CityGML 1.0 / 2.0 / 3.0 file into a semantic triangle mesh (``CityModel``).

Why a streaming reader: state CityGML tiles reach 1 GB, so the file is read with ``lxml.etree.iterparse``
one ``cityObjectMember`` at a time; every processed member (and everything before it) is cleared, so memory
holds one city object plus the growing mesh.

What it reads:

- Buildings and their BuildingParts (a part's polygons belong to its building), BuildingInstallations,
  boundary surfaces (``boundedBy`` in 1.0/2.0, ``boundary`` in 3.0) with their semantic class
  (``classes.SURFACE_CLASS``), LoD3/LoD4 openings (``Window`` / ``Door``), and plain ``lodNSolid`` /
  ``lodNMultiSurface`` / ``lodNGeometry`` geometry without semantics (``semantic=None``: the mesh builder
  classifies those by their normals). Interior rooms, furniture and interior installations are skipped
  (invisible from the air), as are implicit geometries, curves and non-building city objects (counted).
- GML geometry: Polygon (``exterior``/``interior`` and GML2 ``outerBoundaryIs``/``innerBoundaryIs``) with
  LinearRings of ``posList`` (``srsDimension``, default 3), ``pos`` or GML2 ``coordinates``;
  MultiSurface, CompositeSurface, Shell, Solid (exterior shell only), OrientableSurface (``orientation="-"``
  reverses the rings), Surface/PolygonPatch, TriangulatedSurface/Tin/Triangle.
- XLinks (``xlink:href="#id"``) to any surface with a ``gml:id`` (a polygon or a whole composite): resolved
  within the city object first, then against a bounded cache of earlier objects' surfaces, then against
  later objects as they stream by; what never resolves is counted in ``stats.unresolved_xlinks``. A polygon
  reached twice in one building (a ``lod2Solid`` member that points into a ``RoofSurface``) is meshed once,
  with the boundary surface's class.
- LoD: ``lod=None`` keeps, per building and per BuildingPart, the highest LoD it has (a building's own
  geometry is dropped when one of its parts is more detailed: the coarse shell would enclose the parts);
  ``lod=N`` keeps only LoD N (a whole number 0 to 4, also as ``"2"`` / ``"2.0"``; anything else is a
  ``ParameterError``: ``citygml_lod``). Every triangle records its LoD.
- CRS: the first ``srsName`` of the file (root or building Envelope, or a geometry) names it; different later
  names only warn. ``crs_override`` replaces it. Geographic CRSs (PLATEAU's EPSG:6697, latitude first) are
  projected to the UTM zone of the data with ``MetricFrame``: the zone of the first Envelope's centre when
  that Envelope holds the first building, else (a stale Envelope) of the first building, with a warning.

2D coordinates (``srsDimension="2"`` or two numbers per point): such polygons are skipped and counted; a file
with nothing but 2D polygons raises ``InputFileError`` (there is no height to build a 3D model from).
Skipped polygons are counted in ``stats`` (``malformed_polygons``: no exterior ring or unreadable numbers;
``polygons_2d``; ``polygons_without_lod``), each kind with a warning, wherever they are parsed (any LoD).
Coordinates that are NaN, infinite or absurd (``builder.usable_points``: beyond 1e9 m): such polygons are
dropped where they are parsed (before LoD selection, the CRS's sample point and the triangulation) and
counted in ``stats.invalid_coordinate_polygons`` (one warning); a file with nothing else raises
``EmptyModelError`` saying so.

Safety: the parser never resolves entities, never loads a DTD and never touches the network; a DOCTYPE that
declares entities is refused (``MalformedXMLError``): CityGML never uses them, and leaving them unexpanded
would silently drop text (``citygml_xml``).

This module streams the file one city object at a time, hands each Building through the stages and turns
what they keep into mesh polygons in the metric frame; each stage is a module of its own:

- ``citygml_xml``: the file opened and parsed safely, read errors typed;
- ``citygml_names``: the root's CityGML version, and what each element is to the walk;
- ``citygml_walk``: one Building's polygons, XLinks and gml:ids (``gml_geometry`` reads a polygon's rings);
- ``citygml_xlinks``: XLinks resolved within the building, against earlier and later ones;
- ``citygml_lod_choice``: the LoD kept per building and part, each surface once;
- ``citygml_crs``: the metric frame;
- ``citygml_records``: the records and the ``CityGMLReport`` these stages share.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pyproj
from lxml import etree

from semcityloc.citymodel.builder import MeshBuilder, invalid_coordinates_note
from semcityloc.citymodel.citygml_crs import CRSChoice
from semcityloc.citymodel.citygml_lod_choice import LodChoice, citygml_lod
from semcityloc.citymodel.citygml_names import (
    CITYGML_NS,
    GML_ID_31,
    citygml_version,
    local_name,
    tag_namespace,
)
from semcityloc.citymodel.citygml_records import CityGMLReport, SurfaceRecord
from semcityloc.citymodel.citygml_walk import CityObjectWalk
from semcityloc.citymodel.citygml_xlinks import XLinkResolver
from semcityloc.citymodel.citygml_xml import PARSER_OPTIONS, external_entity_error, reading, root_element
from semcityloc.citymodel.crs import parse_crs_name
from semcityloc.citymodel.model import CityModel, ParseStats
from semcityloc.errors import EmptyModelError, InputFileError, LodNotHeldError, counted

__all__ = [
    "CityGMLPolygon",
    "CityGMLReader",
    "CityGMLReport",
    "citygml_lod",
    "iter_citygml_polygons",
    "read_citygml",
]

# Members of the root that hold city objects / that we clear as soon as they end.
_MEMBER_NAMES = ("cityObjectMember", "featureMember", "featureMembers")
_TOP_LEVEL_TAGS = tuple(f"{{*}}{n}" for n in (*_MEMBER_NAMES, "appearanceMember", "boundedBy"))


class CityGMLPolygon(NamedTuple):
    """One polygon as it goes into the mesh: metric world coordinates (after CRS conversion)."""

    building_id: str
    semantic: int | None  # SemanticClass id, or None = classify by normals
    lod: int
    exterior: np.ndarray  # (n, 3) float64
    interiors: list[np.ndarray]


class CityGMLReader:
    """One pass over a CityGML file. ``polygons()`` streams the mesh polygons; afterwards ``crs``,
    ``source_crs``, ``stats`` (``ParseStats`` for the mesh) and ``report`` describe what was read."""

    def __init__(
        self,
        path: str | Path,
        lod: int | str | None = None,
        target_crs: pyproj.CRS | str | None = None,
        crs_override: str | None = None,
    ):
        self.path = Path(path)
        self.lod = citygml_lod(lod, self.path)
        self.target_crs = parse_crs_name(target_crs) if isinstance(target_crs, str) else target_crs
        self.crs_override = crs_override
        self.stats = ParseStats()
        self.report = CityGMLReport()
        self.crs: pyproj.CRS | None = None
        self.source_crs: pyproj.CRS | None = None
        self._started = False
        self._external_dtd: str | None = None  # the DOCTYPE's external DTD (never loaded)

        self._gml_id = GML_ID_31  # the gml:id attribute: GML 3.1 in CityGML 1.0/2.0, GML 3.2 in 3.0
        self._crs_choice = CRSChoice(
            self.path, self.target_crs, crs_override, self.stats, self.report.srs_names
        )
        self._xlinks = XLinkResolver(self.report)
        self._lods = LodChoice(self.lod, self.report)

    # ------------------------------------------------------------------ streaming
    def polygons(self) -> Iterator[CityGMLPolygon]:
        """Mesh polygons in metric world coordinates, building by building (late XLinks at the end)."""
        if self._started:
            raise RuntimeError("CityGMLReader.polygons() streams the file once: make a new reader")
        self._started = True
        self._check_root()
        walk = CityObjectWalk(self._gml_id, self._crs_choice, self.report, self.stats)
        yielded = 0
        with reading(self.path) as fh:
            context = etree.iterparse(fh, events=("end",), tag=_TOP_LEVEL_TAGS, **PARSER_OPTIONS)
            for _, el in context:
                parent = el.getparent()
                if parent is None or parent.getparent() is not None:
                    continue  # a nested boundedBy: handled with its city object
                local = local_name(el.tag)
                if local == "boundedBy":
                    self._crs_choice.read_envelope_prop(el)
                elif local in _MEMBER_NAMES:
                    objects = list(el) if local == "featureMembers" else [next(iter(el), None)]
                    for obj in objects:
                        if obj is not None and obj.tag.__class__ is str:
                            for p in self._city_object(walk, obj):
                                yielded += 1
                                yield p
                el.clear()
                while el.getprevious() is not None:
                    del parent[0]

        self.stats.unresolved_xlinks += self._xlinks.unresolved()
        self._count_skipped()
        if self.report.skipped_objects:
            names = ", ".join(f"{k} x{v}" for k, v in sorted(self.report.skipped_objects.items()))
            self.stats.warnings.append(f"skipped non-building city objects: {names}")
        if self.report.implicit_geometries:
            self.stats.warnings.append(
                f"{self.report.implicit_geometries} implicit geometries (lodNImplicitRepresentation) not read"
            )
        if yielded == 0:
            self._raise_empty()

    def _count_skipped(self) -> None:
        """The polygons skipped where they were parsed (2D, unreadable) into ``stats``, each kind with a
        warning: a dropped roof must show in ``city info`` and in the commands' warnings, not vanish."""
        r, stats = self.report, self.stats
        stats.malformed_polygons += r.malformed_polygons
        stats.polygons_2d += r.polygons_2d
        stats.polygons_without_lod += r.polygons_without_lod
        if r.malformed_polygons:
            stats.warnings.append(
                f"skipped {r.malformed_polygons} polygons without an exterior ring or with unreadable "
                "coordinates (a token that is no number, or a count that does not fit the dimension)"
            )
        if r.polygons_2d:
            stats.warnings.append(f"skipped {r.polygons_2d} polygons with 2D coordinates (no heights)")
        if r.polygons_without_lod:
            stats.warnings.append(
                f"skipped {r.polygons_without_lod} polygons outside any lodN property (ADE geometry: no LoD)"
            )

    def _raise_empty(self) -> None:
        r = self.report
        self.refuse_external_entities()
        if r.buildings == 0:
            found = ", ".join(f"{k} x{v}" for k, v in sorted(r.skipped_objects.items())) or "nothing"
            raise EmptyModelError(f"{self.path}: no Building city objects (found: {found})")
        present = sorted(r.lod_polygons)
        if self.lod is not None and present:
            raise LodNotHeldError(
                f"{self.path}: no LoD {self.lod} building geometry; "
                f"LoDs present: {', '.join(map(str, present))}",
                present=", ".join(map(str, present)),
            )
        if r.polygons_2d:
            raise InputFileError(
                f"{self.path}: all {r.polygons_2d} building polygons have 2D coordinates (no heights): "
                "cannot build a 3D model"
            )
        invalid = self.stats.invalid_coordinate_polygons
        why = f" ({invalid_coordinates_note(invalid)})" if invalid else ""
        raise EmptyModelError(
            f"{self.path}: {counted(r.buildings, 'building')} but no readable building surfaces{why}"
        )

    def _check_root(self) -> None:
        """Reject unknown roots and entity-declaring DTDs before streaming the whole file."""
        tag, self._external_dtd = root_element(self.path)
        if self._external_dtd is not None:
            self.stats.warnings.append(f"external DTD {self._external_dtd!r} not loaded")
        self.report.version, self._gml_id = citygml_version(self.path, tag)

    def refuse_external_entities(self) -> None:
        """When nothing could be read from a document with an external DTD whose entities it uses: the
        ``MalformedXMLError`` naming the DTD and the entity (the DTD is never loaded, module docstring)."""
        error = external_entity_error(self.path, self._external_dtd)
        if error is not None:
            raise error

    # ------------------------------------------------------------------ one city object
    def _city_object(self, walk: CityObjectWalk, obj) -> list[CityGMLPolygon]:
        local = local_name(obj.tag)
        m = CITYGML_NS.match(tag_namespace(obj.tag))
        if local != "Building" or m is None:
            self.report.skipped_objects[local] += 1
            return []
        self.report.buildings += 1
        building_id = obj.get(self._gml_id) or f"building_{self.report.buildings}"
        walked = walk.building(obj)
        resolved, waiting = self._xlinks.resolve(building_id, walked)
        out = self._output(building_id, self._lods.building(building_id, walked.records + resolved, waiting))
        late: list[CityGMLPolygon] = []
        for other_id, recs in self._xlinks.register(walked):
            late += self._output(other_id, self._lods.late(other_id, recs))
        if not out:
            self.report.buildings_without_geometry += 1
        return out + late

    def _output(self, building_id: str, recs: list[SurfaceRecord]) -> list[CityGMLPolygon]:
        """The kept records as mesh polygons in the metric frame (chosen at the first building with any)."""
        if not recs:
            return []
        choice = self._crs_choice
        if choice.frame is None:
            frame = choice.choose([r.exterior for r in recs])
            self.source_crs, self.crs = frame.source, frame.target
        out = []
        if choice.identity:
            for r in recs:
                out.append(CityGMLPolygon(building_id, r.semantic, r.lod, r.exterior, r.interiors))
        else:
            rings = [ring for r in recs for ring in (r.exterior, *r.interiors)]
            metric = choice.frame.to_metric(np.concatenate(rings))
            bounds = np.cumsum([len(x) for x in rings])[:-1]
            parts = np.split(metric, bounds)
            i = 0
            for r in recs:
                n = 1 + len(r.interiors)
                out.append(CityGMLPolygon(building_id, r.semantic, r.lod, parts[i], parts[i + 1 : i + n]))
                i += n
        self.report.polygons += len(out)
        return out


def iter_citygml_polygons(
    path: str | Path,
    lod: int | str | None = None,
    target_crs: pyproj.CRS | str | None = None,
    crs_override: str | None = None,
) -> Iterator[CityGMLPolygon]:
    """The polygons ``read_citygml`` meshes, one by one, in metric world coordinates (checks, tools)."""
    yield from CityGMLReader(path, lod, target_crs, crs_override).polygons()


def read_citygml(
    path: str | Path,
    lod: int | str | None = None,
    target_crs: pyproj.CRS | str | None = None,
    crs_override: str | None = None,
    origin: np.ndarray | None = None,
) -> CityModel:
    """Read the buildings of a CityGML 1.0 / 2.0 / 3.0 file (``.gml``, ``.xml``, gzip) into a ``CityModel``.

    ``lod=None``: each building's (and part's) highest LoD; ``lod=N``: only LoD N (``EmptyModelError`` naming
    the LoDs present if there is none). ``target_crs``: metric CRS to convert to (default: the file's CRS,
    or the UTM zone of the data for a geographic CRS). ``crs_override``: CRS name replacing the file's
    ``srsName``. Raises ``InputFileError`` (missing file), ``MalformedXMLError`` (not XML, truncated,
    entity declarations), ``UnsupportedFormatError`` (not a CityGML 1-3 CityModel), ``CRSError``,
    ``EmptyModelError``, ``ParameterError`` (``lod`` no whole LoD 0 to 4: ``citygml_lod``). ``origin``: the
    local frame's float64 origin (default: the data's rounded centre; a tile store gives all its tiles one).
    """
    reader = CityGMLReader(path, lod, target_crs, crs_override)
    builder = MeshBuilder(reader.stats)
    add = builder.add_polygon
    for p in reader.polygons():
        add(p.exterior, p.interiors, p.semantic, p.building_id, p.lod)
    try:
        return builder.build(
            crs=reader.crs, source_crs=reader.source_crs, source=str(reader.path), origin=origin
        )
    except EmptyModelError:
        reader.refuse_external_entities()
        raise

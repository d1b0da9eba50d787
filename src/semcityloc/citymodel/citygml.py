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
would silently drop text.

This module streams the file, walks each city object, resolves XLinks and selects LoDs; three modules do
the rest: ``gml_geometry`` reads a polygon's rings, ``citygml_names`` says what each element is to the walk,
``citygml_crs`` chooses the metric frame.
"""

from __future__ import annotations

import gzip
import operator
import zlib
from collections import Counter, OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, NamedTuple

import numpy as np
import pyproj
from lxml import etree

from semcityloc.citymodel.builder import MeshBuilder, invalid_coordinates_note, usable_polygon
from semcityloc.citymodel.citygml_crs import CRSChoice
from semcityloc.citymodel.citygml_names import (
    CITYGML_NS,
    GML_ID_31,
    GML_ID_32,
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
    tag_namespace,
)
from semcityloc.citymodel.cityjson import lod_key
from semcityloc.citymodel.crs import parse_crs_name
from semcityloc.citymodel.gml_geometry import CoordError, dim_attr, polygon_rings
from semcityloc.citymodel.limits import check_file_size
from semcityloc.citymodel.model import CityModel, ParseStats
from semcityloc.errors import (
    EmptyModelError,
    InputFileError,
    MalformedXMLError,
    ParameterError,
    UnsupportedFormatError,
    counted,
)

__all__ = [
    "CityGMLPolygon",
    "CityGMLReader",
    "CityGMLReport",
    "citygml_lod",
    "iter_citygml_polygons",
    "read_citygml",
]

# The safe parser settings (also used for the root sniff): no entity expansion, no DTD, no network, libxml2's
# default size limits (huge_tree=False), and no id hash table (we index gml:ids ourselves, bounded).
PARSER_OPTIONS = dict(
    resolve_entities=False,
    no_network=True,
    load_dtd=False,
    dtd_validation=False,
    huge_tree=False,
    remove_comments=True,
    remove_pis=True,
    collect_ids=False,
    recover=False,
)

# Cross-object XLink cache: surfaces (by gml:id) of earlier city objects kept for later references.
XLINK_CACHE_IDS = 100_000

SUPPORTED_MAJOR_VERSIONS = (1, 2, 3)

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


@dataclass
class CityGMLReport:
    """What the CityGML reader met, beyond the ``ParseStats`` the mesh keeps."""

    version: str = ""  # CityGML version of the root namespace, e.g. "2.0"
    buildings: int = 0  # Building city objects
    building_parts: int = 0
    buildings_without_geometry: int = 0  # buildings that contributed no polygon (after LoD selection)
    openings: Counter = field(default_factory=Counter)  # Window / Door objects (and 3.0 filling surfaces)
    skipped_objects: Counter = field(default_factory=Counter)  # non-building city objects by element name
    lod_polygons: Counter = field(default_factory=Counter)  # LoD -> polygons defined in the file (any LoD)
    polygons: int = 0  # polygons handed to the mesh
    polygons_2d: int = 0  # skipped: no heights
    malformed_polygons: int = 0  # skipped: no exterior ring or unreadable coordinates
    polygons_without_lod: int = 0  # geometry outside any lodN property (ADE content): skipped
    duplicate_polygons: int = 0  # reached twice in one building (solid member + boundary surface)
    xlinks_resolved: int = 0
    xlinks_cross_object: int = 0  # resolved against another city object
    implicit_geometries: int = 0  # lodNImplicitRepresentation: not read
    srs_names: list[str] = field(default_factory=list)  # distinct srsName strings, in order of appearance


# A polygon while its city object is read: file coordinates, before LoD selection and CRS conversion.
class _Rec(NamedTuple):
    part: int  # 0 = the building itself, 1.. = its BuildingParts
    lod: int
    semantic: int | None
    exterior: np.ndarray
    interiors: list[np.ndarray]
    gml_id: str | None
    via_xlink: bool


class _Ref(NamedTuple):
    target: str
    part: int
    lod: int | None
    semantic: int | None
    flip: bool


def citygml_lod(lod: object, path: Path | None = None) -> int | None:
    """The LoD the reader keeps for ``lod``: None (each building's highest) or a whole LoD 0 to 4, given as
    an int or in a form the CityJSON reader takes for it (``"2"``, ``"2.0"``, ``2.0``: ``lod_key``).

    CityGML's LoDs are whole numbers, so anything else (``"foo"``, ``-1``, ``7``, ``"2.2"``, ``True``) is a
    ``ParameterError`` naming the value, raised before the file is opened, rather than a ``TypeError`` from
    deep inside or an empty model.
    """
    if lod is None:
        return None
    value = lod
    if not isinstance(lod, bool):
        try:
            value = operator.index(lod)  # numpy integers too
        except TypeError:
            pass
    key = lod_key(value)
    if key is None or "." in key:
        where = f"{path}: " if path is not None else ""
        raise ParameterError(
            f"{where}LoD {lod!r} is not a CityGML LoD: give a whole number 0 to 4 (or no LoD for each "
            "building's highest)"
        )
    return int(key)


def _xml_error(path: Path, exc: etree.XMLSyntaxError) -> MalformedXMLError:
    if "amplification" in str(exc.msg):  # libxml2 stopped an entity expansion: a hostile file, not a typo
        return MalformedXMLError(
            f"{path}: refused: its DTD declares entities that expand without bound (a 'billion laughs' or "
            f"quadratic-blowup document, line {exc.lineno}); city models need no entities"
        )
    return MalformedXMLError(f"{path}: not well-formed XML, line {exc.lineno}: {exc.msg}")


def _open(path: Path) -> IO[bytes]:
    """The file as a binary stream; gzip (by its magic bytes) is decompressed on the fly."""
    try:
        fh = open(path, "rb")  # noqa: SIM115 - returned to the caller, who closes it
    except FileNotFoundError as exc:
        raise InputFileError(f"{path}: no such file") from exc
    except IsADirectoryError as exc:
        raise InputFileError(f"{path}: is a directory, not a CityGML file") from exc
    except OSError as exc:
        raise InputFileError(f"{path}: cannot open ({exc.strerror or exc})") from exc
    check_file_size(path, "CityGML")
    if fh.read(2) == b"\x1f\x8b":
        fh.seek(0)
        return gzip.GzipFile(fileobj=fh, mode="rb")
    fh.seek(0)
    return fh


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

        self._kinds: dict[str, tuple[int, int]] = {}
        self._gml_id = GML_ID_31  # the gml:id attribute: GML 3.1 in CityGML 1.0/2.0, GML 3.2 in 3.0
        self._crs_choice = CRSChoice(
            self.path, self.target_crs, crs_override, self.stats, self.report.srs_names
        )
        # per city object
        self._recs: list[_Rec] = []
        self._refs: list[_Ref] = []
        self._ids: dict[str, tuple[int, int]] = {}
        self._n_parts = 0
        # across city objects
        self._cache: OrderedDict[str, list[_Rec]] = OrderedDict()
        self._pending: dict[str, list[tuple[str, _Ref]]] = {}
        self._late: dict[str, tuple[dict[int, int], set[str]]] = {}

    # ------------------------------------------------------------------ streaming
    def polygons(self) -> Iterator[CityGMLPolygon]:
        """Mesh polygons in metric world coordinates, building by building (late XLinks at the end)."""
        if self._started:
            raise RuntimeError("CityGMLReader.polygons() streams the file once: make a new reader")
        self._started = True
        self._check_root()
        yielded = 0
        fh = _open(self.path)
        try:
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
                            for p in self._city_object(obj):
                                yielded += 1
                                yield p
                el.clear()
                while el.getprevious() is not None:
                    del parent[0]
        except etree.XMLSyntaxError as exc:
            raise _xml_error(self.path, exc) from exc
        except (EOFError, zlib.error, gzip.BadGzipFile) as exc:
            raise MalformedXMLError(f"{self.path}: truncated or corrupt gzip stream ({exc})") from exc
        except OSError as exc:
            raise InputFileError(f"{self.path}: read error ({exc})") from exc
        finally:
            fh.close()

        self.stats.unresolved_xlinks += sum(len(v) for v in self._pending.values())
        self._pending.clear()
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
            raise EmptyModelError(
                f"{self.path}: no LoD {self.lod} building geometry; "
                f"LoDs present: {', '.join(map(str, present))}"
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
        fh = _open(self.path)
        try:
            _, root = next(iter(etree.iterparse(fh, events=("start",), **PARSER_OPTIONS)))
            docinfo = root.getroottree().docinfo
        except etree.XMLSyntaxError as exc:
            raise _xml_error(self.path, exc) from exc
        except (EOFError, zlib.error, gzip.BadGzipFile) as exc:
            raise MalformedXMLError(f"{self.path}: truncated or corrupt gzip stream ({exc})") from exc
        except OSError as exc:
            raise InputFileError(f"{self.path}: read error ({exc})") from exc
        finally:
            fh.close()
        dtd = docinfo.internalDTD
        if dtd is not None and any(True for _ in dtd.iterentities()):
            raise MalformedXMLError(
                f"{self.path}: the DOCTYPE declares XML entities; CityGML does not use them and they are "
                "refused (entity expansion is a known attack)"
            )
        if docinfo.system_url or docinfo.public_id:
            self._external_dtd = docinfo.system_url or docinfo.public_id
            self.stats.warnings.append(f"external DTD {self._external_dtd!r} not loaded")
        tag = root.tag if isinstance(root.tag, str) else ""
        ns, local = tag_namespace(tag), local_name(tag)
        m = CITYGML_NS.match(ns)
        if local == "CityModel" and m is not None and m.group(1) is None:
            major, minor = int(m.group(2)), int(m.group(3))
            if major not in SUPPORTED_MAJOR_VERSIONS:
                raise UnsupportedFormatError(
                    f"{self.path}: CityGML {major}.{minor} (root <{local}> in {ns}) is not supported; "
                    "this reader knows CityGML 1.x, 2.x and 3.x"
                )
            self.report.version = f"{major}.{minor}"
            self._gml_id = GML_ID_32 if major >= 3 else GML_ID_31
            return
        if local == "CityModel" or m is not None:
            raise UnsupportedFormatError(
                f"{self.path}: root <{local}> in namespace {ns or '(none)'!r} is not a known CityGML "
                "version's CityModel (expected http://www.opengis.net/citygml/1.0, 2.0 or 3.0)"
            )
        raise UnsupportedFormatError(
            f"{self.path}: root element <{local}> (namespace {ns or '(none)'!r}) is not a CityGML CityModel"
        )

    def refuse_external_entities(self) -> None:
        """When nothing could be read from a document with an external DTD whose entities it uses: the
        ``MalformedXMLError`` naming the DTD and the entity (the DTD is never loaded, module docstring)."""
        if self._external_dtd is None:
            return
        entity = self._first_entity_reference()
        if entity is not None:
            raise MalformedXMLError(
                f"{self.path}: no building surfaces could be read: the document uses the entity "
                f"&{entity}; declared in the external DTD {self._external_dtd!r}, which is never loaded "
                "(external DTDs and entities are refused: they are how XXE attacks read files and the "
                "network)"
            )

    def _first_entity_reference(self) -> str | None:
        """The name of the first (unexpanded) entity reference in the document, or None."""
        fh = _open(self.path)
        try:
            for _, el in etree.iterparse(fh, events=("end",), **PARSER_OPTIONS):
                for child in el:
                    if isinstance(child, etree._Entity):
                        return child.name
                el.clear()
        except (etree.XMLSyntaxError, EOFError, zlib.error, gzip.BadGzipFile, OSError):
            return None
        finally:
            fh.close()
        return None

    # ------------------------------------------------------------------ one city object
    def _city_object(self, obj) -> list[CityGMLPolygon]:
        local = local_name(obj.tag)
        m = CITYGML_NS.match(tag_namespace(obj.tag))
        if local != "Building" or m is None:
            self.report.skipped_objects[local] += 1
            return []
        self.report.buildings += 1
        building_id = obj.get(self._gml_id) or f"building_{self.report.buildings}"
        self._recs, self._refs, self._ids, self._n_parts = [], [], {}, 0
        self._walk(obj, 0, None, None, False, None)
        out = self._finish_building(building_id)
        late = self._register_ids()
        if not out:
            self.report.buildings_without_geometry += 1
        return out + late

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
                        self._refs.append(_Ref(href.lstrip("#"), c_part, c_lod, c_sem, c_flip))
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
        self._recs.append(_Rec(part, lod, sem, ext, holes, gid, False))

    # ------------------------------------------------------------------ xlinks, LoD selection, output
    def _expand(self, ref: _Ref, targets: list[_Rec]) -> list[_Rec]:
        out = []
        for r in targets:
            ext, holes = r.exterior, r.interiors
            if ref.flip:
                ext, holes = ext[::-1], [h[::-1] for h in holes]
            out.append(
                _Rec(
                    ref.part,
                    r.lod if ref.lod is None else ref.lod,
                    r.semantic if ref.semantic is None else ref.semantic,
                    ext,
                    holes,
                    r.gml_id,
                    True,
                )
            )
        return out

    def _finish_building(self, building_id: str) -> list[CityGMLPolygon]:
        recs = self._recs
        resolved: list[_Rec] = []
        waiting: list[_Ref] = []
        for ref in self._refs:
            span = self._ids.get(ref.target)
            if span is not None:
                resolved += self._expand(ref, recs[span[0] : span[1]])
                self.report.xlinks_resolved += 1
                continue
            cached = self._cache.get(ref.target)
            if cached is not None:
                resolved += self._expand(ref, cached)
                self.report.xlinks_resolved += 1
                self.report.xlinks_cross_object += 1
                continue
            waiting.append(ref)
        for ref in waiting:
            self._pending.setdefault(ref.target, []).append((building_id, ref))
        for r in resolved:  # a LoD reached only through references is present too (count: 0 polygons)
            self.report.lod_polygons.setdefault(r.lod, 0)
        all_recs = recs + resolved

        best: dict[int, int] = {}
        for r in all_recs:
            if r.lod > best.get(r.part, -1):
                best[r.part] = r.lod
        if self.lod is not None:
            chosen = {p: self.lod for p in best}
        else:
            chosen = dict(best)
            parts_best = max((v for p, v in chosen.items() if p != 0), default=-1)
            if 0 in chosen and parts_best > chosen[0]:
                chosen[0] = -1  # the building's own coarser shell would enclose its detailed parts
        seen: set[str] = set()
        keep = self._select(all_recs, chosen, seen)
        if waiting:
            self._late[building_id] = (chosen, seen)
        return self._output(building_id, keep)

    def _select(self, recs: list[_Rec], chosen: dict[int, int], seen: set[str]) -> list[_Rec]:
        """Records of the chosen LoD per part, each gml:id once (labelled, directly defined ones first)."""
        selected = [r for r in recs if chosen.get(r.part, r.lod) == r.lod]
        selected.sort(key=lambda r: (r.semantic is None, r.via_xlink))
        keep = []
        for r in selected:
            if r.gml_id is not None:
                if r.gml_id in seen:
                    self.report.duplicate_polygons += 1
                    continue
                seen.add(r.gml_id)
            keep.append(r)
        return keep

    def _register_ids(self) -> list[CityGMLPolygon]:
        """Offer this object's surfaces to earlier forward references and to later objects (bounded cache)."""
        late: list[CityGMLPolygon] = []
        recs = self._recs
        for gid, (a, b) in self._ids.items():
            targets = recs[a:b]
            waiting = self._pending.pop(gid, None) if self._pending else None
            if waiting:
                for building_id, ref in waiting:
                    self.report.xlinks_resolved += 1
                    self.report.xlinks_cross_object += 1
                    late += self._late_output(building_id, self._expand(ref, targets))
            self._cache[gid] = targets
            self._cache.move_to_end(gid)
        while len(self._cache) > XLINK_CACHE_IDS:
            self._cache.popitem(last=False)
        return late

    def _late_output(self, building_id: str, recs: list[_Rec]) -> list[CityGMLPolygon]:
        chosen, seen = self._late.get(building_id, ({}, set()))
        for r in recs:
            self.report.lod_polygons.setdefault(r.lod, 0)
            if self.lod is None:
                chosen.setdefault(r.part, r.lod)
            else:
                chosen[r.part] = self.lod
        return self._output(building_id, self._select(recs, chosen, seen))

    def _output(self, building_id: str, recs: list[_Rec]) -> list[CityGMLPolygon]:
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

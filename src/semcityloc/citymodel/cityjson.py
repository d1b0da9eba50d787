"""Read the buildings of a CityJSON file (versions 0.8, 0.9, 1.0, 1.1, 2.0) into a semantic ``CityModel``.

A CityJSONSeq stream (``.city.jsonl``, as 3DBAG's API and ``cjio export jsonl`` write it) is merged into one
document first (``cityjson_seq``) and read the same way.

Why a reader of its own: CityJSON stores one shared vertex list (integers with a ``transform`` since 1.0,
optional in 0.x) and nests boundaries and semantics by geometry type. We convert the vertex list once to
float64 world coordinates (``vertices * scale + translate``), then walk each building's geometry and hand
every surface (exterior ring first, holes after) to ``MeshBuilder.add_polygon`` with its class.

What is read and what is skipped (counted in ``model.stats.warnings``):

- City objects ``Building``, ``BuildingPart`` and ``BuildingInstallation``. Parts and installations are
  attached to their root ``Building`` by following ``parents`` (1.x/2.0) or ``parent`` (0.8/0.9);
  other types (roads, vegetation, water, bridges, land use, ``TINRelief`` ...) and ``+``-prefixed
  extension types are skipped and counted per type.
- Geometries ``MultiSurface``, ``CompositeSurface``, ``Solid``, ``MultiSolid``, ``CompositeSolid`` and
  ``GeometryInstance`` (a ``geometry-templates`` entry moved by its 4x4 matrix and reference vertex).
- Semantics: ``surfaces[i].type`` through ``classes.SURFACE_CLASS``; a surface without a value (or of an
  unknown type) gets ``semantic=None`` and the builder classifies it by its normal.
- LoD: ``lod=None`` keeps, per object, its highest LoD; an ``int`` keeps that LoD family (``2`` ->
  "2", "2.0", "2.2": the highest of those); a ``str``/``float`` is an exact LoD ("1.2"). When an object
  has several geometries of the chosen LoD, the one with semantics (then the one with more surfaces)
  is kept, so redundant encodings are not meshed twice. The integer part goes to ``CityModel.lods``.
- A polygon whose ring indexes a vertex that does not exist (or is not an integer) is skipped and
  counted, never an ``IndexError``; one whose vertices are NaN, infinite or absurd (``MeshBuilder``:
  ``builder.usable_points``) likewise, under its own count, before any arithmetic on them.

CRS: ``metadata.referenceSystem`` (``https://www.opengis.net/def/crs/EPSG/0/7415``, 0.8/1.0
``urn:ogc:def:crs:EPSG::7415``, or a bare EPSG number) or the 0.x ``metadata.crs.epsg``; ``crs_override``
wins. A file naming no
CRS gives ``crs=None`` and a warning. A geographic CRS is projected to its UTM zone (or ``target_crs``)
by ``MetricFrame``, axis order as the EPSG definition says (like the CityGML reader).
"""

from __future__ import annotations

import json
import re
import zlib
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from semcityloc.citymodel.builder import MAX_ABS_COORDINATE_M, MeshBuilder, usable_points
from semcityloc.citymodel.cityjson_seq import looks_like_sequence, merge_sequence
from semcityloc.citymodel.crs import (
    CRS_HINT,
    MetricFrame,
    check_degrees,
    named_by,
    overridden_warning,
    parse_crs_name,
)
from semcityloc.citymodel.limits import check_file_size, gunzip_bounded
from semcityloc.citymodel.model import CityModel, ParseStats
from semcityloc.classes import SURFACE_CLASS
from semcityloc.errors import (
    CRSError,
    EmptyModelError,
    InputFileError,
    LodNotHeldError,
    MalformedCityJSONError,
    UnsupportedFormatError,
)

SUPPORTED_VERSIONS = ("0.8", "0.9", "1.0", "1.1", "2.0")
BUILDING_TYPES = frozenset({"Building", "BuildingPart", "BuildingInstallation"})
# Nesting levels above the surface level: a MultiSurface is a list of surfaces, a Solid a list of
# shells (lists of surfaces), a MultiSolid a list of solids (lists of shells).
SURFACE_DEPTH = {"MultiSurface": 0, "CompositeSurface": 0, "Solid": 1, "MultiSolid": 2, "CompositeSolid": 2}
GEOMETRY_INSTANCE = "GeometryInstance"


def read_cityjson(
    path: str | Path,
    lod: str | int | float | None = None,
    target_crs: str | pyproj.CRS | None = None,
    crs_override: str | None = None,
    origin: np.ndarray | None = None,
) -> CityModel:
    """Read the buildings of a CityJSON file as a semantic triangle mesh.

    Args:
        path: a ``.json`` CityJSON file (gzip-compressed files are recognised by their magic bytes).
        lod: None = the highest LoD of each object; int = that LoD family (highest within it);
            str/float = that exact LoD, e.g. ``"1.2"`` (a value that is no LoD matches nothing).
        target_crs: metric CRS to project a geographic source to (default: its UTM zone).
        crs_override: CRS of the coordinates when the file names none or a wrong one.
        origin: the local frame's float64 origin (default: the data's rounded centre).

    Raises:
        InputFileError: the file cannot be read.
        MalformedCityJSONError: not JSON, or JSON that breaks the CityJSON top-level structure.
        UnsupportedFormatError: JSON that is not CityJSON (``type``) or a version we do not read.
        CRSError: a CRS that cannot be parsed; ``target_crs`` without any source CRS.
        EmptyModelError: no building surface is left (after LoD selection: the message names the LoDs).
    """
    path = Path(path)
    doc, notes = _load_json(path)
    version = _check_header(doc, path)
    return _CityJSONReader(doc, path, version, lod, notes).read(target_crs, crs_override, origin)


# ---------------------------------------------------------------------------------------------- file


def _load_json(path: Path) -> tuple[dict, list[str]]:
    """The document (a CityJSONSeq stream merged into one) and warnings about lines of a stream left out."""
    check_file_size(path, "CityJSON")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    if raw[:2] == b"\x1f\x8b":
        try:
            raw = gunzip_bounded(path, raw, "CityJSON")
        except (OSError, EOFError, zlib.error) as exc:
            raise MalformedCityJSONError(f"{path}: broken gzip stream ({exc})") from exc
    if looks_like_sequence(raw):
        return merge_sequence(raw, str(path))
    try:
        doc = json.loads(raw)
    except json.JSONDecodeError as exc:
        raise MalformedCityJSONError(
            f"{path}: not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})"
        ) from exc
    except (UnicodeDecodeError, RecursionError, ValueError) as exc:
        raise MalformedCityJSONError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(doc, dict):
        raise MalformedCityJSONError(
            f"{path}: the top level is a JSON {type(doc).__name__}, not a CityJSON object"
        )
    return doc, []


def _check_header(doc: dict, path: Path) -> str:
    """The file's ``major.minor`` version; typed errors for what is not CityJSON we read."""
    kind = doc.get("type")
    if kind == "CityJSONFeature":
        raise UnsupportedFormatError(
            f"{path}: a CityJSONFeature (one line of a CityJSONSeq stream), not a CityJSON file"
        )
    if kind != "CityJSON":
        raise UnsupportedFormatError(f"{path}: JSON with type {kind!r}, not 'CityJSON'")
    raw_version = doc.get("version")
    match = re.match(r"^\s*(\d+)\.(\d+)", str(raw_version)) if raw_version is not None else None
    version = f"{match.group(1)}.{match.group(2)}" if match else None
    if version not in SUPPORTED_VERSIONS:
        raise UnsupportedFormatError(
            f"{path}: CityJSON version {raw_version!r} is not supported "
            f"(supported: {', '.join(SUPPORTED_VERSIONS)})"
        )
    if not isinstance(doc.get("CityObjects"), dict):
        raise MalformedCityJSONError(f"{path}: 'CityObjects' is missing or not an object")
    if not isinstance(doc.get("vertices"), list | np.ndarray):  # an array: a CityJSONSeq stream merged
        raise MalformedCityJSONError(f"{path}: 'vertices' is missing or not an array")
    return version


def _type_of(node: dict) -> str | None:
    """The ``type`` member when it is a string (anything else in a broken file is no type)."""
    kind = node.get("type")
    return kind if isinstance(kind, str) else None


def _vertex_array(values: Any, what: str, path: Path) -> np.ndarray:
    """(n, 3) float64 from a JSON list of [x, y, z]."""
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise MalformedCityJSONError(f"{path}: '{what}' is not a list of [x, y, z] numbers") from exc
    if arr.size == 0:
        return np.zeros((0, 3))
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise MalformedCityJSONError(f"{path}: '{what}' has shape {arr.shape}, expected (n, 3)")
    return arr


# A transform's scale per axis must lie in (0, MAX_SCALE]: integer vertices times a scale beyond a metre per
# unit, or a zero / negative one (a flat or mirrored model), are a broken file, not a city.
MAX_SCALE = 1.0


def _transform(doc: dict, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(scale, translate) of the vertices: CityJSON 1.0+ has a ``transform``, older files may omit it (plain
    coordinates); a ``transform`` present but null or broken is refused, naming what is wrong with it."""
    if "transform" not in doc:
        return np.ones(3), np.zeros(3)
    t = doc["transform"]
    if not isinstance(t, dict):
        raise MalformedCityJSONError(
            f"{path}: 'transform' is {json.dumps(t)[:40]}, expected an object with 'scale' and 'translate'"
        )
    try:
        scale = np.asarray(t["scale"], dtype=np.float64).reshape(3)
        translate = np.asarray(t["translate"], dtype=np.float64).reshape(3)
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise MalformedCityJSONError(
            f"{path}: 'transform' needs 'scale' and 'translate' of 3 numbers"
        ) from exc
    if not (np.isfinite(scale).all() and (scale > 0).all() and (scale <= MAX_SCALE).all()):
        raise MalformedCityJSONError(
            f"{path}: 'transform' 'scale' {scale.tolist()} must be 3 numbers in (0, {MAX_SCALE:g}] "
            "(a zero or negative scale flattens or mirrors the model; a larger one is not a city's)"
        )
    if not usable_points(translate).all():
        raise MalformedCityJSONError(
            f"{path}: 'transform' 'translate' {translate.tolist()} must be finite and within "
            f"{MAX_ABS_COORDINATE_M:g} m"
        )
    return scale, translate


def _source_crs_name(doc: dict) -> str | None:
    meta = doc.get("metadata")
    if not isinstance(meta, dict):
        return None
    ref = meta.get("referenceSystem")
    if isinstance(ref, str) and ref.strip():
        return ref
    if isinstance(ref, int) and not isinstance(ref, bool) and ref > 0:  # a bare EPSG code, as 0.x wrote it
        return f"EPSG:{ref}"
    crs = meta.get("crs")  # CityJSON 0.6 - 0.9: {"epsg": 7415}
    if isinstance(crs, dict) and isinstance(crs.get("epsg"), int | str):
        return f"EPSG:{crs['epsg']}"
    return None


# ---------------------------------------------------------------------------------------------- LoD


def lod_key(value: Any) -> str | None:
    """Normalised LoD string: 2 -> "2", 2.0 -> "2", 2.2 -> "2.2", "1.3" -> "1.3"; None if not a LoD
    (CityGML LoDs are 0 to 4, with an optional decimal refinement)."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        text = str(value)
    elif isinstance(value, float):
        text = f"{value:.6g}" if np.isfinite(value) else ""
    elif isinstance(value, str):
        text = value.strip()
    else:
        return None
    match = re.fullmatch(r"([0-4])(?:\.(\d{1,3}))?", text)
    if match is None:
        return None
    whole, decimal = match.groups()
    decimal = (decimal or "").rstrip("0")
    return f"{whole}.{decimal}" if decimal else whole


def _lod_order(key: str) -> tuple[int, ...]:
    return tuple(int(p) for p in key.split("."))


def _lod_int(key: str) -> int:
    return int(key.split(".")[0])


# ---------------------------------------------------------------------------------------------- reader


@dataclass
class _Candidate:
    """One geometry of a city object, ready to mesh."""

    lod: str
    geometry: dict
    vertices: np.ndarray  # the world-coordinate vertex array its boundaries index
    has_semantics: bool
    n_surfaces: int


@dataclass
class _Counts:
    skipped_types: Counter = field(default_factory=Counter)
    extension_types: Counter = field(default_factory=Counter)
    skipped_geometry_types: Counter = field(default_factory=Counter)
    invalid_polygons: int = 0  # bad vertex index / ring structure
    malformed_geometries: int = 0
    malformed_objects: int = 0
    missing_lod: int = 0
    redundant_geometries: int = 0
    unknown_surface_types: Counter = field(default_factory=Counter)
    bad_semantic_values: int = 0
    broken_instances: int = 0
    objects_without_lod: int = 0  # building objects with geometry, none at the requested LoD


class _CityJSONReader:
    def __init__(self, doc: dict, path: Path, version: str, lod: str | int | float | None, notes: list[str]):
        self.doc = doc
        self.path = path
        self.version = version
        self.lod_request = lod
        self.counts = _Counts()
        self.stats = ParseStats()
        self.stats.warnings.extend(notes)
        self.objects: dict = doc["CityObjects"]

    # ------------------------------------------------------------------ coordinates
    def _frame(self, raw: np.ndarray, target_crs, crs_override) -> MetricFrame:
        stated = _source_crs_name(self.doc)
        name = crs_override or stated
        if crs_override and stated and (said := overridden_warning(crs_override, stated)) is not None:
            self.stats.warnings.append(said)
        source = parse_crs_name(name) if name else None
        target = parse_crs_name(target_crs) if isinstance(target_crs, str) else target_crs
        if source is None:
            self.stats.warnings.append(
                f"{self.path.name}: no referenceSystem in the file: coordinates used as they are, crs=None"
            )
            if target is not None:
                raise CRSError(
                    f"{self.path}: target_crs given but the file names no CRS to convert from; {CRS_HINT}"
                )
        finite = usable_points(raw)
        sample = raw[finite, :2] if finite.any() else None
        check_degrees(
            source, sample, str(self.path), named_by(crs_override, name, "the file's referenceSystem")
        )
        return MetricFrame.for_source(source, sample, target)

    def _templates(self) -> tuple[list, np.ndarray]:
        """Template geometries and their (untransformed, local) vertices."""
        gt = self.doc.get("geometry-templates")
        if not isinstance(gt, dict):
            return [], np.zeros((0, 3))
        templates = gt.get("templates") if isinstance(gt.get("templates"), list) else []
        try:
            tverts = _vertex_array(gt.get("vertices-templates", []), "vertices-templates", self.path)
        except MalformedCityJSONError:
            self.counts.broken_instances += 1
            return [], np.zeros((0, 3))
        return templates, tverts

    # ------------------------------------------------------------------ objects
    def _root_building(self, key: str) -> str:
        """The id of the Building a part/installation belongs to (itself for a Building or an orphan)."""
        seen = {key}
        current = key
        while True:
            obj = self.objects.get(current)
            if not isinstance(obj, dict) or obj.get("type") == "Building":
                return current
            parents = obj.get("parents", obj.get("parent"))
            if isinstance(parents, str):
                parents = [parents]
            if not isinstance(parents, list) or not parents:
                return current
            parent = parents[0]
            parent_obj = self.objects.get(parent) if isinstance(parent, str) else None
            if (
                not isinstance(parent_obj, dict)
                or _type_of(parent_obj) not in BUILDING_TYPES
                or parent in seen
            ):
                return current
            seen.add(parent)
            current = parent

    def _candidates(self, obj: dict, verts, templates, tverts, frame, raw) -> list[_Candidate]:
        geoms = obj.get("geometry", [])
        if not isinstance(geoms, list):
            self.counts.malformed_geometries += 1
            return []
        out = []
        for geom in geoms:
            if not isinstance(geom, dict):
                self.counts.malformed_geometries += 1
                continue
            gtype = _type_of(geom)
            if gtype == GEOMETRY_INSTANCE:
                cand = self._instance(geom, templates, tverts, frame, raw)
                if cand is not None:
                    out.append(cand)
                continue
            if gtype not in SURFACE_DEPTH:
                self.counts.skipped_geometry_types[str(gtype)] += 1
                continue
            key = lod_key(geom.get("lod"))
            if key is None:
                self.counts.missing_lod += 1
                key = "0"
            out.append(self._candidate(key, geom, verts))
        return out

    def _candidate(self, key: str, geom: dict, verts: np.ndarray) -> _Candidate:
        sem = geom.get("semantics")
        has_sem = isinstance(sem, dict) and isinstance(sem.get("surfaces"), list) and bool(sem.get("values"))
        boundaries = geom.get("boundaries")
        n = len(boundaries) if isinstance(boundaries, list) else 0
        return _Candidate(key, geom, verts, has_sem, n)

    def _instance(
        self, geom: dict, templates: list, tverts: np.ndarray, frame: MetricFrame, raw
    ) -> _Candidate | None:
        """A GeometryInstance as a candidate with its own world-coordinate vertices, or None (counted)."""
        try:
            t_index, r_index = int(geom["template"]), int(geom["boundaries"][0])
            if not (0 <= t_index < len(templates) and 0 <= r_index < len(raw)):
                raise IndexError("template or reference vertex out of range")
            template = templates[t_index]
            ref = raw[r_index]
            matrix = np.asarray(
                geom.get("transformationMatrix", np.eye(4).ravel()), dtype=np.float64
            ).reshape(4, 4)
        except (KeyError, IndexError, TypeError, ValueError, OverflowError):
            self.counts.broken_instances += 1
            return None
        if not isinstance(template, dict) or _type_of(template) not in SURFACE_DEPTH:
            self.counts.broken_instances += 1
            return None
        key = lod_key(template.get("lod"))
        if key is None:
            self.counts.missing_lod += 1
            key = "0"
        with np.errstate(over="ignore", invalid="ignore"):  # a corrupt matrix: its polygons are dropped
            moved = tverts @ matrix[:3, :3].T + matrix[:3, 3] + ref
        world = frame.to_metric(moved) if len(moved) else moved
        return self._candidate(key, template, world)

    def _select(self, cands: list[_Candidate]) -> list[_Candidate]:
        """The geometry to mesh for one object under the LoD request (empty if none matches)."""
        req = self.lod_request
        if req is None:
            pool = cands
        elif isinstance(req, int) and not isinstance(req, bool):
            pool = [c for c in cands if _lod_int(c.lod) == req]
        else:  # an exact LoD; something that is no LoD at all matches nothing (EmptyModelError later)
            want = lod_key(req)
            pool = [c for c in cands if want is not None and c.lod == want]
        if not pool:
            return []
        best = max(_lod_order(c.lod) for c in pool)
        same = [c for c in pool if _lod_order(c.lod) == best]
        if len(same) > 1:
            self.counts.redundant_geometries += len(same) - 1
            same.sort(key=lambda c: (c.has_semantics, c.n_surfaces), reverse=True)
        return same[:1]

    # ------------------------------------------------------------------ geometry
    def _surfaces(self, node: Any, values: Any, depth: int) -> Iterator[tuple[Any, Any]]:
        """(surface, semantic value) pairs of a boundary tree; broken levels are counted and skipped."""
        if not isinstance(node, list):
            self.counts.malformed_geometries += 1
            return
        for i, child in enumerate(node):
            value = values[i] if isinstance(values, list) and i < len(values) else None
            if depth == 0:
                yield child, value
            else:
                yield from self._surfaces(child, value, depth - 1)

    def _rings(self, surface: Any, verts: np.ndarray) -> list[np.ndarray] | None:
        """World-coordinate rings of one surface, or None when an index is invalid (unusable coordinates
        are the builder's to drop and count)."""
        if not isinstance(surface, list) or not surface:
            return None
        rings = []
        n = len(verts)
        for ring in surface:
            if not isinstance(ring, list) or not ring or any(v is True or v is False for v in ring):
                return None  # JSON true / false are no vertex index (numpy would read true as 1)
            try:
                idx = np.asarray(ring)
            except (TypeError, ValueError):
                return None
            if idx.ndim != 1 or idx.dtype.kind not in "iu":
                return None
            if idx.min() < 0 or idx.max() >= n:
                return None
            rings.append(verts[idx])
        return rings

    def _semantic(self, value: Any, surfaces: list) -> int | None:
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < len(surfaces):
            self.counts.bad_semantic_values += 1
            return None
        surface = surfaces[value]
        name = surface.get("type") if isinstance(surface, dict) else None
        cls = SURFACE_CLASS.get(name) if isinstance(name, str) else None
        if cls is None:
            self.counts.unknown_surface_types[str(name)] += 1
            return None
        return int(cls)

    def _mesh(self, builder: MeshBuilder, cand: _Candidate, building_id: str) -> None:
        geom = cand.geometry
        sem = geom.get("semantics") if cand.has_semantics else None
        surfaces = sem["surfaces"] if sem else []
        values = sem.get("values") if sem else None
        if sem and not isinstance(values, list):  # e.g. "abc": no surface gets a class from it
            self.counts.bad_semantic_values += 1
        lod = _lod_int(cand.lod)
        for surface, value in self._surfaces(geom.get("boundaries"), values, SURFACE_DEPTH[geom["type"]]):
            rings = self._rings(surface, cand.vertices)
            if rings is None:
                self.counts.invalid_polygons += 1
                self.stats.malformed_polygons += 1
                self.stats.polygons += 1
                continue
            builder.add_polygon(rings[0], rings[1:], self._semantic(value, surfaces), building_id, lod)

    # ------------------------------------------------------------------ driver
    def read(self, target_crs, crs_override, origin=None) -> CityModel:
        """The document's buildings meshed into a ``CityModel``; an empty result says which LoDs exist."""
        scale, translate = _transform(self.doc, self.path)
        raw = _vertex_array(self.doc["vertices"], "vertices", self.path) * scale + translate
        frame = self._frame(raw, target_crs, crs_override)
        verts = frame.to_metric(raw) if len(raw) else raw
        templates, tverts = self._templates()

        builder = MeshBuilder(self.stats)
        lods_present: set[str] = set()
        for key, obj in self.objects.items():
            if not isinstance(obj, dict):
                self.counts.malformed_objects += 1
                continue
            otype = _type_of(obj)
            if otype not in BUILDING_TYPES:
                if isinstance(otype, str) and otype.startswith("+"):
                    self.counts.extension_types[otype] += 1
                else:
                    self.counts.skipped_types[str(otype)] += 1
                continue
            cands = self._candidates(obj, verts, templates, tverts, frame, raw)
            lods_present.update(c.lod for c in cands)
            chosen = self._select(cands)
            if cands and not chosen:
                self.counts.objects_without_lod += 1
            building_id = self._root_building(key)
            for cand in chosen:
                self._mesh(builder, cand, building_id)

        self._warn()
        try:
            return builder.build(
                crs=frame.target, source_crs=frame.source, source=str(self.path), origin=origin
            )
        except EmptyModelError:
            present = ", ".join(sorted(lods_present, key=_lod_order)) or "none"
            if self.lod_request is not None and lods_present:
                raise LodNotHeldError(
                    f"{self.path}: no building geometry at LoD {self.lod_request!r}; LoDs present: {present}",
                    present=present,
                ) from None
            raise EmptyModelError(
                f"{self.path}: no building surfaces could be read (building LoDs present: {present}; "
                f"{'; '.join(self.stats.warnings) or 'no warnings'})"
            ) from None

    def _warn(self) -> None:
        c, w = self.counts, self.stats.warnings

        def listing(counter: Counter) -> str:
            return ", ".join(f"{k} {v}" for k, v in counter.most_common())

        if c.skipped_types:
            n = sum(c.skipped_types.values())
            w.append(f"skipped {n} non-building city objects: {listing(c.skipped_types)}")
        if c.extension_types:
            n = sum(c.extension_types.values())
            w.append(f"ignored {n} extension city objects: {listing(c.extension_types)}")
        if c.skipped_geometry_types:
            w.append(
                f"skipped {sum(c.skipped_geometry_types.values())} building geometries of types without "
                f"surfaces: {listing(c.skipped_geometry_types)}"
            )
        if c.invalid_polygons:
            w.append(f"skipped {c.invalid_polygons} polygons with invalid vertex indices or ring structure")
        if c.malformed_geometries or c.malformed_objects:
            w.append(
                f"skipped {c.malformed_geometries} malformed geometry parts and {c.malformed_objects} "
                "malformed city objects"
            )
        if c.broken_instances:
            w.append(f"skipped {c.broken_instances} GeometryInstances with a missing or broken template")
        if c.missing_lod:
            w.append(f"{c.missing_lod} geometries had no valid 'lod': read as LoD 0")
        if c.redundant_geometries:
            w.append(f"ignored {c.redundant_geometries} redundant geometries of an object's selected LoD")
        if c.unknown_surface_types:
            w.append(
                f"{sum(c.unknown_surface_types.values())} surfaces of unknown semantic type classified by "
                f"normals: {listing(c.unknown_surface_types)}"
            )
        if c.bad_semantic_values:
            w.append(f"{c.bad_semantic_values} semantic values pointed to no surface: classified by normals")
        if c.objects_without_lod and self.lod_request is not None:
            w.append(f"{c.objects_without_lod} building objects have no geometry at LoD {self.lod_request!r}")

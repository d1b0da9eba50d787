"""What a CityGML / GML element is to the CityGML reader's geometry walk, from its namespace and name.

Why a module of its own: the reader's walk (``citymodel.citygml_walk``) meets every element of a city
object, and what it does with one (skip it, descend into it, read a polygon, start a BuildingPart, take a
boundary surface's class or a ``lodN`` property's LoD) depends only on the element's tag. ``classify`` gives
that as a ``(kind, argument)`` pair (the walk caches it per tag); the tables below are the vocabulary it
decides by, for CityGML 1.0, 2.0 and 3.0 (3.0 renames some properties and the filling surfaces) and GML 3.1
/ 3.2. The qualified attribute names the reader looks up (``gml:id`` of either GML version, ``xlink:href``)
are here too, and ``citygml_version``: which CityGML a root element is, and so which ``gml:id`` its objects
carry.
"""

from __future__ import annotations

import re
from pathlib import Path

from semcityloc.classes import SURFACE_CLASS, SemanticClass
from semcityloc.errors import UnsupportedFormatError

GML_ID_31 = "{http://www.opengis.net/gml}id"
GML_ID_32 = "{http://www.opengis.net/gml/3.2}id"
XLINK_HREF = "{http://www.w3.org/1999/xlink}href"
# The CityGML core namespace (no module) or a module's (building, appearance...), with the version.
CITYGML_NS = re.compile(r"^http://www\.opengis\.net/citygml/(?:([A-Za-z]+)/)?(\d+)\.(\d+)$")
SUPPORTED_MAJOR_VERSIONS = (1, 2, 3)
_LOD_PROPERTY = re.compile(r"^lod([0-4])([A-Za-z]*)$")

# CityGML 3.0 names the filling surfaces of openings this way; 1.0/2.0 have Window / Door (in SURFACE_CLASS).
_EXTRA_SURFACE_CLASS = {"WindowSurface": SemanticClass.WINDOW, "DoorSurface": SemanticClass.DOOR}
OPENING_NAMES = frozenset({"Window", "Door", "WindowSurface", "DoorSurface"})
# CityGML subtrees that hold nothing visible from outside (or nothing geometric) and are skipped whole.
_SKIP_CITYGML = frozenset(
    {
        "interiorRoom",
        "Room",
        "interiorFurniture",
        "BuildingFurniture",
        "buildingFurniture",
        "interiorBuildingInstallation",
        "IntBuildingInstallation",
        "buildingRoom",
        "BuildingRoom",
        "buildingSubdivision",
        "Storey",
        "BuildingUnit",
        "address",
        "Address",
        "externalReference",
        "generalizesTo",
        "appearance",
        "dynamizer",
        "relatedTo",
    }
)
_SKIP_CITYGML_MODULES = frozenset({"appearance", "generics", "dynamizer", "versioning", "pointcloud"})
_SKIP_GML = frozenset(
    {
        "name",
        "description",
        "identifier",
        "metaDataProperty",
        "descriptionReference",
        "LineString",
        "MultiCurve",
        "CompositeCurve",
        "Curve",
        "OrientableCurve",
        "Point",
        "MultiPoint",
    }
)
# A polygon-like surface: rings directly below it.
_POLYGON_NAMES = frozenset({"Polygon", "PolygonPatch", "Triangle", "Rectangle"})
_LOD_SKIP_SUFFIXES = ("Curve", "TerrainIntersection", "Point")
# Feature properties (outside any lodN property) whose xlink:href may point at a surface-bearing feature.
HREF_FEATURE_PROPERTIES = frozenset(
    {
        "boundedBy",
        "boundary",
        "opening",
        "fillingSurface",
        "filling",
        "consistsOfBuildingPart",
        "buildingPart",
        "outerBuildingInstallation",
        "buildingInstallation",
    }
)

# Element kinds of the geometry walk.
K_SKIP, K_DESCEND, K_GML_CONTAINER, K_PART, K_SEMANTIC, K_LOD = range(6)
K_LOD_SKIP, K_IMPLICIT, K_POLYGON, K_ORIENTABLE, K_SOLID, K_ENVELOPE_PROP = range(6, 12)


def local_name(tag: str) -> str:
    """``{namespace}name`` -> ``name``."""
    return tag[tag.rfind("}") + 1 :]


def tag_namespace(tag: str) -> str:
    """``{namespace}name`` -> ``namespace`` (empty without one)."""
    return tag[1 : tag.find("}")] if tag.startswith("{") else ""


def citygml_version(path: Path, tag: str) -> tuple[str, str]:
    """The CityGML version (``"2.0"``) of the root element ``tag`` of the file ``path`` and the ``gml:id``
    attribute its objects carry (GML 3.1 in CityGML 1.x / 2.x, GML 3.2 in 3.x); ``UnsupportedFormatError``
    for any root but a CityModel of CityGML 1 to 3, saying what it is."""
    ns, local = tag_namespace(tag), local_name(tag)
    m = CITYGML_NS.match(ns)
    if local == "CityModel" and m is not None and m.group(1) is None:
        major, minor = int(m.group(2)), int(m.group(3))
        if major not in SUPPORTED_MAJOR_VERSIONS:
            raise UnsupportedFormatError(
                f"{path}: CityGML {major}.{minor} (root <{local}> in {ns}) is not supported; "
                "this reader knows CityGML 1.x, 2.x and 3.x"
            )
        return f"{major}.{minor}", (GML_ID_32 if major >= 3 else GML_ID_31)
    if local == "CityModel" or m is not None:
        raise UnsupportedFormatError(
            f"{path}: root <{local}> in namespace {ns or '(none)'!r} is not a known CityGML "
            "version's CityModel (expected http://www.opengis.net/citygml/1.0, 2.0 or 3.0)"
        )
    raise UnsupportedFormatError(
        f"{path}: root element <{local}> (namespace {ns or '(none)'!r}) is not a CityGML CityModel"
    )


def classify(tag: str) -> tuple[int, int]:
    """(kind, argument) of an element in a city object, from its namespace family and local name."""
    ns, local = tag_namespace(tag), local_name(tag)
    if ns.startswith("http://www.opengis.net/gml"):
        if local in _POLYGON_NAMES:
            return K_POLYGON, 0
        if local == "OrientableSurface":
            return K_ORIENTABLE, 0
        if local == "Solid":
            return K_SOLID, 0
        if local == "boundedBy":
            return K_ENVELOPE_PROP, 0
        if local in _SKIP_GML:
            return K_SKIP, 0
        return K_GML_CONTAINER, 0
    m = CITYGML_NS.match(ns)
    if m is None:
        # xAL addresses and other non-geometry vocabularies are skipped; ADE content is walked (but its
        # geometry only counts inside a CityGML lodN property).
        return (K_SKIP, 0) if ns.startswith("urn:oasis:names:tc:ciq") else (K_DESCEND, 0)
    if m.group(1) in _SKIP_CITYGML_MODULES or local in _SKIP_CITYGML:
        return K_SKIP, 0
    if local == "BuildingPart":
        return K_PART, 0
    cls = SURFACE_CLASS.get(local, _EXTRA_SURFACE_CLASS.get(local))
    if cls is not None:
        return K_SEMANTIC, int(cls)
    lod = _LOD_PROPERTY.match(local)
    if lod:
        suffix = lod.group(2)
        if "Implicit" in suffix:
            return K_IMPLICIT, 0
        if suffix.endswith(_LOD_SKIP_SUFFIXES):
            return K_LOD_SKIP, 0
        return K_LOD, int(lod.group(1))
    return K_DESCEND, 0

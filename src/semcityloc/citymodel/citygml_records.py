"""What the CityGML reader's stages hand each other: a surface read, an XLink waiting, and the counts kept.

Why a module of its own: the reader (``citymodel.citygml``) is a pipeline of small stages (the walk of one
city object, ``citygml_walk``; XLink resolution across objects, ``citygml_xlinks``; the LoD kept per
building and part, ``citygml_lod_choice``), and each of them reads or writes these records and counts into
one ``CityGMLReport``. Defined here, below all of them, no stage imports another to learn their shape.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np


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


class SurfaceRecord(NamedTuple):
    """A polygon while its city object is read: file coordinates, before LoD selection and CRS conversion."""

    part: int  # 0 = the building itself, 1.. = its BuildingParts
    lod: int
    semantic: int | None  # SemanticClass id, or None = classify by normals
    exterior: np.ndarray  # (n, 3) float64
    interiors: list[np.ndarray]
    gml_id: str | None  # of the polygon or of the surface that holds it (what an XLink may name)
    via_xlink: bool  # reached through an XLink, not defined here


class SurfaceRef(NamedTuple):
    """An ``xlink:href`` met in the walk: the surfaces with gml:id ``target`` belong here, with what the
    referring element says about them (``None``: what the target itself says)."""

    target: str
    part: int
    lod: int | None
    semantic: int | None
    flip: bool  # inside an OrientableSurface with orientation="-": the rings reversed

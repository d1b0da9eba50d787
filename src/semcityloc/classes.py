"""Semantic classes shared by the city model, the renderer and the perception side.

The ids are fixed and part of the file formats we write (label PNGs, npz caches): never renumber them.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np


class SemanticClass(IntEnum):
    """The semantic classes of the whole pipeline, as fixed integer ids.

    One enumeration for the city model's triangles, the rendered masks, the query masks and the perception
    heads, so that a class means the same everywhere. The ids are written into files (label PNGs, npz caches,
    trained heads), so they are never renumbered; ``IGNORE`` (255) is deliberately not a member: it is "no
    label", not a class.
    """

    BACKGROUND = 0  # sky, vegetation, anything the model does not describe
    GROUND = 1
    WALL = 2
    ROOF = 3
    WINDOW = 4
    DOOR = 5


NUM_CLASSES = len(SemanticClass)
CLASS_NAMES: tuple[str, ...] = tuple(c.name.lower() for c in SemanticClass)

# Label id of a pixel that carries no class (label PNGs, query masks, training targets): "don't know",
# skipped by every score and loss. A plain int so numba kernels can use it as a global. The largest uint8:
# ``_has_invalid_ids`` relies on it.
IGNORE = 255

# The classes that are part of a building (everything the model describes except the ground).
BUILDING_CLASSES: tuple[SemanticClass, ...] = (
    SemanticClass.WALL,
    SemanticClass.ROOF,
    SemanticClass.WINDOW,
    SemanticClass.DOOR,
)

# Palette for label PNGs (index = class id). Documented in docs/conventions.md.
PALETTE = np.array(
    [
        [0, 0, 0],  # background
        [128, 128, 128],  # ground
        [230, 190, 60],  # wall
        [200, 40, 40],  # roof
        [60, 140, 230],  # window
        [60, 200, 90],  # door
    ],
    dtype=np.uint8,
)

# CityGML / CityJSON surface names -> class. Surfaces that are not one of the five are mapped to their
# nearest visible class: ClosureSurface closes open volumes (usually vertical, seen like a wall),
# OuterCeilingSurface faces downward under overhangs (wall-coloured underside), OuterFloorSurface is a
# walkable floor open to the sky (balcony/terrace: seen from above like a roof).
# BuildingInstallation (dormers, chimneys, balconies) keeps the class of its own boundary surfaces and
# falls back to normal classification.
SURFACE_CLASS: dict[str, SemanticClass] = {
    "GroundSurface": SemanticClass.GROUND,
    "WallSurface": SemanticClass.WALL,
    "RoofSurface": SemanticClass.ROOF,
    "Window": SemanticClass.WINDOW,
    "Door": SemanticClass.DOOR,
    "WindowSurface": SemanticClass.WINDOW,  # CityGML 3.0 boundary names of openings
    "DoorSurface": SemanticClass.DOOR,
    "ClosureSurface": SemanticClass.WALL,
    "OuterCeilingSurface": SemanticClass.WALL,
    "OuterFloorSurface": SemanticClass.ROOF,
    "InteriorWallSurface": SemanticClass.WALL,
    "CeilingSurface": SemanticClass.WALL,
    "FloorSurface": SemanticClass.GROUND,
    # CityJSON 2.0 names the same things with these strings.
    "TrafficArea": SemanticClass.GROUND,
    "AuxiliaryTrafficArea": SemanticClass.GROUND,
}


def _has_invalid_ids(labels: np.ndarray) -> bool:
    """Whether any id of ``labels`` is neither a class nor ``IGNORE`` (``invalid_class_ids``' rule). A uint8
    mask (every mask file, every mask the perception makes) is checked in one pass, 5x faster on 12 MP:
    adding 1 wraps ``IGNORE`` (255) to 0 and moves the classes to 1..NUM_CLASSES, so any other id ends
    above NUM_CLASSES. Other dtypes (a ``.npy`` of int64, floats) by the rule itself."""
    if labels.dtype == np.uint8:
        return labels.size > 0 and int((labels + np.uint8(1)).max()) > NUM_CLASSES
    return bool(((labels != IGNORE) & ((labels < 0) | (labels >= NUM_CLASSES))).any())


def invalid_class_ids(labels: np.ndarray) -> str | None:
    """What is wrong with a label map's ids, or None: every id must be a class (0..5) or ``IGNORE``.
    One rule for mask files (``io.images.read_mask_file``) and arrays handed to the localizer: another id
    (a segmentation head's own numbering, say) would otherwise count as nothing, silently."""
    labels = np.asarray(labels)
    if not _has_invalid_ids(labels):
        return None
    bad = (labels != IGNORE) & ((labels < 0) | (labels >= NUM_CLASSES))
    ids = np.unique(labels[bad])
    shown = ", ".join(str(int(i)) for i in ids[:12]) + (", ..." if len(ids) > 12 else "")
    return (
        f"invalid class ids {shown} in {int(bad.sum())} pixels; class ids must be "
        f"0..{NUM_CLASSES - 1} ({', '.join(CLASS_NAMES)}) or {IGNORE} (ignore; semcityloc.classes)"
    )

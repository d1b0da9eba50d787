"""The one in-memory form of a city model: a semantic triangle mesh in a local metric frame.

World coordinates (metres, in ``crs``) are ``origin + local``. ``origin`` is float64; the vertices are
float32 *after* the origin was subtracted in float64, so a UTM northing of 5.8e6 m never meets float32.
"""

from __future__ import annotations

import dataclasses
import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyproj

from semcityloc.classes import CLASS_NAMES, NUM_CLASSES
from semcityloc.errors import ArgumentTypeError, EmptyModelError, InputFileError, ShapeError
from semcityloc.geometry.pose import Pose, float64_coordinates
from semcityloc.io.files import removed_on_error


@dataclass
class ParseStats:
    """What a reader met and skipped. Readers never crash on one bad polygon; they count it here."""

    polygons: int = 0
    degenerate_polygons: int = 0  # fewer than 3 distinct points, zero area: skipped
    nonplanar_polygons: int = 0  # off their best-fit plane by more than the tolerance: still meshed
    failed_triangulations: int = 0  # earcut gave nothing for a non-degenerate polygon: skipped
    invalid_coordinate_polygons: int = 0  # NaN, infinite or absurd coordinates (``builder.usable_points``)
    malformed_polygons: int = 0  # no exterior ring, a token that is no number, bad vertex indices: skipped
    polygons_2d: int = 0  # no heights (CityGML ``srsDimension="2"``): skipped
    polygons_without_lod: int = 0  # CityGML geometry outside any lodN property (ADE content): skipped
    unresolved_xlinks: int = 0
    classified_by_normal: int = 0  # polygons that had no semantics and were classified from normals
    warnings: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        """The counts and warnings as a plain dict (an npz file's metadata, a tile store's totals)."""
        return {k: v for k, v in self.__dict__.items()}


@dataclass
class CityModel:
    """Semantic triangle mesh of a city district.

    Attributes:
        origin: float64 (3,), world coordinates (in ``crs``) of the local frame's origin.
        vertices: float32 (V, 3), local coordinates: ``world = origin + vertices``. x east, y north, z up
            for projected CRSs (see docs/conventions.md).
        triangles: int32 (T, 3) vertex indices, counter-clockwise seen from outside where the source
            orientation is right.
        classes: uint8 (T,), ``SemanticClass`` id per triangle.
        building_index: int32 (T,), index into ``building_ids`` (building parts map to their building).
        lods: uint8 (T,), LoD the triangle was read from.
        building_ids: the source ids (gml:id / CityJSON key) of the buildings.
        crs: the metric CRS the world coordinates are in, or None when the source named none.
        source_crs: the CRS the file was written in (differs from ``crs`` when a geographic source was
            projected to UTM).
        stats: what the reader skipped or guessed.
    """

    origin: np.ndarray
    vertices: np.ndarray
    triangles: np.ndarray
    classes: np.ndarray
    building_index: np.ndarray
    lods: np.ndarray
    building_ids: list[str]
    crs: pyproj.CRS | None = None
    source_crs: pyproj.CRS | None = None
    source: str = ""
    stats: ParseStats = field(default_factory=ParseStats)

    def __post_init__(self) -> None:
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(3)
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float32).reshape(-1, 3)
        self.triangles = np.ascontiguousarray(self.triangles, dtype=np.int32).reshape(-1, 3)
        t = len(self.triangles)
        self.classes = np.ascontiguousarray(self.classes, dtype=np.uint8).reshape(-1)
        self.building_index = np.ascontiguousarray(self.building_index, dtype=np.int32).reshape(-1)
        self.lods = np.ascontiguousarray(self.lods, dtype=np.uint8).reshape(-1)
        for name in ("classes", "building_index", "lods"):
            if len(getattr(self, name)) != t:
                raise ShapeError(f"CityModel.{name} has {len(getattr(self, name))} entries for {t} triangles")
        if t and (self.triangles.min() < 0 or self.triangles.max() >= len(self.vertices)):
            raise ShapeError("CityModel.triangles index vertices that do not exist")
        if t and self.classes.max() >= NUM_CLASSES:
            raise ShapeError(f"CityModel.classes holds ids >= {NUM_CLASSES}")

    # ------------------------------------------------------------------ geometry
    @property
    def num_triangles(self) -> int:
        """How many triangles the mesh has."""
        return int(len(self.triangles))

    @property
    def num_buildings(self) -> int:
        """How many distinct buildings the triangles belong to (0 for an empty model)."""
        return len(np.unique(self.building_index)) if self.num_triangles else 0

    @property
    def bounds_local(self) -> np.ndarray:
        """(2, 3) float64 min/max corner of the used vertices in the local frame."""
        if not self.num_triangles:
            raise EmptyModelError("the city model has no triangles")
        used = self.vertices[np.unique(self.triangles)]
        return np.stack([used.min(0), used.max(0)]).astype(np.float64)

    @property
    def extent_m(self) -> np.ndarray:
        """(3,) size of the bounding box in metres (dx, dy, dz)."""
        b = self.bounds_local
        return b[1] - b[0]

    def triangle_corners(self) -> np.ndarray:
        """(T, 3, 3) float64 corners of every triangle in the local frame."""
        return self.vertices[self.triangles].astype(np.float64)

    def triangle_normals(self) -> np.ndarray:
        """(T, 3) unnormalised normals (cross product; length = 2 * area)."""
        c = self.triangle_corners()
        return np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])

    def triangle_areas(self) -> np.ndarray:
        """Each triangle's area in square metres (half its normal's length)."""
        return 0.5 * np.linalg.norm(self.triangle_normals(), axis=1)

    def class_triangle_counts(self) -> dict[str, int]:
        """Triangles per semantic class, by class name (every class listed, zeros included): ``city info``'s
        table.
        """
        counts = np.bincount(self.classes, minlength=NUM_CLASSES)
        return {CLASS_NAMES[i]: int(counts[i]) for i in range(NUM_CLASSES)}

    def class_areas(self) -> dict[str, float]:
        """Surface area per semantic class in square metres, by class name: how much wall, roof and opening
        the model really has, which triangle counts do not tell.
        """
        areas = np.bincount(self.classes, weights=self.triangle_areas(), minlength=NUM_CLASSES)
        return {CLASS_NAMES[i]: float(areas[i]) for i in range(NUM_CLASSES)}

    def lods_present(self) -> list[int]:
        """The levels of detail the triangles come from, sorted (a file may mix them)."""
        return sorted(int(v) for v in np.unique(self.lods))

    def to_world(self, local: np.ndarray) -> np.ndarray:
        """Local (..., 3) -> world coordinates, float64."""
        return np.asarray(local, dtype=np.float64) + self.origin

    def to_local(self, world: np.ndarray) -> np.ndarray:
        """World (..., 3) float64 -> local coordinates, float64 (cast to float32 only after this; world
        coordinates that come in float32 have lost their centimetres already: ``PoseError``)."""
        return float64_coordinates(world, "world coordinates") - self.origin

    def with_origin(self, origin: np.ndarray) -> CityModel:
        """This model re-expressed with the local frame's origin at ``origin`` (float64 world coordinates).

        World coordinates do not change: the vertices are shifted by ``self.origin - origin`` in float64,
        then cast to float32. Returns ``self`` when ``origin`` equals ``self.origin``.
        """
        origin = np.asarray(origin, dtype=np.float64)
        if np.array_equal(self.origin, origin):
            return self
        shifted = self.vertices.astype(np.float64) + (self.origin - origin)
        return dataclasses.replace(self, origin=origin.copy(), vertices=shifted.astype(np.float32))

    def pose_to_local(self, pose_world: Pose) -> Pose:
        """A cam_from_world pose in world (CRS) coordinates -> the same camera in this model's local frame."""
        return _pose(pose_world, "pose_world").shift_world(self.origin)

    def pose_to_world(self, pose_local: Pose) -> Pose:
        """A cam_from_world pose in this model's local frame -> the same camera in world (CRS) coordinates."""
        return _pose(pose_local, "pose_local").shift_world(-self.origin)

    def select(self, triangle_mask: np.ndarray) -> CityModel:
        """A new model with only the triangles where ``triangle_mask`` is true (vertices compacted)."""
        keep = np.asarray(triangle_mask, dtype=bool)
        tris = self.triangles[keep]
        used, inverse = np.unique(tris, return_inverse=True)
        return CityModel(
            origin=self.origin.copy(),
            vertices=self.vertices[used],
            triangles=inverse.reshape(-1, 3),
            classes=self.classes[keep],
            building_index=self.building_index[keep],
            lods=self.lods[keep],
            building_ids=list(self.building_ids),
            crs=self.crs,
            source_crs=self.source_crs,
            source=self.source,
            stats=self.stats,
        )

    def summary(self) -> dict:
        """The facts ``semcityloc city info --json`` prints."""
        return {
            "source": self.source,
            "buildings": self.num_buildings,
            "triangles": self.num_triangles,
            "class_triangles": self.class_triangle_counts(),
            "class_area_m2": {k: round(v, 3) for k, v in self.class_areas().items()},
            "crs": crs_label(self.crs),
            "source_crs": crs_label(self.source_crs),
            "lods": self.lods_present(),
            "extent_m": [round(float(v), 3) for v in self.extent_m] if self.num_triangles else [0, 0, 0],
            "origin": [float(v) for v in self.origin],
            # the world (CRS) bounding box, [[x, y, z] min, [x, y, z] max]: where the model lies, its z range
            "bounds_world": (
                [[round(float(v), 3) for v in corner] for corner in self.to_world(self.bounds_local)]
                if self.num_triangles
                else None
            ),
            "skipped": {
                "degenerate_polygons": self.stats.degenerate_polygons,
                "failed_triangulations": self.stats.failed_triangulations,
                "invalid_coordinate_polygons": self.stats.invalid_coordinate_polygons,
                "malformed_polygons": self.stats.malformed_polygons,
                "polygons_2d": self.stats.polygons_2d,
                "polygons_without_lod": self.stats.polygons_without_lod,
                "unresolved_xlinks": self.stats.unresolved_xlinks,
            },
            "nonplanar_polygons": self.stats.nonplanar_polygons,
            "classified_by_normal": self.stats.classified_by_normal,
            "warnings": list(self.stats.warnings),  # what the reader skipped or guessed, in its words
        }

    # ------------------------------------------------------------------ npz round trip
    def save_npz(self, path: str | Path) -> Path:
        """Write the model as our ``.npz`` (arrays plus JSON metadata, no pickled objects): the parse cache's
        format and ``city convert``'s; ``load_npz`` reads it back unchanged.
        """
        path = Path(path)
        meta = {
            "building_ids": self.building_ids,
            "crs": self.crs.to_wkt() if self.crs is not None else None,
            "source_crs": self.source_crs.to_wkt() if self.source_crs is not None else None,
            "source": self.source,
            "stats": self.stats.as_dict(),
        }
        tmp = path.with_name(path.name + ".tmp.npz")
        with removed_on_error(tmp):  # a full disk leaves no half-written temporary file either
            np.savez(
                tmp,
                origin=self.origin,
                vertices=self.vertices,
                triangles=self.triangles,
                classes=self.classes,
                building_index=self.building_index,
                lods=self.lods,
                meta=np.frombuffer(json.dumps(meta).encode("utf-8"), dtype=np.uint8),
            )
            tmp.replace(path)
        return path

    @classmethod
    def load_npz(cls, path: str | Path) -> CityModel:
        """A model written by ``save_npz``; a damaged or foreign file is an ``InputFileError``, and pickled
        content is never loaded (``allow_pickle=False``).
        """
        try:
            with np.load(path, allow_pickle=False) as z:
                meta = json.loads(bytes(z["meta"]).decode("utf-8"))
                arrays = {
                    k: z[k] for k in ("origin", "vertices", "triangles", "classes", "building_index", "lods")
                }
        except FileNotFoundError as exc:
            raise InputFileError(f"{path}: no such file") from exc
        except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile) as exc:  # empty, cut short
            why = _npz_fault(path, exc)
            raise InputFileError(
                f"{path}: not a semcityloc city-model npz (damaged, or another program's: {why})"
            ) from exc
        return cls(
            **arrays,
            building_ids=list(meta["building_ids"]),
            crs=pyproj.CRS.from_wkt(meta["crs"]) if meta.get("crs") else None,
            source_crs=pyproj.CRS.from_wkt(meta["source_crs"]) if meta.get("source_crs") else None,
            source=meta.get("source", ""),
            stats=ParseStats(**meta.get("stats", {})),
        )


def _npz_fault(path: str | Path, exc: Exception) -> str:
    """What is wrong with a file ``CityModel.load_npz`` could not read, in a user's words: numpy tries any
    file that is no ZIP (npz) or npy as a pickle, and says so, also for a text file."""
    try:
        with open(path, "rb") as f:
            head = f.read(6)
    except OSError as err:
        return str(err)
    if not head:
        return "the file is empty"
    if "pickle" not in str(exc):
        return str(exc)
    if head.startswith((b"PK", b"\x93NUMPY", b"\x80")):  # an npz or npy of objects, or a pickle itself
        return "it holds pickled objects"
    return "it is no npz (ZIP) file: text or another kind of file"


def _pose(pose, what: str) -> Pose:
    """``pose`` if it is a ``Pose``; a 4x4 matrix or a position list is refused naming the constructors."""
    if not isinstance(pose, Pose):
        raise ArgumentTypeError(
            f"{what} must be a semcityloc Pose (Pose.from_world_from_cam(T), Pose.from_xyz_rpy(...)), got "
            f"{type(pose).__name__}"
        )
    return pose


def crs_label(crs: pyproj.CRS | None) -> str | None:
    """Short human label for a CRS: ``EPSG:25833`` when it has one, a compound without one of its own as
    ``EPSG:31468+5783`` (a form ``parse_crs_name`` reads back), else its name."""
    if crs is None:
        return None
    auth = crs.to_authority(min_confidence=70)
    if auth:
        return f"{auth[0]}:{auth[1]}"
    parts = [sub.to_authority(min_confidence=70) for sub in crs.sub_crs_list] if crs.is_compound else []
    if len(parts) == 2 and all(p is not None and p[0] == "EPSG" for p in parts):
        return f"EPSG:{parts[0][1]}+{parts[1][1]}"
    return crs.name

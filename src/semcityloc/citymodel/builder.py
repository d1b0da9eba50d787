"""Collect semantic polygons from any reader and turn them into one ``CityModel``.

Readers call ``MeshBuilder.add_polygon`` with rings in world coordinates (float64, metric CRS) and a
class id, or ``None`` when the source has no semantics; ``build()`` triangulates, classifies the
unlabelled triangles from their normals (``classify_by_normals``), picks the float64 origin, subtracts it
in float64 and only then casts the vertices to float32.

Coordinates that are NaN, infinite or farther than ``MAX_ABS_COORDINATE_M`` from the CRS origin
(``usable_points``) are corrupt: readers drop such polygons where they parse them, and ``add_polygon`` drops
any that still arrive (a projection that failed), so none reaches the triangulation or the origin. Each is
counted in ``stats.invalid_coordinate_polygons``; ``build()`` says so in one warning
(``invalid_coordinates_note``).
"""

from __future__ import annotations

import numpy as np
import pyproj

from semcityloc.citymodel.model import CityModel, ParseStats
from semcityloc.citymodel.triangulate import NONPLANAR_TOLERANCE_M, triangulate_polygon
from semcityloc.classes import SemanticClass
from semcityloc.errors import EmptyModelError, InputFileError, ParameterError, parameter

# Builder-internal sentinel "the source gave no class": ``build()`` replaces every such triangle with a class
# from its normal (``classify_by_normals``), so it never reaches a CityModel. Not ``classes.IGNORE`` (a
# label-map value), though both happen to be 255.
UNLABELLED = 255

# A face whose unit normal has |n_z| below this is a wall: it is within ~10 degrees of vertical.
WALL_MAX_ABS_NZ = 0.17
# A downward-facing face within this height of its building's lowest point is ground (the footprint).
GROUND_HEIGHT_TOLERANCE_M = 0.5
# Local-frame z stays absolute (origin z = 0) while the model's heights lie within this range.
ABSOLUTE_Z_LIMIT_M = 10_000.0
# A coordinate farther than this from the CRS origin (metres) is corrupt: ECEF radii are ~6.4e6 m, and it
# would not survive the float32 local frame.
MAX_ABS_COORDINATE_M = 1e9
# Local coordinates (metres from the origin) must stay within this for float32 to keep them to 4 mm (the
# spacing of float32 numbers is 7.8 mm from 2^16 m on): 131 km across, a whole federal state's LoD2 tile
# set at most. Farther means a building in another place or unit (``check_local_extent``).
MAX_LOCAL_EXTENT_M = 65_536.0


def usable_points(points: np.ndarray) -> np.ndarray:
    """Bool per point of an (n, k) array: every coordinate finite and within ``MAX_ABS_COORDINATE_M``."""
    return (np.abs(np.asarray(points, dtype=np.float64)) <= MAX_ABS_COORDINATE_M).all(axis=-1)


def usable_polygon(exterior: np.ndarray, interiors: list[np.ndarray] | tuple = ()) -> bool:
    """Whether every point of a polygon's rings is usable (``usable_points``)."""
    return all(usable_points(ring).all() for ring in (exterior, *interiors))


def invalid_coordinates_note(count: int) -> str:
    """The warning of ``count`` polygons dropped for their coordinates (the same for every reader)."""
    return (
        f"skipped {count} polygons with coordinates that are NaN, infinite or beyond "
        f"{MAX_ABS_COORDINATE_M:g} m"
    )


def classify_by_normals(normals: np.ndarray, min_z: np.ndarray, building_min_z: np.ndarray) -> np.ndarray:
    """Class per face from its normal (source orientation: outward) and its height in its building.

    - ``|n_z| < WALL_MAX_ABS_NZ`` (within ~10 deg of vertical) -> wall;
    - upward (``n_z > 0``) -> roof;
    - downward and within ``GROUND_HEIGHT_TOLERANCE_M`` of the building's lowest point -> ground;
    - downward elsewhere (the underside of an overhang) -> wall, like OuterCeilingSurface.
    """
    unit = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    nz = unit[:, 2]
    out = np.full(len(normals), SemanticClass.WALL, dtype=np.uint8)
    up = nz >= WALL_MAX_ABS_NZ
    down = nz <= -WALL_MAX_ABS_NZ
    out[up] = SemanticClass.ROOF
    out[down & (min_z <= building_min_z + GROUND_HEIGHT_TOLERANCE_M)] = SemanticClass.GROUND
    return out


class MeshBuilder:
    """Accumulates triangulated polygons; one per reader call."""

    def __init__(self, stats: ParseStats | None = None):
        self.stats = stats if stats is not None else ParseStats()
        self._points: list[np.ndarray] = []
        self._tris: list[np.ndarray] = []
        self._meta: list[tuple[int, int, int, int]] = []  # pending polygons: (n_tris, class, building, lod)
        self._attr_chunks: list[np.ndarray] = []  # (n, 3) per-triangle class, building, lod
        self._n_points = 0
        self._building_index: dict[str, int] = {}

    def building(self, building_id: str) -> int:
        """Index of a building id, registering it on first use."""
        idx = self._building_index.get(building_id)
        if idx is None:
            idx = self._building_index[building_id] = len(self._building_index)
        return idx

    @property
    def building_ids(self) -> list[str]:
        """The building ids in index order (``building`` registers them as polygons arrive)."""
        return list(self._building_index)

    def add_polygon(
        self,
        exterior: np.ndarray,
        interiors: list[np.ndarray] | tuple = (),
        semantic: int | None = None,
        building_id: str = "",
        lod: int = 0,
    ) -> bool:
        """Triangulate and keep one polygon (world coordinates). Returns False if it was skipped."""
        self.stats.polygons += 1
        if not usable_polygon(exterior, interiors):
            self.stats.invalid_coordinate_polygons += 1
            return False
        tri = triangulate_polygon(exterior, interiors)
        if tri is None:
            self.stats.degenerate_polygons += 1
            return False
        if tri.planarity_m > NONPLANAR_TOLERANCE_M:
            self.stats.nonplanar_polygons += 1
        if semantic is None:
            self.stats.classified_by_normal += 1
            semantic = UNLABELLED
        self._points.append(tri.points)
        self._tris.append(tri.triangles + self._n_points)
        self._n_points += len(tri.points)
        self._meta.append((len(tri.triangles), int(semantic), self.building(building_id), int(lod)))
        return True

    def add_mesh(
        self,
        points: np.ndarray,
        triangles: np.ndarray,
        semantic: np.ndarray,
        building: np.ndarray,
        lod: int,
    ) -> None:
        """Add an already triangulated mesh (OBJ): ``semantic`` per triangle, UNLABELLED where unknown."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        self._points.append(points)
        self._tris.append(triangles + self._n_points)
        self._n_points += len(points)
        self._flush()
        attrs = np.empty((len(triangles), 3), dtype=np.int64)
        attrs[:, 0] = np.asarray(semantic).reshape(-1)
        attrs[:, 1] = np.asarray(building).reshape(-1)
        attrs[:, 2] = lod
        self._attr_chunks.append(attrs)

    def _flush(self) -> None:
        """Expand the pending per-polygon attributes into per-triangle rows."""
        if self._meta:
            meta = np.array(self._meta, dtype=np.int64)
            self._attr_chunks.append(np.repeat(meta[:, 1:], meta[:, 0], axis=0))
            self._meta = []

    def build(
        self,
        crs: pyproj.CRS | None = None,
        source_crs: pyproj.CRS | None = None,
        source: str = "",
        origin: np.ndarray | None = None,
    ) -> CityModel:
        """The ``CityModel`` of every polygon added: local frame, normals classify unlabelled ones."""
        invalid = self.stats.invalid_coordinate_polygons
        if invalid:
            self.stats.warnings.append(invalid_coordinates_note(invalid))
        if not self._tris:
            why = f" ({invalid_coordinates_note(invalid)})" if invalid else ""
            raise EmptyModelError(f"{source or 'city model'}: no building surfaces could be read{why}")
        points = np.concatenate(self._points)
        tris = np.concatenate(self._tris)
        self._flush()
        attrs = np.concatenate(self._attr_chunks)
        classes, building, lods = attrs[:, 0].copy(), attrs[:, 1], attrs[:, 2]

        if origin is None:
            origin = choose_origin(points)
        origin = checked_origin(origin)
        local = points - origin
        check_local_extent(local, tris, building, self.building_ids, source)

        unlabelled = classes == UNLABELLED
        if unlabelled.any():
            corners = local[tris[unlabelled]]
            normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
            tri_min_z = corners[:, :, 2].min(1)
            all_min_z = local[tris][:, :, 2].min(1)
            b_min = np.full(building.max() + 1, np.inf)
            np.minimum.at(b_min, building, all_min_z)
            classes[unlabelled] = classify_by_normals(normals, tri_min_z, b_min[building[unlabelled]])

        return CityModel(
            origin=origin,
            vertices=local.astype(np.float32),
            triangles=tris,
            classes=classes,
            building_index=building,
            lods=lods,
            building_ids=self.building_ids,
            crs=crs,
            source_crs=source_crs,
            source=source,
            stats=self.stats,
        )


def checked_origin(origin) -> np.ndarray:
    """A given local-frame origin as float64 (3,): three finite numbers, else ``ParameterError``."""
    try:
        out = np.asarray(origin, dtype=np.float64)
    except (TypeError, ValueError):
        out = np.empty(0)
    if out.shape != (3,) or not np.isfinite(out).all():
        raise ParameterError(
            f"origin must be three finite numbers (x, y, z in the model's CRS), got {origin!r}"
        )
    return out


def check_local_extent(
    local: np.ndarray, tris: np.ndarray, building: np.ndarray, building_ids: list[str], source: str
) -> None:
    """Refuse a model whose triangles reach farther than ``MAX_LOCAL_EXTENT_M`` from its origin, naming
    the building farthest from the others. Why: one building at a wrong position (a typo, another unit)
    moves the origin away from all the rest, and float32 then rounds every other vertex by metres,
    silently (a 15 m box read as 16 m)."""
    used = local[np.unique(tris)]
    if not len(used) or np.abs(used).max() <= MAX_LOCAL_EXTENT_M:
        return
    first = local[tris[:, 0]]
    centres = np.full((int(building.max()) + 1, 3), np.nan)
    for b in np.unique(building):
        centres[b] = first[building == b].mean(axis=0)
    seen = np.isfinite(centres[:, 0])
    middle = np.median(centres[seen], axis=0)
    far = np.where(seen, np.linalg.norm(np.nan_to_num(centres - middle), axis=1), -1.0)
    worst = int(np.argmax(far))
    name = building_ids[worst] if worst < len(building_ids) else f"#{worst}"
    span = used.max(axis=0) - used.min(axis=0)
    raise InputFileError(
        f"{source or 'city model'}: the model spans {span[0] / 1000:,.1f} x {span[1] / 1000:,.1f} km; "
        f"building {name!r} lies {far[worst] / 1000:,.1f} km from the middle of the others. Local float32 "
        f"coordinates would lose centimetres to metres of precision beyond {MAX_LOCAL_EXTENT_M / 1000:g} km "
        "from the origin: fix or remove that building's coordinates, or split the model into tiles "
        f"({parameter('store_build')})"
    )


def choose_origin(points: np.ndarray) -> np.ndarray:
    """Bounding-box centre rounded to whole metres in x, y; z = 0 so local z stays the source height,
    unless heights exceed ``ABSOLUTE_Z_LIMIT_M`` (e.g. ECEF frames), then the rounded centre too."""
    lo, hi = points.min(0), points.max(0)
    centre = np.round(0.5 * (lo + hi))
    if max(abs(lo[2]), abs(hi[2])) <= ABSOLUTE_Z_LIMIT_M:
        centre[2] = 0.0
    return centre.astype(np.float64)

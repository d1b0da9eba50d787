"""The render scene: the triangles a renderer draws, grouped into ground tiles for view culling.

Built once per ``CityModel`` (``build_scene``):

- building bottoms (GroundSurface triangles, see ``citymodel.ground.building_bottom_mask``) are dropped:
  they are never visible from the air and cost 15-20% of the raster time;
- a terrain TIN of class GROUND is added (``terrain.build_terrain``) unless ``ground=False``, without
  the triangles hidden under building footprints;
- triangles are grouped into square ground tiles of ``tile_size_m`` (by their centroid) and the tiles
  into blocks of ``BLOCK_TILES`` x ``BLOCK_TILES`` tiles. Each tile and block has a 3D bounding box, so
  a view only touches the triangles of tiles whose box meets its frustum. A triangle wider than a tile
  (large terrain or roof triangles) gets a tile of its own so it does not inflate its neighbours' box.

Layout (CSR): triangles are stored sorted by tile, tiles sorted by block. Tile ``k`` owns triangles
``tile_start[k]:tile_start[k+1]``; block ``b`` owns tiles ``block_start[b]:block_start[b+1]``. So
``tile_tri`` (the triangle index of CSR slot ``i``) is the identity and is not stored. Face ids that
renderers return index these sorted triangles; ``source_triangle`` maps them back to the model
(-1 for terrain).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semcityloc.citymodel.model import CityModel
from semcityloc.classes import SemanticClass
from semcityloc.errors import EmptyModelError, RenderError
from semcityloc.render.terrain import build_terrain, building_bottom_mask

BLOCK_TILES = 8


@dataclass(frozen=True)
class RenderScene:
    """Triangles in the model's local frame, float32, grouped into tiles and blocks (module docstring).

    Attributes:
        tri_xyz: float32 (T, 9) corners ``x0 y0 z0 x1 y1 z1 x2 y2 z2`` of every triangle (local frame).
        classes: uint8 (T,) class id per triangle.
        source_triangle: int32 (T,) index of the triangle in the ``CityModel``, -1 for terrain.
        tile_start: int32 (n_tiles + 1,) CSR start of each tile's triangles.
        tile_bbox: float32 (n_tiles, 6) ``xmin ymin zmin xmax ymax zmax`` per tile.
        block_start: int32 (n_blocks + 1,) CSR start of each block's tiles.
        block_bbox: float32 (n_blocks, 6) bounding box per block.
        origin: float64 (3,) the model's origin (world = origin + local).
        tile_size_m: tile edge length in metres.
    """

    tri_xyz: np.ndarray
    classes: np.ndarray
    source_triangle: np.ndarray
    tile_start: np.ndarray
    tile_bbox: np.ndarray
    block_start: np.ndarray
    block_bbox: np.ndarray
    origin: np.ndarray
    tile_size_m: float

    @property
    def num_triangles(self) -> int:
        return int(len(self.classes))

    @property
    def num_tiles(self) -> int:
        return int(len(self.tile_bbox))

    @property
    def num_blocks(self) -> int:
        return int(len(self.block_bbox))

    @property
    def num_terrain_triangles(self) -> int:
        return int(np.count_nonzero(self.source_triangle < 0))

    @property
    def corners(self) -> np.ndarray:
        """(T, 3, 3) float32 view of ``tri_xyz``."""
        return self.tri_xyz.reshape(-1, 3, 3)

    @property
    def bounds_local(self) -> np.ndarray:
        """(2, 3) float64 min/max corner of everything drawn."""
        return np.stack([self.block_bbox[:, :3].min(0), self.block_bbox[:, 3:].max(0)]).astype(np.float64)


def build_scene(
    model: CityModel,
    ground: bool = True,
    tile_size_m: float = 25.0,
    drop_hidden_terrain: bool = True,
    terrain_ring: np.ndarray | None = None,
) -> RenderScene:
    """Render scene of ``model`` (module docstring). Raises ``EmptyModelError`` if nothing is drawable.

    ``drop_hidden_terrain``: leave out terrain under building footprints (``terrain.build_terrain``);
    ``terrain_ring``: the terrain's border points (a tile store's: ``TileStore.terrain_ring``).
    """
    if not isinstance(model, CityModel):
        raise TypeError(f"build_scene needs a CityModel, got {type(model).__name__}")
    if not (isinstance(tile_size_m, (int, float)) and np.isfinite(tile_size_m) and tile_size_m > 0):
        raise RenderError(f"tile_size_m must be a positive number of metres, got {tile_size_m!r}")
    if model.num_triangles == 0:
        raise EmptyModelError("the city model has no triangles to render")
    keep = ~building_bottom_mask(model)
    if not keep.any():
        raise EmptyModelError("the city model has only building bottoms (GroundSurface): nothing is visible")
    corners = model.vertices[model.triangles[keep]].astype(np.float64)  # (T, 3, 3)
    classes = model.classes[keep]
    source = np.flatnonzero(keep).astype(np.int32)
    if ground:
        tv, tt = build_terrain(model, drop_hidden=drop_hidden_terrain, ring=terrain_ring)
        if len(tt):
            corners = np.concatenate([corners, tv[tt]])
            classes = np.concatenate([classes, np.full(len(tt), SemanticClass.GROUND, dtype=np.uint8)])
            source = np.concatenate([source, np.full(len(tt), -1, dtype=np.int32)])
    # Degenerate (zero-area) triangles never cover a pixel: drop them here once.
    area2 = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    ok = np.isfinite(area2) & (area2 > 0)
    corners, classes, source = corners[ok], classes[ok], source[ok]
    if len(corners) == 0:
        raise EmptyModelError("the city model has no non-degenerate triangles to render")
    return _tile(corners, classes, source, model.origin, float(tile_size_m))


def with_model_triangles(scene: RenderScene, model_corners: np.ndarray) -> RenderScene | None:
    """``scene`` with its model triangles at ``model_corners`` ((N, 3, 3), the model's triangles in the
    local frame, indexed like ``source_triangle``), re-tiled; the terrain, classes and order of drawing
    kept. For a variant of the same map with some triangles moved (``citymodel.eaves``): whatever was
    done to the scene's classes (openings merged, silhouettes) and its terrain carries over. None when
    no triangle moved by 1 mm or more."""
    model_tri = scene.source_triangle >= 0
    old = scene.corners.astype(np.float64)
    new = old.copy()
    new[model_tri] = np.asarray(model_corners, dtype=np.float64)[scene.source_triangle[model_tri]]
    if not np.any(np.abs(new - old) >= 1e-3):
        return None
    return _tile(new, scene.classes, scene.source_triangle, scene.origin, scene.tile_size_m)


def _tile(
    corners: np.ndarray, classes: np.ndarray, source: np.ndarray, origin: np.ndarray, ts: float
) -> RenderScene:
    lo, hi = corners.min(1), corners.max(1)  # (T, 3)
    centroid = corners.mean(1)
    big = np.any(hi[:, :2] - lo[:, :2] > ts, axis=1)
    tx = np.floor(centroid[:, 0] / ts).astype(np.int64)
    ty = np.floor(centroid[:, 1] / ts).astype(np.int64)
    bx, by = tx // BLOCK_TILES, ty // BLOCK_TILES
    special = np.where(big, np.arange(len(corners)) + 1, 0)
    order = np.lexsort((special, ty, tx, by, bx))
    keys = np.stack([bx, by, tx, ty, special], 1)[order]
    new_tile = np.ones(len(order), dtype=bool)
    new_tile[1:] = np.any(keys[1:] != keys[:-1], axis=1)
    tile_first = np.flatnonzero(new_tile)
    new_block = np.ones(len(tile_first), dtype=bool)
    tk = keys[tile_first, :2]
    new_block[1:] = np.any(tk[1:] != tk[:-1], axis=1)
    block_first = np.flatnonzero(new_block)

    lo, hi = lo[order], hi[order]
    tile_bbox = np.concatenate([np.minimum.reduceat(lo, tile_first), np.maximum.reduceat(hi, tile_first)], 1)
    block_bbox = np.concatenate(
        [
            np.minimum.reduceat(tile_bbox[:, :3], block_first),
            np.maximum.reduceat(tile_bbox[:, 3:], block_first),
        ],
        1,
    )
    # float32 boxes must still contain the float32 triangles: round outward.
    tile_bbox32 = _outward_f32(tile_bbox)
    block_bbox32 = _outward_f32(block_bbox)
    return RenderScene(
        tri_xyz=np.ascontiguousarray(corners[order].reshape(-1, 9), dtype=np.float32),
        classes=np.ascontiguousarray(classes[order], dtype=np.uint8),
        source_triangle=np.ascontiguousarray(source[order], dtype=np.int32),
        tile_start=np.append(tile_first, len(order)).astype(np.int32),
        tile_bbox=tile_bbox32,
        block_start=np.append(block_first, len(tile_first)).astype(np.int32),
        block_bbox=block_bbox32,
        origin=np.asarray(origin, dtype=np.float64).copy(),
        tile_size_m=ts,
    )


def _outward_f32(bbox: np.ndarray) -> np.ndarray:
    out = bbox.astype(np.float32)
    out[:, :3] = np.nextafter(out[:, :3], np.float32(-np.inf))
    out[:, 3:] = np.nextafter(out[:, 3:], np.float32(np.inf))
    return np.ascontiguousarray(out)

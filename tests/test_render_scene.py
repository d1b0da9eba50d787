"""The render scene: building bottoms dropped, terrain below them, tiles and blocks that hold every
triangle inside their boxes."""

from __future__ import annotations

import numpy as np
import pytest

from semcityloc.citymodel.builder import MeshBuilder
from semcityloc.citymodel.generator import footprints_to_model, tile_model
from semcityloc.citymodel.generator_footprints import generate_footprints
from semcityloc.classes import SemanticClass
from semcityloc.errors import RenderError
from semcityloc.render.scene import build_scene
from semcityloc.render.terrain import TERRAIN_DROP_M, base_points, build_terrain, building_bottom_mask


@pytest.fixture(scope="module")
def city():
    """The generated district (2 x 2 blocks, LoD2): closed buildings on ground with a 1-2 % slope."""
    return footprints_to_model(generate_footprints(seed=7, blocks=(2, 2)), lod=2)


def test_building_bottoms_are_dropped_and_ground_only_objects_kept(city):
    bottoms = building_bottom_mask(city)
    assert bottoms.sum() == (city.classes == SemanticClass.GROUND).sum() > 0
    # A ground-only object (a road surface) stays.
    mb = MeshBuilder()
    o = city.origin
    road = np.array(
        [[o[0], o[1], 30.0], [o[0] + 50, o[1], 30.0], [o[0] + 50, o[1] + 5, 30.0], [o[0], o[1] + 5, 30.0]]
    )
    mb.add_polygon(road, semantic=SemanticClass.GROUND, building_id="road", lod=2)
    roads = mb.build(origin=o)
    assert not building_bottom_mask(roads).any()
    scene = build_scene(city, ground=False)
    assert scene.num_triangles == city.num_triangles - bottoms.sum()
    assert not (scene.classes == SemanticClass.GROUND).any()
    assert scene.num_terrain_triangles == 0


def test_terrain_lies_just_below_the_building_bottoms_and_follows_the_slope(city):
    tv, tt = build_terrain(city)
    assert len(tt) > 0 and tt.dtype == np.int32
    base = base_points(city)
    # Every footprint point is a terrain vertex, TERRAIN_DROP_M lower.
    from scipy.spatial import cKDTree

    d, idx = cKDTree(tv[:, :2]).query(base[:, :2])
    assert d.max() < 0.02
    np.testing.assert_allclose(tv[idx, 2], base[:, 2] - TERRAIN_DROP_M, atol=1e-9)
    # The margin reaches at least 200 m beyond the buildings, and the district's slope (1-2 %, fitted to
    # the base points) shows: the margin beyond the uphill side is higher than beyond the downhill side.
    lo, hi = city.bounds_local
    assert tv[:, 0].min() <= lo[0] - 199 and tv[:, 1].max() >= hi[1] + 199
    grad = np.linalg.lstsq(np.column_stack([base[:, :2], np.ones(len(base))]), base[:, 2], rcond=None)[0][:2]
    slope = float(np.hypot(*grad))
    assert 0.01 <= slope <= 0.02
    along, base_along = tv[:, :2] @ (grad / slope), base[:, :2] @ (grad / slope)
    uphill = tv[along > base_along.max()][:, 2].mean()
    downhill = tv[along < base_along.min()][:, 2].mean()
    assert uphill - downhill > 0.5 * slope * (base_along.max() - base_along.min()) > 1.0
    # Upward-facing TIN (no vertical slivers) and no triangle above the highest base point.
    c = tv[tt]
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    assert (np.abs(n[:, 2]) > 0).all()
    assert c[:, :, 2].max() <= base[:, 2].max()


def test_terrain_under_footprints_is_dropped_without_changing_any_view(city):
    full_v, full_t = build_terrain(city, drop_hidden=False)
    kept_v, kept_t = build_terrain(city)
    assert 0 < len(kept_t) < len(full_t)
    # Every dropped triangle's centroid is under a footprint (a bottom triangle).
    from semcityloc.render.terrain import _under_footprints

    bottoms = city.vertices[city.triangles[building_bottom_mask(city)]][:, :, :2].astype(np.float64)
    kept = {tuple(c) for c in np.round(kept_v[kept_t].mean(1), 6)}
    full_c = np.round(full_v[full_t].mean(1), 6)
    dropped = np.array([c for c in full_c if tuple(c) not in kept])
    assert len(dropped) == len(full_t) - len(kept_t)
    assert _under_footprints(dropped[:, None, :2].repeat(3, axis=1), bottoms).all()
    # The generated buildings are closed: from cameras outside them the masks are the same, except where a
    # grazing ray slips through the TERRAIN_DROP_M slit under a wall and used to meet the dropped terrain.
    from semcityloc.geometry.camera import Camera
    from semcityloc.geometry.pose import Pose
    from semcityloc.render.raster_numba import NumbaEngine

    rng = np.random.default_rng(0)
    lo, hi = city.bounds_local
    n = 30
    xyz = np.column_stack(
        [rng.uniform(lo[0], hi[0], n), rng.uniform(lo[1], hi[1], n), np.full(n, hi[2] + 60)]
    )
    poses = Pose.from_xyz_rpy(xyz, np.zeros(n), rng.uniform(0, 60, n), rng.uniform(-180, 180, n))
    cam = Camera.from_fov(96, 72, 60.0)
    R, t = np.ascontiguousarray(poses.R), np.ascontiguousarray(poses.t)
    a = NumbaEngine(build_scene(city, drop_hidden_terrain=False)).render(cam, R, t, depth=True)
    b = NumbaEngine(build_scene(city)).render(cam, R, t, depth=True)
    same = a.labels == b.labels
    assert same.mean() > 0.999
    assert (a.labels[~same] == SemanticClass.GROUND).all() and (b.labels[~same] == 0).all()
    np.testing.assert_array_equal(a.depth[same], b.depth[same])


def test_scene_tiles_and_blocks_are_a_consistent_csr_index(city):
    big = tile_model(city, 3, 2)
    scene = build_scene(big, tile_size_m=20.0)
    assert scene.tri_xyz.dtype == np.float32 and scene.tri_xyz.shape == (scene.num_triangles, 9)
    ts, bs = scene.tile_start, scene.block_start
    assert ts[0] == 0 and ts[-1] == scene.num_triangles and np.all(np.diff(ts) > 0)
    assert bs[0] == 0 and bs[-1] == scene.num_tiles and np.all(np.diff(bs) > 0)
    corners = scene.corners
    tile_of = np.repeat(np.arange(scene.num_tiles), np.diff(ts))
    box = scene.tile_bbox[tile_of]
    assert (corners.min(1) >= box[:, :3]).all() and (corners.max(1) <= box[:, 3:]).all()
    block_of = np.repeat(np.arange(scene.num_blocks), np.diff(bs))
    bb = scene.block_bbox[block_of]
    assert (scene.tile_bbox[:, :3] >= bb[:, :3]).all() and (scene.tile_bbox[:, 3:] <= bb[:, 3:]).all()
    # Ordinary tiles are at most a tile wide (plus the triangles reaching out of them).
    small = np.diff(ts) > 1
    assert (scene.tile_bbox[small, 3] - scene.tile_bbox[small, 0]).max() <= 3 * 20.0
    # source_triangle maps back to the model; terrain is -1 and GROUND.
    src = scene.source_triangle
    np.testing.assert_array_equal(scene.classes[src >= 0], big.classes[src[src >= 0]])
    assert (scene.classes[src < 0] == SemanticClass.GROUND).all()
    np.testing.assert_allclose(
        corners[src >= 0], big.vertices[big.triangles[src[src >= 0]]].astype(np.float32), atol=0
    )


def test_bad_tile_size_is_a_render_error(city):
    with pytest.raises(RenderError, match="tile_size_m"):
        build_scene(city, tile_size_m=0.0)
    with pytest.raises(TypeError, match="CityModel"):
        build_scene("city.gml")


def test_a_scene_with_model_triangles_moved_keeps_its_terrain_and_classes(city):
    """``with_model_triangles``: the same scene with the model's triangles where they now are (a map with
    eaves), re-tiled so every box still holds its triangles; terrain and classes (whatever the scene had
    done to them) kept; None when nothing moved."""
    from semcityloc.citymodel.eaves import with_eaves
    from semcityloc.render.scene import with_model_triangles

    scene = build_scene(city, tile_size_m=20.0)
    scene = type(scene)(**{**scene.__dict__, "classes": np.where(scene.classes == 1, 2, scene.classes)})
    assert with_model_triangles(scene, city.vertices[city.triangles]) is None
    moved_model = with_eaves(city, 0.8, flat_roofs=True)
    moved = with_model_triangles(scene, moved_model.vertices[moved_model.triangles])
    assert moved is not None and moved.num_triangles == scene.num_triangles
    src = moved.source_triangle
    np.testing.assert_allclose(
        moved.corners[src >= 0], moved_model.vertices[moved_model.triangles[src[src >= 0]]], atol=1e-5
    )
    old_terrain = scene.corners[scene.source_triangle < 0]
    new_terrain = moved.corners[src < 0]
    key = lambda c: np.lexsort(c.reshape(len(c), 9).T)  # noqa: E731  (the terrain, in any order)
    np.testing.assert_array_equal(new_terrain[key(new_terrain)], old_terrain[key(old_terrain)])
    class_of = np.zeros(city.num_triangles, dtype=np.uint8)
    class_of[scene.source_triangle[scene.source_triangle >= 0]] = scene.classes[scene.source_triangle >= 0]
    np.testing.assert_array_equal(
        moved.classes[src >= 0], class_of[src[src >= 0]]
    )  # the scene's, not the model's
    tile_of = np.repeat(np.arange(moved.num_tiles), np.diff(moved.tile_start))
    box = moved.tile_bbox[tile_of]
    assert (moved.corners.min(1) >= box[:, :3]).all() and (moved.corners.max(1) <= box[:, 3:]).all()

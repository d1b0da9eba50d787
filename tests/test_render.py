"""The numba rasteriser: analytic footprints and depths, sampling convention, tie rule, near-plane
clipping, degenerate inputs, and agreement with the Embree ray caster on generated cities."""

from __future__ import annotations

import numpy as np
import pytest

from semcityloc.citymodel.builder import MeshBuilder
from semcityloc.citymodel.generator import footprints_to_model
from semcityloc.citymodel.generator_footprints import generate_footprints
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import SemanticClass
from semcityloc.errors import ArgumentTypeError, EmptyModelError, PoseError, RenderError, ShapeError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.render import Renderer, RenderOutput
from semcityloc.render.embree_ref import embree_available

needs_embree = pytest.mark.skipif(
    not embree_available(), reason="embreex (semcityloc[reference]) not installed"
)

ORIGIN = np.array([391000.0, 5817000.0, 0.0])


def nadir(x: float, y: float, z: float, yaw: float = 0.0) -> Pose:
    return Pose.from_xyz_rpy(np.array([x, y, z]), 0.0, 0.0, yaw)


def box_model(size: float = 10.0, height: float = 10.0) -> CityModel:
    """One flat-roofed box centred on the local origin, ground at local z = 0: four walls, a roof and a
    bottom, outward-facing polygons with their semantic class."""
    mb = MeshBuilder()
    h = size / 2
    x0, y0, x1, y1 = ORIGIN[0] - h, ORIGIN[1] - h, ORIGIN[0] + h, ORIGIN[1] + h
    corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    for k in range(4):
        (ax, ay), (bx, by) = corners[k], corners[(k + 1) % 4]
        wall = np.array([[ax, ay, 0.0], [bx, by, 0.0], [bx, by, height], [ax, ay, height]])
        mb.add_polygon(wall, semantic=SemanticClass.WALL, building_id="box", lod=2)
    bottom = np.array([[x0, y0, 0.0], [x0, y1, 0.0], [x1, y1, 0.0], [x1, y0, 0.0]])
    mb.add_polygon(bottom, semantic=SemanticClass.GROUND, building_id="box", lod=2)
    top = np.array([[x0, y0, height], [x1, y0, height], [x1, y1, height], [x0, y1, height]])
    mb.add_polygon(top, semantic=SemanticClass.ROOF, building_id="box", lod=2)
    return mb.build(origin=ORIGIN)


def mesh_model(points: np.ndarray, triangles: np.ndarray, cls: int = SemanticClass.ROOF) -> CityModel:
    """A raw triangle mesh in LOCAL coordinates (origin 0: exact binary coordinates stay exact)."""
    mb = MeshBuilder()
    tris = np.asarray(triangles).reshape(-1, 3)
    mb.add_mesh(points, tris, np.full(len(tris), cls), np.zeros(len(tris), dtype=int), lod=2)
    return mb.build(origin=np.zeros(3))


@pytest.fixture(scope="module")
def city() -> CityModel:
    """The generated district (2 x 2 blocks, LoD2 with flat, gable, hip and mono-pitch roofs)."""
    return footprints_to_model(generate_footprints(seed=3, blocks=(2, 2)), lod=2)


@pytest.fixture(scope="module")
def city_renderer(city) -> Renderer:
    return Renderer(city, engine="numba")


def random_views(model: CityModel, n: int, pitch: tuple[float, float], seed: int) -> Pose:
    rng = np.random.default_rng(seed)
    lo, hi = model.bounds_local
    xyz = np.column_stack(
        [rng.uniform(lo[0], hi[0], n), rng.uniform(lo[1], hi[1], n), hi[2] + rng.uniform(40, 150, n)]
    )
    return Pose.from_xyz_rpy(xyz, rng.normal(0, 3, n), rng.uniform(*pitch, n), rng.uniform(-180, 180, n))


# ------------------------------------------------------------------------------------------ analytic
def test_box_from_above_has_exact_roof_footprint_and_depth():
    r = Renderer(box_model(10.0, 10.0), engine="numba")
    assert r.engine_name == "numba"
    # Camera 110 m above the roof with f = 110 px: the 10 m roof is exactly 10 px wide, its edges on
    # pixel boundaries (u = 27 and 37), so it covers centres 27.5 .. 36.5 in both directions.
    cam = Camera(110.0, 110.0, 32.0, 24.0, 64, 48)
    out = r.render(cam, nadir(0.0, 0.0, 120.0), depth=True, face_ids=True)
    labels = out.labels[0]
    roof = labels == SemanticClass.ROOF
    assert roof.sum() == 100
    rows, cols = np.nonzero(roof)
    assert (cols.min(), cols.max(), rows.min(), rows.max()) == (27, 36, 19, 28)
    np.testing.assert_allclose(out.depth[0][roof], 110.0, rtol=1e-6)
    # Walls are hidden at nadir (their bases project inside the roof outline); the terrain fills the rest,
    # 0.05 m below the building bottom.
    assert not (labels == SemanticClass.WALL).any()
    ground = labels == SemanticClass.GROUND
    assert ground.sum() == 64 * 48 - 100
    np.testing.assert_allclose(out.depth[0][ground], 120.05, rtol=1e-6)
    assert (out.face_ids[0] >= 0).all()
    src = r.scene.source_triangle[out.face_ids[0]]
    assert (src[roof] >= 0).all() and (src[ground] == -1).all()


def test_class_ids_roof_on_top_walls_when_oblique_ground_around():
    r = Renderer(box_model(10.0, 20.0), engine="numba")
    cam = Camera.from_fov(64, 48, 60.0)
    # 45 degrees oblique, 60 m back from the box (south), looking north at it.
    pose = Pose.from_xyz_rpy(np.array([0.0, -60.0, 60.0]), 0.0, 45.0, 0.0)
    out = r.render(cam, pose, depth=True)
    labels = out.labels[0]
    counts = np.bincount(labels.ravel(), minlength=6)
    assert (
        counts[SemanticClass.WALL] > 20
        and counts[SemanticClass.ROOF] > 20
        and counts[SemanticClass.GROUND] > 500
    )
    rows_roof = np.nonzero(labels == SemanticClass.ROOF)[0]
    rows_wall = np.nonzero(labels == SemanticClass.WALL)[0]
    assert rows_roof.mean() < rows_wall.mean()  # the roof is above the facade in the image
    # Nadir: no background at all over the terrain; ground without ground=False disappears.
    bare = Renderer(box_model(10.0, 20.0), engine="numba", ground=False)
    lab = bare.render(cam, nadir(0.0, 0.0, 80.0)).labels[0]
    assert set(np.unique(lab)) <= {0, SemanticClass.ROOF, SemanticClass.WALL}
    assert (lab == 0).sum() > 1000


def test_pixel_centres_are_sampled_like_rays():
    # A 10 m square 64 m below a nadir camera with f = 64: u = X + 32 and v = 24 - Y exactly.
    # Square X in [-21.75, -11.75] -> u in [10.25, 20.25]: centres 10.5 .. 19.5, i.e. columns 10..19.
    # (Sampling pixel corners u = j would give columns 11..20.)
    pts = np.array([[-21.75, -5, 0], [-11.75, -5, 0], [-11.75, 5, 0], [-21.75, 5, 0]], dtype=float)
    r = Renderer(mesh_model(pts, [[0, 1, 2], [0, 2, 3]]), engine="numba", ground=False)
    cam = Camera(64.0, 64.0, 32.0, 24.0, 64, 48)
    lab = r.render(cam, nadir(0.0, 0.0, 64.0)).labels[0]
    cols = np.nonzero(lab.any(0))[0]
    rows = np.nonzero(lab.any(1))[0]
    assert list(cols) == list(range(10, 20))
    assert list(rows) == list(range(19, 29))  # v in [19, 29]


def _coverage(points, tris, cam, pose) -> np.ndarray:
    r = Renderer(mesh_model(points, tris), engine="numba", ground=False)
    return r.render(cam, pose, face_ids=True).face_ids[0] >= 0


def test_edges_through_pixel_centres_are_covered_exactly_once():
    cam = Camera(64.0, 64.0, 32.0, 24.0, 64, 48)
    pose = nadir(0.0, 0.0, 64.0)
    # Square u, v in [10, 20] x [10, 20] split along its diagonal, which passes through 10 centres.
    # World: X = u - 32, Y = 24 - v.
    sq = np.array([[-22, 14, 0], [-12, 14, 0], [-12, 4, 0], [-22, 4, 0]], dtype=float)
    a = _coverage(sq, [[0, 1, 2]], cam, pose)
    b = _coverage(sq, [[0, 2, 3]], cam, pose)
    both = _coverage(sq, [[0, 1, 2], [0, 2, 3]], cam, pose)
    assert both.sum() == 100
    assert a.sum() + b.sum() == 100
    assert not (a & b).any()
    # A fan of 6 triangles around a vertex exactly at a pixel centre (u, v) = (40.5, 30.5), with rim
    # vertices on pixel centres too: every centre of the hexagon is covered by exactly one triangle.
    cu, cv = 40.5, 30.5
    rim = [(cu + 6, cv), (cu + 3, cv - 5), (cu - 3, cv - 5), (cu - 6, cv), (cu - 3, cv + 5), (cu + 3, cv + 5)]
    pts = np.array([[cu - 32, 24 - cv, 0]] + [[u - 32, 24 - v, 0] for u, v in rim], dtype=float)
    fan = [[0, 1 + k, 1 + (k + 1) % 6] for k in range(6)]
    single = [_coverage(pts, [t], cam, pose) for t in fan]
    union = _coverage(pts, fan, cam, pose)
    total = np.sum(single, axis=0)
    assert total.max() == 1
    assert (total == union).all()


def test_near_plane_clipping_of_a_huge_ground_triangle_matches_the_plane():
    # A 20 km triangle on z = 0; camera 2 m above it, 70 degrees from nadir: the triangle crosses the
    # near plane (two corners behind the camera).
    pts = np.array([[-10000.0, -10000.0, 0.0], [10000.0, -10000.0, 0.0], [0.0, 10000.0, 0.0]])
    r = Renderer(mesh_model(pts, [[0, 1, 2]], cls=SemanticClass.GROUND), engine="numba", ground=False)
    cam = Camera.from_fov(64, 48, 70.0)
    for pitch, yaw in [(70.0, 0.0), (85.0, 30.0), (60.0, 180.0)]:
        pose = Pose.from_xyz_rpy(np.array([0.0, 0.0, 2.0]), 0.0, pitch, yaw)
        out = r.render(cam, pose, depth=True)
        rays = cam.ray_directions()  # z = 1 camera rays
        d = rays @ pose.R  # world directions (R^T r as row vectors)
        hits = d[..., 2] < 0
        expect = np.where(hits, 2.0 / np.where(hits, -d[..., 2], 1.0), np.inf)
        # Far hits beyond the triangle edge would be misses; at 2 m height all hits are within ~200 m.
        assert (out.labels[0] == SemanticClass.GROUND).sum() == hits.sum() > 0
        np.testing.assert_array_equal(out.labels[0] > 0, hits)
        np.testing.assert_allclose(out.depth[0][hits], expect[hits], rtol=1e-5)
        assert np.isinf(out.depth[0][~hits]).all()


def test_one_vertex_in_front_clipping_case():
    # Camera 1 m above the ground looking horizontally north; a triangle with one vertex 50 m ahead and
    # two vertices 5 m behind the camera: after clipping, one triangle remains.
    pts = np.array([[0.0, 50.0, 0.0], [-30.0, -5.0, 0.0], [30.0, -5.0, 0.0]])
    r = Renderer(mesh_model(pts, [[0, 1, 2]], cls=SemanticClass.GROUND), engine="numba", ground=False)
    cam = Camera.from_fov(64, 48, 90.0)
    pose = Pose.from_xyz_rpy(np.array([0.0, 0.0, 1.0]), 0.0, 90.0, 0.0)
    out = r.render(cam, pose, depth=True)
    lab = out.labels[0]
    assert lab[:24].sum() == 0  # nothing above the horizon
    assert (lab[-1, 20:44] == SemanticClass.GROUND).all()  # bottom row just ahead of the camera
    # Depth along the optical axis of a ground point seen at row i: z = 1 * fy / (v - cy).
    i = 47
    np.testing.assert_allclose(out.depth[0][i, 32], cam.fy / (i + 0.5 - cam.cy), rtol=1e-5)


# ------------------------------------------------------------------------------------------ degenerate
def test_sky_view_is_all_background_not_an_error(city_renderer, city):
    cam = Camera.from_fov(32, 24, 60.0)
    top = city.bounds_local[1][2]
    up = Pose.from_xyz_rpy(np.array([0.0, 0.0, top + 50.0]), 0.0, 180.0, 0.0)  # optical axis to zenith
    out = city_renderer.render(cam, up, depth=True, face_ids=True)
    assert out.labels.shape == (1, 24, 32) and out.labels.dtype == np.uint8
    assert (out.labels == 0).all() and np.isinf(out.depth).all() and (out.face_ids == -1).all()


def test_camera_inside_a_building_renders(city):
    r = Renderer(box_model(10.0, 10.0), engine="numba")
    cam = Camera.from_fov(32, 24, 90.0)
    inside = Pose.from_xyz_rpy(np.array([[0.0, 0.0, 5.0]] * 3), 0.0, np.array([0.0, 90.0, 180.0]), 0.0)
    out = r.render(cam, inside, depth=True)
    # Looking down: nothing (the bottom is dropped and so is the terrain under the footprint, both hidden
    # from outside); sideways: walls all around; up: the roof.
    assert (out.labels[0] == 0).all()
    assert (out.labels[1] == SemanticClass.WALL).sum() > 0.5 * 32 * 24
    assert (out.labels[1] > 0).all()
    assert (out.labels[2] == SemanticClass.ROOF).all()
    np.testing.assert_allclose(out.depth[2], 5.0, rtol=1e-6)


def test_batched_equals_one_by_one(city_renderer, city):
    cam = Camera.from_fov(40, 30, 60.0)
    poses = random_views(city, 9, (0.0, 60.0), seed=5)
    batch = city_renderer.render(cam, poses, depth=True, face_ids=True)
    assert batch.labels.shape == (9, 30, 40) and len(batch) == 9
    for k in range(9):
        one = city_renderer.render(cam, poses[k], depth=True, face_ids=True)
        np.testing.assert_array_equal(one.labels[0], batch.labels[k])
        np.testing.assert_array_equal(one.face_ids[0], batch.face_ids[k])
        np.testing.assert_array_equal(one.depth[0], batch.depth[k])
    sub = batch[3]
    assert isinstance(sub, RenderOutput) and sub.labels.shape == (1, 30, 40)


def test_bad_inputs_are_rejected_with_typed_errors(city_renderer):
    cam = Camera.from_fov(32, 24, 60.0)
    with pytest.raises(TypeError, match="Camera"):
        city_renderer.render("camera", nadir(0, 0, 100))
    with pytest.raises(TypeError, match="Pose"):
        city_renderer.render(cam, np.eye(4))
    grid = Pose(np.broadcast_to(np.eye(3), (2, 3, 3, 3)), np.zeros((2, 3, 3)))
    with pytest.raises(ShapeError, match="1-D batch"):
        city_renderer.render(cam, grid)
    huge = Camera.from_fov(100_000, 75_000, 60.0)  # stop 45's audit: all the RAM, then killed
    with pytest.raises(RenderError, match=r"1 view\(s\) of 100000x75000 pixels .* exceed"):
        city_renderer.render(huge, nadir(0, 0, 100))
    with pytest.raises(RenderError, match="unknown render engine"):
        Renderer(box_model(), engine="opengl")
    empty = CityModel(
        origin=ORIGIN,
        vertices=np.zeros((0, 3)),
        triangles=np.zeros((0, 3)),
        classes=[],
        building_index=[],
        lods=[],
        building_ids=[],
    )
    with pytest.raises(EmptyModelError):
        Renderer(empty)
    # A ground-only object is not a building bottom (nothing stands on it): it is drawn, not dropped.
    ground_only = box_model().select(box_model().classes == SemanticClass.GROUND)
    lab = Renderer(ground_only, engine="numba").render(cam, nadir(0, 0, 50)).labels
    assert (lab == SemanticClass.GROUND).sum() > 0


# ------------------------------------------------------------------------------------------ vs Embree
@needs_embree
@pytest.mark.parametrize("pitch", [(0.0, 10.0), (30.0, 60.0)], ids=["nadir", "oblique"])
def test_agrees_with_embree_on_a_generated_city(city, pitch):
    numba_r = Renderer(city, engine="numba")
    embree_r = Renderer(city, engine="embree")
    assert embree_r.engine_name == "embree"
    cam = Camera.from_fov(64, 48, 60.0)
    poses = random_views(city, 40, pitch, seed=int(pitch[0]) + 1)
    a = numba_r.render(cam, poses, depth=True, face_ids=True)
    b = embree_r.render(cam, poses, depth=True, face_ids=True)
    assert (a.labels == b.labels).mean() >= 0.995
    assert (a.face_ids == b.face_ids).mean() >= 0.995
    both = np.isfinite(a.depth) & np.isfinite(b.depth)
    assert both.mean() > 0.5  # oblique views also see sky beyond the terrain margin
    rel = np.abs(a.depth[both] - b.depth[both]) / b.depth[both]
    same_face = (a.face_ids == b.face_ids)[both]
    assert rel[same_face].max() <= 1e-3  # depth = ray-cast depth wherever both see the same triangle
    assert np.median(rel) < 1e-5


def test_a_world_pose_or_a_wrong_kind_of_argument_is_a_typed_error():
    """``render`` takes local poses: a world (CRS) pose drew an all-background mask without a word; a
    path for the model, a K matrix for the camera and a list for the poses were plain TypeErrors."""
    model = box_model()
    renderer = Renderer(model)
    camera = Camera.from_fov(64, 48, 60.0)
    local = nadir(0.0, 0.0, 40.0)
    assert (renderer.render(camera, local).labels[0] == SemanticClass.ROOF).any()
    with pytest.raises(PoseError, match=r"takes poses in the model's local frame: camera centre \(391"):
        renderer.render(camera, model.pose_to_world(local))
    for call in (
        lambda: Renderer("city.gml"),
        lambda: renderer.render(camera.K, local),
        lambda: renderer.render(camera, [local, local]),
        lambda: model.pose_to_local(np.eye(4)),
    ):
        with pytest.raises(ArgumentTypeError):
            call()


@pytest.mark.parametrize("preset, expected", [(None, "PASSIVE"), ("ACTIVE", "ACTIVE")])
def test_openmp_threads_wait_asleep_unless_the_user_chose(preset, expected):
    """On shared cores a spinning OpenMP thread cost every parallel kernel call ~8 ms (stop 54): the render
    package sets ``OMP_WAIT_POLICY=PASSIVE`` before numba starts its threads, and keeps a user's own."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if preset is not None:
        env["OMP_WAIT_POLICY"] = preset
    code = "import os, semcityloc.render.raster_numba; print(os.environ.get('OMP_WAIT_POLICY'))"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == expected

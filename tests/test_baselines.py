"""Baselines: model feature edges, simulated edge maps, the LoD-Loc-style wireframe localizer and the
silhouette localizer on the generated city, and their benchmark wiring."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy import ndimage

from semcityloc.baselines import (
    REASON_NO_EDGES,
    EdgeMapSimulator,
    SilhouetteLocalizer,
    WireframeLocalizer,
    extract_edges,
    image_edge_map,
    make_baseline_method,
    simulate_edge_map,
)
from semcityloc.baselines.edges import EDGE_CLASS
from semcityloc.baselines.silhouette import BUILDING, silhouette_labels
from semcityloc.citymodel.citygml import read_citygml
from semcityloc.citymodel.generator import generate_city
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import SemanticClass
from semcityloc.errors import CameraError, ParameterError, PoseError, ShapeError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.errors import center_error_m, rotation_error_deg
from semcityloc.geometry.pose import Pose
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.result import LOCALIZED, NOT_LOCALIZED, REASON_LOW_SCORE, REASON_NO_GEOMETRY
from semcityloc.render import Renderer

CAMERA = Camera.from_fov(512, 384, 70.0)
W, R, G, D = SemanticClass.WALL, SemanticClass.ROOF, SemanticClass.GROUND, SemanticClass.DOOR


# ------------------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def city(tmp_path_factory):
    paths = generate_city(tmp_path_factory.mktemp("city"), seed=0)
    return read_citygml(paths[2])


@pytest.fixture(scope="module")
def wire(city):
    return WireframeLocalizer(city)


@pytest.fixture(scope="module")
def edge_sim(city, wire):
    return EdgeMapSimulator(city, wire.scene, wire.edges)


@pytest.fixture(scope="module")
def renderer(city):
    return Renderer(city, engine="numba")


def view(city, dx, dy, height, roll, pitch, yaw) -> Pose:
    lo, hi = city.bounds_local
    centre = 0.5 * (lo + hi)
    return Pose.from_xyz_rpy([centre[0] + dx, centre[1] + dy, lo[2] + height], roll, pitch, yaw)


def perturbed(pose: Pose, dxyz, droll, dpitch, dyaw) -> Pose:
    x, y, z, roll, pitch, yaw = pose.to_xyz_rpy()
    return Pose.from_xyz_rpy(np.array([x, y, z]) + dxyz, roll + droll, pitch + dpitch, yaw + dyaw)


VIEWS = {
    "nadir": (10.0, -20.0, 80.0, 1.0, 2.0, 30.0),
    "oblique": (-30.0, 15.0, 90.0, -1.0, 40.0, 200.0),
}
# Priors 5 m and 3 degrees of yaw off, plus 0.5 degrees of roll and pitch.
PRIOR_SHIFTS = {"nadir": (3.0, -4.0, 0.0), "oblique": (-4.0, 0.0, 3.0)}


# ------------------------------------------------------------------------------------------ edges
def _quad(p0, p1, p2, p3):
    return [np.array([p0, p1, p2]), np.array([p0, p2, p3])]


def box_model() -> CityModel:
    """10 x 6 x 4 m box; every face has its own vertices; the roof is two coplanar halves (a T-junction
    on the long walls' top edges); the south facade is a wall (x 0-8) and a door (x 8-10)."""
    faces: list[tuple[int, list]] = []
    faces.append((G, _quad((0, 0, 0), (10, 0, 0), (10, 6, 0), (0, 6, 0))))
    faces.append((R, _quad((0, 0, 4), (5, 0, 4), (5, 6, 4), (0, 6, 4))))
    faces.append((R, _quad((5, 0, 4), (10, 0, 4), (10, 6, 4), (5, 6, 4))))
    faces.append((W, _quad((0, 0, 0), (8, 0, 0), (8, 0, 4), (0, 0, 4))))
    faces.append((D, _quad((8, 0, 0), (10, 0, 0), (10, 0, 4), (8, 0, 4))))
    faces.append((W, _quad((0, 6, 0), (10, 6, 0), (10, 6, 4), (0, 6, 4))))
    faces.append((W, _quad((0, 0, 0), (0, 6, 0), (0, 6, 4), (0, 0, 4))))
    faces.append((W, _quad((10, 0, 0), (10, 6, 0), (10, 6, 4), (10, 0, 4))))
    tris, classes = [], []
    for cls, pair in faces:
        tris += pair
        classes += [int(cls)] * len(pair)
    corners = np.array(tris, dtype=np.float64)
    return CityModel(
        origin=np.array([500000.0, 5800000.0, 30.0]),
        vertices=corners.reshape(-1, 3),
        triangles=np.arange(3 * len(corners)).reshape(-1, 3),
        classes=np.array(classes),
        building_index=np.zeros(len(corners), dtype=np.int32),
        lods=np.full(len(corners), 2),
        building_ids=["box"],
    )


def test_box_edges_are_its_twelve_edges_plus_the_door_frame():
    edges = extract_edges(box_model())
    lengths = edges.lengths
    # 4 x (10 + 6 + 4) = 80 m of box edges, plus the 4 m wall/door seam; no diagonals, no roof seam.
    assert lengths.sum() == pytest.approx(84.0, abs=1e-6)
    assert lengths[edges.kind == EDGE_CLASS].sum() == pytest.approx(4.0, abs=1e-6)
    seg = edges.segments
    on_roof_seam = np.all(np.isclose(seg[:, :, 0], 5.0), axis=1) & np.all(np.isclose(seg[:, :, 2], 4.0), 1)
    assert not on_roof_seam.any()
    diagonal = np.count_nonzero(np.abs(seg[:, 1] - seg[:, 0]) > 1e-9, axis=1) > 1
    assert not diagonal.any()
    assert edges.physical().lengths.sum() == pytest.approx(80.0, abs=1e-6)


def test_edge_samples_lie_on_the_edges_at_the_spacing():
    edges = extract_edges(box_model())
    points, index = edges.sample(0.5)
    assert len(points) == pytest.approx(84.0 / 0.5, abs=len(edges))
    a, b = edges.segments[index, 0], edges.segments[index, 1]
    t = np.einsum("ij,ij->i", points - a, b - a) / np.einsum("ij,ij->i", b - a, b - a)
    assert np.all((t > 0) & (t < 1))
    assert np.allclose(a + t[:, None] * (b - a), points)
    with pytest.raises(ParameterError):
        edges.sample(0.0)


def test_generated_city_edges(city):
    edges = extract_edges(city)
    assert len(edges) > 500
    # Every edge touches a building: nothing lies only on the ground (z of the terrain, far from walls).
    assert np.all(edges.segments[:, :, 2].max(1) >= city.bounds_local[0, 2] - 1e-3)
    assert set(np.unique(edges.building)) <= set(range(len(city.building_ids)))


# ------------------------------------------------------------------------------------------ edge maps
def _true_edge_pixels(sim: EdgeMapSimulator, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    uv, _, _ = sim.visible_edges(CAMERA, pose)
    ideal = np.zeros((CAMERA.height, CAMERA.width), dtype=bool)
    col, row = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    ok = (col >= 0) & (col < CAMERA.width) & (row >= 0) & (row < CAMERA.height)
    ideal[row[ok], col[ok]] = True
    return uv, ideal


def test_edge_map_presets_are_ordered_by_quality(city, edge_sim):
    pose = view(city, *VIEWS["oblique"])
    uv, ideal = _true_edge_pixels(edge_sim, pose)
    far = ndimage.distance_transform_edt(~ideal) > 4
    recall, clutter = {}, {}
    for quality in ("clean", "trained", "noisy"):
        r, c = [], []
        for seed in range(3):
            emap = edge_sim.simulate(CAMERA, pose, quality, np.random.default_rng(seed))
            assert emap.shape == (CAMERA.height, CAMERA.width) and emap.dtype == np.float32
            assert emap.min() >= 0.0 and emap.max() <= 1.0
            col = np.clip(np.floor(uv[:, 0]).astype(int), 0, CAMERA.width - 1)
            row = np.clip(np.floor(uv[:, 1]).astype(int), 0, CAMERA.height - 1)
            r.append(float(emap[row, col].mean()))  # how much of the true wireframe is there
            c.append(float(emap[far].sum() / emap.sum()))  # share of the map away from true edges
        recall[quality], clutter[quality] = np.mean(r), np.mean(c)
    assert recall["clean"] > 0.95
    assert recall["clean"] > recall["trained"] + 0.05 > recall["noisy"] + 0.1
    assert clutter["clean"] < 0.01
    assert clutter["clean"] < clutter["trained"] < clutter["noisy"]


def test_edge_map_is_deterministic_and_hides_occluded_edges(city, edge_sim, renderer):
    pose = view(city, *VIEWS["nadir"])
    a = simulate_edge_map(edge_sim, CAMERA, pose, "trained", np.random.default_rng(7))
    b = simulate_edge_map(renderer, CAMERA, pose, "trained", np.random.default_rng(7))
    assert np.array_equal(a, b)
    occ = np.zeros((CAMERA.height, CAMERA.width), dtype=bool)
    occ[:, : CAMERA.width // 2] = True
    clean = edge_sim.simulate(CAMERA, pose, "clean", np.random.default_rng(0), occluder_mask=occ)
    assert clean[:, : CAMERA.width // 2 - 6].max() == 0.0
    assert clean[:, CAMERA.width // 2 + 6 :].max() > 0.9
    noisy = edge_sim.simulate(CAMERA, pose, "noisy", np.random.default_rng(0), occluder_mask=occ)
    assert noisy[:, CAMERA.width // 2 - 1].max() > 0.3  # the occluder's outline is a (spurious) edge
    with pytest.raises(ShapeError):
        edge_sim.simulate(CAMERA, pose, "clean", occluder_mask=occ[:, :100])
    with pytest.raises(ParameterError):
        edge_sim.simulate(CAMERA, pose, "perfect-ish")


def test_image_edge_map_marks_intensity_steps():
    img = np.zeros((60, 80, 3), dtype=np.uint8)
    img[20:40, 30:60] = 200
    emap = image_edge_map(img)
    assert emap.shape == (60, 80) and emap.dtype == np.float32
    assert emap[20, 45] > 0.9 and emap[30, 30] > 0.9  # on the square's outline
    assert emap[30, 45] < 0.05 and emap[5, 5] < 0.05  # inside and outside
    with pytest.raises(ShapeError):
        image_edge_map(np.zeros(10))
    assert image_edge_map(np.full((20, 20), 3.0)).max() == 0.0


# ------------------------------------------------------------------------------------------ wireframe
@pytest.mark.parametrize("axis", ["x", "yaw"])
def test_wireframe_score_peaks_at_the_true_pose(city, wire, edge_sim, axis):
    true = view(city, *VIEWS["oblique"])
    emap = edge_sim.simulate(CAMERA, true, "clean", np.random.default_rng(0))
    offsets = np.linspace(-4.0, 4.0, 17)
    if axis == "x":
        poses = Pose.stack([perturbed(true, [d, 0, 0], 0, 0, 0) for d in offsets])
    else:
        poses = Pose.stack([perturbed(true, [0, 0, 0], 0, 0, d) for d in offsets])
    scores = wire.score(CAMERA, emap, poses, prior_local=true)
    assert int(np.argmax(scores)) == 8  # offset 0
    assert scores[8] > 0.9
    assert scores[0] < 0.5 * scores[8] and scores[-1] < 0.5 * scores[8]


@pytest.mark.parametrize("name", list(VIEWS))
def test_wireframe_recovers_true_pose_from_prior_5m_3deg(city, wire, edge_sim, name):
    true = view(city, *VIEWS[name])
    shift = np.array(PRIOR_SHIFTS[name])
    assert np.linalg.norm(shift) == pytest.approx(5.0)
    prior = perturbed(true, shift, 0.5, -0.5, 3.0)
    emap = edge_sim.simulate(CAMERA, true, "clean", np.random.default_rng(1))
    prior_world = city.pose_to_world(prior)  # world frame in and out, converted at the boundary
    result = wire.localize(CAMERA, city.pose_to_local(prior_world), emap)
    assert result.status == LOCALIZED, result.reason
    est = city.pose_to_local(city.pose_to_world(result.pose_local))
    # Measured: nadir 0.72 m / 0.64 deg, oblique 0.47 m / 0.29 deg (the 4D grid cannot fix roll and
    # pitch; Gauss-Newton recovers most of it).
    assert center_error_m(est, true) < 1.0
    assert rotation_error_deg(est, true) < 1.0
    assert center_error_m(est, true) < center_error_m(prior, true) / 4
    assert result.counts["coarse_hypotheses"] == 3 * 8 * 10 * 10 * 30
    assert result.counts["edge_points"] >= wire.config.min_points
    assert result.cost_volume.scores.shape == (10, 10, 30, 8)
    assert result.score > 0.8 and result.confidence["contrast"] > 5
    assert {"prep_s", "coarse_s", "refine_s", "total_s"} <= set(result.timings)


def test_wireframe_refuses_empty_or_structureless_evidence(city, wire):
    true = view(city, *VIEWS["nadir"])
    empty = wire.localize(CAMERA, true, np.zeros((384, 512), np.float32))
    assert (empty.status, empty.reason, empty.pose_local) == (NOT_LOCALIZED, REASON_NO_EDGES, None)
    noise = np.random.default_rng(0).random((384, 512)).astype(np.float32)
    flat = wire.localize(CAMERA, true, noise)
    assert (flat.status, flat.reason, flat.pose_local) == (NOT_LOCALIZED, REASON_LOW_SCORE, None)
    away = perturbed(true, [5000.0, 0.0, 0.0], 0, 0, 0)
    lines = np.zeros((384, 512), np.float32)
    lines[::40] = 1.0
    nothing = wire.localize(CAMERA, away, lines)
    assert (nothing.status, nothing.reason) == (NOT_LOCALIZED, REASON_NO_GEOMETRY)


def test_wireframe_bad_inputs(city, wire):
    true = view(city, *VIEWS["nadir"])
    good = np.zeros((384, 512), np.float32)
    with pytest.raises(ShapeError):
        wire.localize(CAMERA, true, np.zeros((300, 512), np.float32))
    with pytest.raises(ShapeError):
        wire.localize(CAMERA, true, np.zeros((384, 512, 3), np.float32))
    with pytest.raises(ShapeError):
        wire.localize(CAMERA, true, np.zeros((384, 512), dtype=object))
    with pytest.raises(PoseError):
        wire.localize(CAMERA, Pose.stack([true, true]), good)
    with pytest.raises(CameraError):
        wire.localize("camera", true, good)


# ------------------------------------------------------------------------------------------ silhouette
def test_silhouette_merges_building_classes_only():
    labels = np.array([[0, 1, 2, 3], [4, 5, 255, 1]], dtype=np.uint8)
    assert silhouette_labels(labels).tolist() == [[0, 1, BUILDING, BUILDING], [BUILDING, BUILDING, 255, 1]]


@pytest.mark.parametrize("name", list(VIEWS))
def test_silhouette_recovers_true_pose_from_prior_5m_3deg(city, renderer, name):
    true = view(city, *VIEWS[name])
    prior = perturbed(true, np.array(PRIOR_SHIFTS[name]), 0.5, -0.5, 3.0)
    labels = renderer.render(CAMERA, true).labels[0]
    loc = SilhouetteLocalizer(city, LocalizerConfig.preset("default"), scene=renderer.scene)
    assert loc.scene.classes.max() == BUILDING and loc.class_on.tolist() == [0, 0, 1, 0, 0, 0]
    result = loc.localize(CAMERA, prior, labels, depth=np.ones((384, 512)))
    assert result.status == LOCALIZED, result.reason
    # Measured: nadir 0.12 m / 0.10 deg, oblique 0.02-0.09 m / 0.03-0.04 deg.
    assert center_error_m(result.pose_local, true) < 0.5
    assert rotation_error_deg(result.pose_local, true) < 0.5
    assert np.isnan(result.depth_cost) or result.depth_cost == 0.0  # depth is never used
    with pytest.raises(ShapeError):
        loc.localize(CAMERA, prior, labels[:100])


# ------------------------------------------------------------------------------------------ benchmark
def test_baseline_methods_localize_a_benchmark_query(city):
    true = view(city, *VIEWS["oblique"])
    labels = Renderer(city, engine="numba").render(CAMERA, true).labels[0].copy()
    labels[:40, :60] = 0  # a "tree"
    q = SimpleNamespace(
        index=3,
        camera=CAMERA,
        true_pose_local=true,
        prior_pose_local=perturbed(true, [-4.0, 0.0, 3.0], 0.5, -0.5, 3.0),
        labels=labels,
        depth=None,
        meta={"seg_quality": "trained"},
    )
    config = LocalizerConfig.preset("fast")
    wire_method = make_baseline_method("lodloc-wireframe", city, config)
    assert wire_method.quality_for(q) == "trained"
    assert np.array_equal(wire_method.edge_map(q), wire_method.edge_map(q))  # seeded from the query index
    # The "tree" (background labels) hides the model edges under it: compare clean maps with and without.
    clean_q = SimpleNamespace(**{**vars(q), "meta": {"seg_quality": "perfect"}})
    assert wire_method.quality_for(clean_q) == "clean"
    no_tree = SimpleNamespace(**{**vars(clean_q), "labels": np.full_like(labels, SemanticClass.GROUND)})
    assert wire_method.edge_map(no_tree)[:34, :54].max() > 0.9
    assert wire_method.edge_map(clean_q)[:34, :54].max() == 0.0
    for name in ("lodloc-wireframe", "silhouette"):
        method = wire_method if name == "lodloc-wireframe" else make_baseline_method(name, city, config)
        assert method.name == name
        result = method.localize(q)
        assert result.status == LOCALIZED, (name, result.reason)
        assert center_error_m(result.pose_local, true) < 2.0
    with pytest.raises(ParameterError):
        make_baseline_method("lodloc", city, config)

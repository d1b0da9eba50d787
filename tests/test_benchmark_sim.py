"""The benchmark's query simulation: poses, reality scene, perception noise, priors, determinism."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from semcityloc.benchmark.perception_sim import (
    SEG_PRESETS,
    miou,
    simulate_depth,
    simulate_segmentation,
)
from semcityloc.benchmark.queries import (
    QueryConfig,
    QuerySimulator,
    sample_prior,
    view_kind,
    zenmuse_l2_camera,
)
from semcityloc.benchmark.reality import RealityParams, build_reality
from semcityloc.citymodel.citygml import read_citygml
from semcityloc.citymodel.generator import generate_city
from semcityloc.classes import IGNORE, SemanticClass
from semcityloc.errors import BenchmarkConfigError, PerceptionSimError, ShapeError
from semcityloc.geometry.pose import Pose

N_QUERIES = 24


@pytest.fixture(scope="session")
def city(tmp_path_factory):
    paths = generate_city(tmp_path_factory.mktemp("benchmark_city"), seed=0, lods=(2,))
    return read_citygml(paths[2])


@pytest.fixture(scope="session")
def sim(city):
    return QuerySimulator(city, QueryConfig(queries=N_QUERIES, seed=0))


@pytest.fixture(scope="session")
def views(sim):
    return [sim.query_with_truth(i) for i in range(N_QUERIES)]


def _same_query(a, b) -> None:
    np.testing.assert_array_equal(a.labels, b.labels)
    np.testing.assert_array_equal(a.depth, b.depth)  # NaN == NaN for assert_array_equal
    np.testing.assert_array_equal(a.true_pose_local.R, b.true_pose_local.R)
    np.testing.assert_array_equal(a.true_pose_local.t, b.true_pose_local.t)
    np.testing.assert_array_equal(a.prior_pose_local.R, b.prior_pose_local.R)
    np.testing.assert_array_equal(a.prior_pose_local.t, b.prior_pose_local.t)
    assert a.query_miou == b.query_miou
    assert a.meta == b.meta
    assert a.query_id == b.query_id


# ------------------------------------------------------------------------------------------ camera, config
def test_camera_is_the_zenmuse_l2_scaled_to_the_working_width():
    full = zenmuse_l2_camera(5280, 3956)
    assert full.fx == pytest.approx(3750.9, abs=0.1)
    cam = zenmuse_l2_camera(512, 384)
    assert cam.fx == cam.fy == pytest.approx(363.7, abs=0.1)
    assert (cam.cx, cam.cy) == (256.0, 192.0)
    assert cam.hfov_deg == pytest.approx(70.3, abs=0.1)


def test_config_rejects_bad_values_and_normalises_pairs():
    cfg = QueryConfig(height_range_m=[40, 150], prior_extra_m=[10, 20])
    assert cfg.height_range_m == (40.0, 150.0) and cfg.prior_extra_m == (10.0, 20.0)
    for bad in (
        {"seg_quality": "great"},
        {"nominal_height_m": 200.0},
        {"height_range_m": (150.0, 40.0)},
        {"oblique_fraction": 1.5},
        {"oblique_pitch_deg": (30.0, 95.0)},
        {"width": 0},
        {"queries": 2.5},
        {"prior_extra_m": (-1.0, 5.0)},
        {"focal_mm": float("nan")},
    ):
        with pytest.raises(BenchmarkConfigError):
            QueryConfig(**bad)


def test_query_index_must_be_a_non_negative_integer(sim):
    for bad in (-1, 1.0, "3"):
        with pytest.raises(BenchmarkConfigError):
            sim.query(bad)


# ------------------------------------------------------------------------------------------ determinism
def test_same_seed_and_index_give_identical_queries_in_any_order(city, sim, views):
    again = QuerySimulator(city, QueryConfig(queries=N_QUERIES, seed=0))
    late = again.query(5)  # asked out of order, after nothing else
    _same_query(late, views[5].query)
    _same_query(again.query(3), views[3].query)
    _same_query(sim.query(3), views[3].query)


def test_different_index_or_seed_gives_a_different_query(city, views):
    a, b = views[0].query, views[1].query
    assert not np.allclose(a.true_pose_local.center, b.true_pose_local.center)
    assert a.labels.shape == b.labels.shape and not np.array_equal(a.labels, b.labels)
    other = QuerySimulator(city, QueryConfig(queries=2, seed=1)).query(0)
    assert not np.allclose(other.true_pose_local.center, a.true_pose_local.center)


def test_changing_only_the_segmentation_quality_keeps_pose_prior_and_depth(city, views):
    sim = QuerySimulator(city, QueryConfig(queries=N_QUERIES, seed=0, seg_quality="zero-shot"))
    q, ref = sim.query(2), views[2].query
    np.testing.assert_array_equal(q.true_pose_local.t, ref.true_pose_local.t)
    np.testing.assert_array_equal(q.prior_pose_local.t, ref.prior_pose_local.t)
    np.testing.assert_array_equal(q.depth, ref.depth)
    assert q.query_miou < ref.query_miou


def test_a_focal_error_changes_only_the_camera_the_localizer_is_told_of(city, views):
    sim = QuerySimulator(city, QueryConfig(queries=N_QUERIES, seed=0, focal_error=-0.024))
    q, ref = sim.query(2), views[2].query
    _same_query(q, ref)  # rendered with the true camera: the same image, truth and prior
    assert q.camera.fx == pytest.approx(0.976 * ref.camera.fx) and q.camera.fy == pytest.approx(
        0.976 * ref.camera.fy
    )
    assert (q.camera.cx, q.camera.cy, q.camera.width) == (ref.camera.cx, ref.camera.cy, ref.camera.width)
    for bad in (0.5, -0.7, float("nan")):
        with pytest.raises(BenchmarkConfigError, match="focal_error"):
            QueryConfig(focal_error=bad)


def test_a_lens_distorts_the_query_and_a_stated_lens_undoes_it(city, views):
    ref = views[2].query
    told = QuerySimulator(city, QueryConfig(queries=N_QUERIES, seed=0, lens_k1=-0.1)).query(2)
    untold = QuerySimulator(city, QueryConfig(queries=N_QUERIES, seed=0, lens_k1=-0.1, lens_stated=False))
    untold = untold.query(2)
    for q in (told, untold):
        np.testing.assert_array_equal(q.true_pose_local.t, ref.true_pose_local.t)
        np.testing.assert_array_equal(q.prior_pose_local.t, ref.prior_pose_local.t)
        assert q.camera == ref.camera and q.query_miou == ref.query_miou  # the masks' own quality
    assert (told.labels != IGNORE).all() and (told.labels == ref.labels).mean() > 0.99
    # Barrel: the photo's corners show what lies beyond the query's pinhole image (its wider canvas),
    # not an unknown border, as a real wide photo does.
    assert (untold.labels != IGNORE).all()
    assert np.isnan(untold.depth).mean() <= np.isnan(ref.depth).mean() + 0.001
    assert (untold.labels == ref.labels).mean() < (told.labels == ref.labels).mean() - 0.05
    assert np.nanmax(np.abs(told.depth - ref.depth)) > 0  # resampled
    sim = QuerySimulator(city, QueryConfig(queries=N_QUERIES, seed=0, lens_k1=-0.1, lens_stated=False))
    assert sim.canvas.width > sim.camera.width and sim.canvas.height > sim.camera.height
    pincushion = QuerySimulator(city, QueryConfig(queries=N_QUERIES, seed=0, lens_k1=0.05))
    assert pincushion.canvas == pincushion.camera  # nothing beyond the pinhole image to show
    # -0.2 alone folds over before the corners of a 70 deg camera: no ray reaches them.
    for bad in ({"lens_k1": -0.2}, {"lens_k1": float("nan")}, {"lens_stated": "maybe"}):
        with pytest.raises(BenchmarkConfigError, match=next(iter(bad))):
            QueryConfig(**bad)


# ------------------------------------------------------------------------------------------ poses, views
def test_queries_cover_buildings_and_follow_the_pose_distribution(sim, views):
    cfg = sim.config
    assert [q.query_id for q in itertools.islice(sim, 2)] == ["q0000", "q0001"]
    assert len(sim) == N_QUERIES
    for i, v in enumerate(views):
        q, m = v.query, v.query.meta
        assert q.index == i and q.query_id == f"q{i:04d}"
        assert q.labels.shape == (cfg.height, cfg.width) and q.labels.dtype == np.uint8
        assert q.depth.shape == (cfg.height, cfg.width) and q.depth.dtype == np.float32
        assert m["accepted"]
        coverage = np.isin(v.clean_labels, [2, 3, 4, 5]).mean()
        assert coverage >= cfg.min_building_fraction and coverage == pytest.approx(m["coverage"])
        x, y, z, roll, pitch, yaw = q.true_pose_local.to_xyz_rpy()
        assert abs(roll) <= cfg.max_roll_deg + 1e-6
        if m["view"] == "oblique":
            assert cfg.oblique_pitch_deg[0] - 1e-6 <= pitch <= cfg.oblique_pitch_deg[1] + 1e-6
        else:
            assert abs(pitch) <= 3.0 + 1e-6
        ground = float(sim.reality.terrain_height(np.array([x, y])))
        assert z - ground == pytest.approx(m["height_m"], abs=1e-6)
        assert cfg.height_range_m[0] <= m["height_m"] <= cfg.height_range_m[1]
        assert np.nanmin(v.true_depth) >= 10.0  # the clearance the simulator enforces
    n_oblique = sum(v.query.meta["view"] == "oblique" for v in views)
    assert abs(n_oblique - cfg.oblique_fraction * N_QUERIES) <= 2
    # the view sequence keeps its fraction over any run of indices, for any seed and fraction
    for seed, frac in ((0, 0.5), (3, 0.25), (7, 0.8)):
        n = sum(view_kind(seed, i, frac) == "oblique" for i in range(100, 300))
        assert abs(n - 200 * frac) <= 3
    assert all(view_kind(0, i, 0.0) == "nadir" for i in range(20))


def test_a_camera_inside_or_under_a_building_is_detected(city, sim):
    roof = city.vertices[city.triangles[city.classes == SemanticClass.ROOF]].astype(np.float64)
    tri = roof[np.argmax(roof[:, :, 2].min(1))]  # a triangle of the highest roof
    centre = tri.mean(0)
    below = Pose.from_xyz_rpy(centre - [0.0, 0.0, 3.0], 0.0, 0.0, 0.0)
    above = Pose.from_xyz_rpy(centre + [0.0, 0.0, 60.0], 0.0, 0.0, 0.0)
    assert sim._blocked_above(below) and not sim._blocked_above(above)


def test_occluders_are_background_with_depth_in_the_clean_labels(sim, views):
    counts = sim.reality.counts
    assert counts["trees"] > 0 and counts["cars"] > 0 and counts["roof_structures"] > 0
    occluded = [((v.clean_labels == 0) & np.isfinite(v.true_depth)).mean() for v in views]
    assert max(occluded) > 0.01
    assert all(
        o == pytest.approx(v.query.meta["occluder_fraction"]) for o, v in zip(occluded, views, strict=True)
    )


def test_reality_differs_from_the_map_within_the_documented_magnitudes(city, sim):
    r = sim.reality
    assert np.linalg.norm(r.building_shift_xy, axis=1).max() <= 0.3 + 1e-12
    assert np.abs(r.building_height_change).max() <= 0.5 + 1e-12
    assert np.linalg.norm(r.building_shift_xy, axis=1).max() > 0.1
    model = r.model
    bg = model.classes == SemanticClass.BACKGROUND
    assert bg.sum() == r.counts["occluder_triangles"]
    # roof structures: ROOF tops and WALL sides that belong to real buildings (not the occluder ids)
    n_real = len(city.building_ids)
    extra = (model.lods == 0) & ~bg & (model.building_index < n_real)
    assert set(np.unique(model.classes[extra])) == {SemanticClass.WALL, SemanticClass.ROOF}


def test_reality_of_a_model_with_another_origin_lands_in_the_map_frame(city):
    params = RealityParams(tree_m2=0, car_m2=0, roof_structure_m2=0)
    ref = build_reality(city, None, seed=4, params=params)
    offset = np.array([100.0, -50.0, 0.0])
    moved = dataclasses.replace(
        city,
        origin=city.origin + offset,
        vertices=(city.vertices.astype(np.float64) - offset).astype(np.float32),
    )
    out = build_reality(city, moved, seed=4, params=params)
    assert out.counts == ref.counts
    np.testing.assert_allclose(out.model.vertices, ref.model.vertices, atol=1e-3)
    np.testing.assert_array_equal(out.model.origin, city.origin)


# ------------------------------------------------------------------------------------------ priors
def test_prior_errors_stay_in_the_configured_bounds():
    pose = Pose.from_xyz_rpy(np.array([10.0, 20.0, 80.0]), 1.0, 40.0, 30.0)
    for extra in (None, (20.0, 30.0), (150.0, 200.0)):
        cfg = QueryConfig(prior_extra_m=extra)
        for i in range(200):
            prior, info = sample_prior(
                pose, cfg, np.random.default_rng([0, i, 1]), np.random.default_rng([0, i, 2])
            )
            assert 5.0 - 1e-9 <= info["prior_base_err_m"] <= 15.0 + 1e-9
            ex = np.abs(info["prior_extra_xyz"])
            if extra is None:
                assert not ex.any()
            else:
                assert np.all((ex >= extra[0] - 1e-9) & (ex <= extra[1] + 1e-9))
            err = prior.center - pose.center
            np.testing.assert_allclose(err, info["prior_err_xyz"], atol=1e-9)
            base = err - np.asarray(info["prior_extra_xyz"])
            assert abs(base[2]) <= 0.4 * 15.0 + 1e-9  # mostly horizontal
            assert abs(info["prior_yaw_err_deg"]) <= 8.0 and abs(info["prior_roll_err_deg"]) <= 1.0
            d = prior.to_xyz_rpy()[3:] - pose.to_xyz_rpy()[3:]
            np.testing.assert_allclose(
                d,
                [info["prior_roll_err_deg"], info["prior_pitch_err_deg"], info["prior_yaw_err_deg"]],
                atol=1e-6,
            )


def test_query_priors_match_their_meta(views):
    for v in views:
        q = v.query
        err = q.prior_pose_local.center - q.true_pose_local.center
        assert np.linalg.norm(err) == pytest.approx(q.meta["prior_err_m"])
        assert 5.0 - 1e-9 <= np.linalg.norm(err) <= 15.0 + 1e-9


# ------------------------------------------------------------------------------------------ perception
def test_segmentation_presets_are_ordered_and_trained_is_near_88(views):
    means = {}
    for name in ("perfect", "trained", "medium", "zero-shot"):
        vals = [
            miou(simulate_segmentation(v.clean_labels, name, np.random.default_rng([9, i])), v.clean_labels)
            for i, v in enumerate(views)
        ]
        means[name] = float(np.mean(vals))
    assert means["perfect"] == 100.0
    assert means["perfect"] > means["trained"] > means["medium"] > means["zero-shot"]
    assert abs(means["trained"] - 88.0) <= 5.0
    assert abs(means["medium"] - 78.0) <= 6.0
    assert 25.0 <= means["zero-shot"] <= 45.0
    assert np.mean([v.query.query_miou for v in views]) == pytest.approx(means["trained"], abs=3.0)


def test_segmentation_keeps_most_openings_when_trained():
    clean = np.full((96, 128), SemanticClass.WALL, dtype=np.uint8)
    clean[70:] = SemanticClass.GROUND
    for r in range(8, 60, 10):
        for c in range(6, 120, 10):
            clean[r : r + 7, c : c + 6] = SemanticClass.WINDOW
    clean[60:70, 60:65] = SemanticClass.DOOR

    def window_iou(pred):
        g, p = clean == SemanticClass.WINDOW, pred == SemanticClass.WINDOW
        return (g & p).sum() / (g | p).sum()

    trained = np.mean(
        [window_iou(simulate_segmentation(clean, "trained", np.random.default_rng(s))) for s in range(10)]
    )
    zero = np.mean(
        [window_iou(simulate_segmentation(clean, "zero-shot", np.random.default_rng(s))) for s in range(10)]
    )
    assert trained > 0.75 and zero < trained


def test_segmentation_is_seeded_and_checks_its_input():
    rng = np.random.default_rng(0)
    clean = rng.integers(0, 4, (48, 64)).astype(np.uint8)
    a = simulate_segmentation(clean, "medium", np.random.default_rng(5))
    b = simulate_segmentation(clean, SEG_PRESETS["medium"], np.random.default_rng(5))
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(simulate_segmentation(clean, "perfect", rng), clean)
    with pytest.raises(PerceptionSimError):
        simulate_segmentation(clean, "excellent", rng)
    with pytest.raises(ShapeError):
        simulate_segmentation(clean.astype(np.float32), "trained", rng)
    with pytest.raises(ShapeError):
        simulate_segmentation(clean + 10, "trained", rng)


def test_miou_counts_classes_present_in_the_ground_truth():
    gt = np.full((20, 20), SemanticClass.GROUND, dtype=np.uint8)
    gt[:, 10:] = SemanticClass.ROOF
    assert miou(gt, gt) == 100.0
    pred = gt.copy()
    pred[:, 10:15] = SemanticClass.BACKGROUND  # half the roof missed
    assert miou(pred, gt, min_pixels=1) == pytest.approx(100 * (1.0 + 0.5) / 2)
    pred[:5, :5] = SemanticClass.WALL  # wall is not in gt: it only costs ground
    assert miou(pred, gt, min_pixels=1) == pytest.approx(100 * (175 / 200 + 0.5) / 2)
    assert math.isnan(miou(np.zeros((4, 4), np.uint8), np.zeros((4, 4), np.uint8)))


def test_depth_is_an_affine_noisy_copy_with_nan_exactly_where_nothing_was_hit(views):
    for v in views[:6]:
        d, truth = v.query.depth, v.true_depth.astype(np.float64)
        np.testing.assert_array_equal(np.isnan(d), ~np.isfinite(truth))
        ok = np.isfinite(truth)
        assert np.all(d[ok] > 0)
        A = np.column_stack([d[ok].astype(np.float64), np.ones(ok.sum())])
        (s, t), *_ = np.linalg.lstsq(A, truth[ok], rcond=None)
        rel = np.abs(s * d[ok] + t - truth[ok]) / truth[ok]
        assert s > 0
        assert 1e-3 < np.median(rel) < 0.05
    # an image with sky: NaN there, and the simulation is seeded
    depth = np.full((40, 50), np.inf, dtype=np.float32)
    depth[10:, :] = np.linspace(50, 120, 30)[:, None]
    labels = np.where(np.isfinite(depth), SemanticClass.GROUND, 0).astype(np.uint8)
    a = simulate_depth(depth, labels, np.random.default_rng(1))
    np.testing.assert_array_equal(np.isnan(a), ~np.isfinite(depth))
    np.testing.assert_array_equal(a, simulate_depth(depth, labels, np.random.default_rng(1)))
    with pytest.raises(ShapeError):
        simulate_depth(depth, labels[:10], np.random.default_rng(1))


# ------------------------------------------------------------------------------------------ real data
def test_berlin_queries_are_simulated_over_the_real_city(shared):
    model = read_citygml(shared("berlin_lod2_citygml2/3910_5817.gml"))
    sim = QuerySimulator(model, QueryConfig(queries=3, seed=0))
    assert sim.reality.counts["trees"] > 100 and sim.reality.counts["roof_structures"] > 100
    for q in sim:
        assert q.meta["accepted"] and q.meta["coverage"] >= 0.15
        assert 60.0 < q.query_miou <= 100.0

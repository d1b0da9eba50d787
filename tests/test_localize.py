"""The localizer on the generated city: recovers true poses, refuses empty or contradicting evidence."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import ndimage

from helpers import CAMERA, perturbed, view
from semcityloc.classes import BUILDING_CLASSES, NUM_CLASSES
from semcityloc.errors import CameraError, ParameterError, PoseError, ShapeError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.errors import center_error_m, rotation_error_deg
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.localization.agreement import boundary_distance_px, building_agreement
from semcityloc.localization.coarse import yaw_lookup
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.covariance import PROBES
from semcityloc.localization.input_checks import check_camera_and_prior
from semcityloc.localization.localize import Localizer
from semcityloc.localization.query import downsample_labels
from semcityloc.localization.result import (
    LOCALIZED,
    NOT_LOCALIZED,
    REASON_NO_BUILDINGS_IN_QUERY,
    REASON_NO_GEOMETRY,
)
from semcityloc.localization.scoring import depth_cost, semantic_score
from semcityloc.render import Renderer


@pytest.fixture(scope="module")
def city(generated_lod2):
    return generated_lod2


@pytest.fixture(scope="module")
def localizer(city):
    return Localizer(city)


@pytest.fixture(scope="module")
def renderer(city):
    return Renderer(city, engine="numba")


# A nadir and an oblique view; priors 10 m and 5 degrees of yaw off (plus 0.5 degrees roll/pitch).
CASES = {
    "nadir": ((10.0, -20.0, 80.0, 1.0, 2.0, 30.0), (6.0, -7.0, 3.873)),
    "oblique": ((-30.0, 15.0, 90.0, -1.0, 40.0, 200.0), (-7.0, 6.0, -3.873)),
}


@pytest.mark.parametrize("name", list(CASES))
def test_recovers_true_pose_from_prior_10m_5deg(city, localizer, renderer, name):
    true_args, shift = CASES[name]
    true = view(city, *true_args)
    assert np.linalg.norm(shift) == pytest.approx(10.0, abs=0.05)
    prior = perturbed(true, np.array(shift), 0.5, -0.5, 5.0)
    out = renderer.render(CAMERA, true, depth=True)
    labels, depth = out.labels[0], out.depth[0]
    relative_depth = 0.37 * depth + 12.0  # any positive scale and shift: only the shape counts
    prior_world = city.pose_to_world(prior)  # a prior as a pose file in the CRS gives it
    result = localizer.localize(CAMERA, city.pose_to_local(prior_world), labels, relative_depth)
    assert result.status == LOCALIZED, result.reason
    est_local = city.pose_to_local(city.pose_to_world(result.pose_local))  # CRS out and back
    assert center_error_m(est_local, true) < 0.5
    assert rotation_error_deg(est_local, true) < 0.5
    assert result.counts["coarse_hypotheses"] >= 10_000
    assert result.counts["refine_evaluations"] >= 1_000
    volume = result.cost_volume  # the sweep's lattice over the default +-15 m, +-30 m, +-9 deg
    assert volume.scores.ndim == 4 and np.ptp(volume.z_values) >= 60.0 and np.ptp(volume.x_values) >= 30.0
    assert set(result.timings) >= {"coarse_s", "refine_s", "total_s"}


def test_is_deterministic_for_a_seed(city, localizer, renderer):
    true = view(city, *CASES["nadir"][0])
    prior = perturbed(true, np.array([4.0, 3.0, 1.0]), 0.0, 0.0, 3.0)
    labels = renderer.render(CAMERA, true).labels[0]
    a = localizer.localize(CAMERA, prior, labels)
    b = localizer.localize(CAMERA, prior, labels)
    np.testing.assert_array_equal(a.pose_local.R, b.pose_local.R)
    np.testing.assert_array_equal(a.pose_local.t, b.pose_local.t)


def test_empty_mask_is_not_localized(city, localizer):
    true = view(city, *CASES["nadir"][0])
    empty = np.zeros((384, 512), dtype=np.uint8)
    result = localizer.localize(CAMERA, true, empty)
    assert result.status == NOT_LOCALIZED and result.reason == REASON_NO_BUILDINGS_IN_QUERY
    assert result.pose_local is None


@pytest.mark.parametrize("with_depth", [True, False])
def test_flipped_mask_is_not_localized(city, localizer, renderer, with_depth):
    true = view(city, *CASES["nadir"][0])
    out = renderer.render(CAMERA, true, depth=True)
    labels, depth = out.labels[0][::-1, ::-1], out.depth[0][::-1, ::-1]  # the image turned upside down
    prior = perturbed(true, np.array([6.0, -7.0, 3.6]), 0.5, -0.5, 5.0)
    result = localizer.localize(
        CAMERA,
        prior,
        np.ascontiguousarray(labels),
        np.ascontiguousarray(depth) if with_depth else None,
    )
    assert result.status == NOT_LOCALIZED, (result.score, result.semantic, result.depth_cost)
    assert result.pose_local is None


def test_a_stated_wide_uncertainty_recovers_a_prior_35m_off_on_every_axis(city, localizer, renderer):
    """35 m per axis is beyond the default volume (+-15 m xy): the default refuses or misses it; stating
    the prior's uncertainty (12 m / 12 m, +-36 m searched) finds it, with no special preset."""
    true = view(city, *CASES["oblique"][0])
    out = renderer.render(CAMERA, true, depth=True)
    prior = perturbed(true, np.array([35.0, -33.0, 31.0]), 0.5, -0.5, 6.0)
    default = localizer.localize(CAMERA, prior, out.labels[0], out.depth[0])
    assert not default.localized or center_error_m(default.pose_local, true) > 5.0  # outside its volume
    wide = PriorUncertainty.parse("xy=12,z=12")
    result = localizer.localize(CAMERA, prior, out.labels[0], out.depth[0], prior_uncertainty=wide)
    assert result.status == LOCALIZED, result.reason
    assert center_error_m(result.pose_local, true) < 1.0
    assert rotation_error_deg(result.pose_local, true) < 1.0


def test_prior_far_outside_the_model_is_not_localized(city, localizer, renderer):
    true = view(city, *CASES["nadir"][0])
    labels = renderer.render(CAMERA, true).labels[0]
    far = perturbed(true, np.array([5000.0, 0.0, 0.0]), 0, 0, 0)
    result = localizer.localize(CAMERA, far, labels)
    assert result.status == NOT_LOCALIZED and result.reason == REASON_NO_GEOMETRY
    # How far, so that a wrong CRS or offset (kilometres) is told from a prior beside a tile's edge
    (said,) = [w for w in result.warnings if w.startswith("the prior lies")]
    metres = float(said.split()[3])
    assert 4700 < metres < 5000 and "kilometres point at a wrong CRS or offset=..." in said


def test_a_prior_near_the_ground_looks_for_buildings_from_the_highest_camera(city, localizer, renderer):
    """A GNSS height far too low (2 m above the ground, 45 m beyond the district's edge) sees a few metres
    around itself; the camera the search may find higher up sees the buildings, so the search runs
    instead of a "no model geometry" refusal."""
    labels = renderer.render(CAMERA, view(city, *CASES["nadir"][0])).labels[0]
    lo, hi = city.bounds_local
    low = Pose.from_xyz_rpy([hi[0] + 45.0, 0.5 * (lo[1] + hi[1]), lo[2] + 2.0], 0.0, 0.0, 0.0)
    result = localizer.localize(CAMERA, low, labels)
    assert result.reason != REASON_NO_GEOMETRY and result.counts["coarse_hypotheses"] > 0
    narrow = localizer.localize(CAMERA, low, labels, prior_uncertainty=PriorUncertainty.parse("z=0.5"))
    assert narrow.reason == REASON_NO_GEOMETRY  # a camera held near the ground there sees none


@pytest.mark.parametrize("size", [(512, 384), (640, 360), (384, 512), (1200, 300), (640, 512)])
def test_each_search_level_scores_as_many_pixels_whatever_the_aspect(localizer, size):
    """A level's width x height is a pixel budget: a 16:9 or portrait camera is not scored on a thinner or
    taller strip than the 4:3 views the search was tuned on (exact for 4:3)."""
    camera = Camera.from_fov(*size, 70.0)
    fine = localizer.fine_camera(camera)
    assert abs(fine.width * fine.height / (128 * 96) - 1) < 0.03
    assert fine.width / fine.height == pytest.approx(size[0] / size[1], rel=0.03)
    if size == (512, 384):
        assert (fine.width, fine.height) == (128, 96)


def test_ablation_switches(city, localizer, renderer):
    true = view(city, *CASES["oblique"][0])
    prior = perturbed(true, np.array([3.0, -2.0, 1.0]), 0, 0, 2.0)
    out = renderer.render(CAMERA, true, depth=True)
    base = LocalizerConfig.preset("fast")
    no_refine = localizer.localize(
        CAMERA,
        prior,
        out.labels[0],
        out.depth[0],
        config=base.with_ablation("no-refine"),
    )
    assert no_refine.counts["refine_evaluations"] == 0 and no_refine.cost_volume is not None
    no_coarse = localizer.localize(
        CAMERA,
        prior,
        out.labels[0],
        out.depth[0],
        config=base.with_ablation("no-coarse"),
    )
    assert no_coarse.counts["coarse_hypotheses"] == 0 and no_coarse.cost_volume is None
    assert no_coarse.counts["refine_evaluations"] > 0
    no_depth = localizer.localize(
        CAMERA, prior, out.labels[0], out.depth[0], config=base.with_ablation("no-depth")
    )
    assert no_depth.depth_cost == 0.0
    with pytest.raises(ParameterError, match="unknown method 'no-such-method'; known: semcityloc, no-coarse"):
        base.with_ablation("no-such-method")


def test_unknown_preset_is_a_parameter_error_naming_the_presets():
    with pytest.raises(ParameterError, match=r"^unknown localizer preset 'typo'; known: default, legacy, "):
        LocalizerConfig.preset("typo")


def test_bad_inputs_raise_typed_errors(city, localizer):
    pose = view(city, *CASES["nadir"][0])
    with pytest.raises(ShapeError):
        localizer.localize(CAMERA, pose, np.zeros((10, 10), dtype=np.uint8))
    with pytest.raises(ShapeError):
        localizer.localize(CAMERA, pose, np.zeros((384, 512, 3), dtype=np.uint8))
    with pytest.raises(PoseError):
        localizer.localize(CAMERA, Pose.stack([pose, pose]), np.zeros((384, 512), np.uint8))


def test_a_world_prior_is_refused_as_the_renderer_refuses_a_world_pose(city, localizer):
    """Stop 56's audit: a prior in world (CRS) coordinates searched an empty volume and came back as a
    miss ("no model geometry within the search volume"); the renderer's hint names model.pose_to_local."""
    pose = view(city, *CASES["nadir"][0])
    world = pose.shift_world(-np.array([690_000.0, 5_336_000.0, 0.0]))  # a UTM origin added
    mask = np.full((384, 512), 3, dtype=np.uint8)
    with pytest.raises(PoseError, match=r"prior must be in the model's local frame: .*model\.pose_to_local"):
        localizer.localize(CAMERA, world, mask)
    with pytest.raises(PoseError, match="pose_to_local"):
        check_camera_and_prior(CAMERA, world)  # the baselines' check too


def test_api_inputs_the_cli_refuses_are_refused_by_the_api_too(city, localizer):
    """Stop 45's audit: the Python API took what the CLI refuses, and failed deep inside or silently."""
    pose = view(city, *CASES["nadir"][0])
    good = np.full((384, 512), 3, dtype=np.uint8)
    with pytest.raises(ShapeError, match="invalid class ids 7 in"):
        localizer.localize(CAMERA, pose, np.full((384, 512), 7))  # a head's own numbering: not "nothing"
    with pytest.raises(ShapeError, match="invalid class ids -1"):
        localizer.localize(CAMERA, pose, np.full((384, 512), -1))
    with pytest.raises(ShapeError, match="real numbers"):
        localizer.localize(CAMERA, pose, good, depth=np.ones((384, 512), dtype=np.complex64))
    with pytest.raises(ParameterError, match="LocalizerConfig or a preset name"):
        localizer.localize(CAMERA, pose, good, config=42)
    with pytest.raises(ParameterError, match="unknown localizer preset"):
        localizer.localize(CAMERA, pose, good, config="typo")
    with pytest.raises(ParameterError, match="must be a CityModel"):
        Localizer(None)
    for seed in (-1, 1.5, "a", True):
        with pytest.raises(ParameterError, match="seed must be a whole number"):
            LocalizerConfig(seed=seed)
    assert LocalizerConfig(seed=np.int64(3)).seed == 3


@pytest.mark.parametrize(
    "intrinsics, message",
    [
        ((364.0, 364.0, 5000.0, 192.0), "principal point"),  # the audit's MemoryError in the kernel
        ((364.0, 364.0, 256.0, -1.0), "principal point"),
        ((1e9, 1e9, 256.0, 192.0), "field of view"),  # a focal length 10^7 times too long: all RAM before
        ((1e300, 1e300, 256.0, 192.0), "field of view"),  # OverflowError before
        ((10.0, 10.0, 256.0, 192.0), "field of view"),  # 175 deg across
    ],
)
def test_intrinsics_no_photo_has_are_refused_before_the_search(city, localizer, intrinsics, message):
    pose = view(city, *CASES["nadir"][0])
    camera = Camera(*intrinsics, 512, 384)
    with pytest.raises(CameraError, match=message):
        localizer.localize(camera, pose, np.full((384, 512), 3, dtype=np.uint8))


def test_wide_view_of_extreme_rotations_is_refused_not_allocated():
    """A 1 deg zoom searched over +-180 deg of yaw would need a wide view of 10^8 pixels: a typed error
    naming the fix, where it exhausted the memory; a 70 deg camera over +-9 deg stays a few thousand."""
    zoom = Camera(1833.0, 1833.0, 16.0, 12.0, 32, 24)  # 1 deg across (from_fov refuses it as radians)
    tilt = Pose.from_xyz_rpy(np.zeros(3), 0.0, 45.0, 0.0).R
    with pytest.raises(CameraError, match="smaller yaw"):
        yaw_lookup(zoom, tilt, np.linspace(-180, 180, 91))
    wide, lut = yaw_lookup(Camera.from_fov(32, 24, 70.0), tilt, np.linspace(-9, 9, 11))
    assert wide.width * wide.height < 5_000 and (lut >= 0).mean() > 0.99


@pytest.mark.parametrize("preset", ["legacy", "default"])
def test_fused_coarse_kernel_matches_direct_rendering(city, localizer, renderer, preset):
    """Every (centre, yaw) score of the cost volume (the first design's grid; the cascade's sweep)
    equals the IoU of a direct render, to within the few pixels where the lookup differs from it."""
    true = view(city, *CASES["oblique"][0])
    labels = renderer.render(CAMERA, true).labels[0]
    cfg = replace(LocalizerConfig.preset(preset), no_refine=True)
    result = localizer.localize(CAMERA, true, labels, config=cfg)
    volume = result.cost_volume
    width = cfg.coarse.width if cfg.search == "grid" else cfg.cascade.sweep.width
    coarse_cam = CAMERA.scaled(width, width * 3 // 4)
    from semcityloc.localization.query import Query

    q = Query.from_arrays(labels, None, has_openings=False).at(coarse_cam.width, coarse_cam.height)[0]
    rng = np.random.default_rng(0)
    diffs = []
    for _ in range(12):
        idx = tuple(rng.integers(0, s) for s in volume.scores.shape)
        x, y, z, roll, pitch, yaw = volume.xyz_rpy(np.array(idx))
        direct = renderer.render(coarse_cam, Pose.from_xyz_rpy([x, y, z], roll, pitch, yaw)).labels[0]
        diffs.append(abs(semantic_score(direct, q.reshape(direct.shape), (1, 2, 3)) - volume.scores[idx]))
    assert np.median(diffs) < 0.02 and max(diffs) < 0.08


def test_yaw_lookup_agrees_with_direct_renders(city, renderer):
    cam = CAMERA.scaled(64, 48)
    base = view(city, *CASES["oblique"][0])
    yaws = np.linspace(-9, 9, 13)
    wide, lut = yaw_lookup(cam, base.R, yaws, oversample=2.0)
    wide_labels = renderer.render(wide, base).labels[0].reshape(-1)
    agreement = []
    for k, d in enumerate(yaws):
        direct = renderer.render(cam, base.rotate_world_z(d)).labels[0].reshape(-1)
        looked_up = np.where(lut[k] >= 0, wide_labels[np.maximum(lut[k], 0)], 0)
        agreement.append(np.mean(direct == looked_up))
    assert np.mean(agreement) >= 0.97


def test_depth_cost_is_invariant_to_scale_and_shift():
    rng = np.random.default_rng(3)
    d_r = rng.uniform(40, 120, size=(48, 64))
    noisy = d_r * (1 + 0.01 * rng.normal(size=d_r.shape))
    base = depth_cost(noisy, d_r)
    for s, t in [(0.01, 0.0), (3.0, -50.0), (1e3, 7.0)]:
        assert depth_cost(s * noisy + t, d_r) == pytest.approx(base, rel=1e-6)
    assert depth_cost(-noisy, d_r) == 1.0  # inverted depth is the worst cost
    assert depth_cost(d_r, d_r) == pytest.approx(0.0, abs=1e-9)


def test_depth_cost_is_minimal_at_the_true_pose_along_a_sweep(city, renderer):
    true = view(city, *CASES["oblique"][0])
    cam = CAMERA.scaled(128, 96)
    d_q = 2.0 * renderer.render(cam, true, depth=True).depth[0] + 3.0
    offsets = np.linspace(-4, 4, 17)
    costs = []
    for dx in offsets:
        d_r = renderer.render(cam, perturbed(true, np.array([dx, 0.0, 0.0]), 0, 0, 0), depth=True).depth[0]
        costs.append(depth_cost(d_q, d_r))
    assert offsets[int(np.argmin(costs))] == 0.0
    assert costs[0] > costs[8] and costs[-1] > costs[8]


def test_result_to_dict_writes_the_world_pose_in_the_pose_json_layout():
    from semcityloc.geometry.io import pose_to_dict
    from semcityloc.localization.result import LocalizationResult

    origin = np.array([690190.0, 5336158.0, 12.5])
    local = Pose.from_xyz_rpy(np.array([11.5, -9.0, 85.25]), 1.0, 35.0, 120.0)
    done = LocalizationResult(status=LOCALIZED, pose_local=local, score=0.9, counts={"coarse_hypotheses": 3})
    d = done.to_dict(origin, "EPSG:25832")
    assert (d["status"], d["score"], d["counts"]) == (LOCALIZED, 0.9, {"coarse_hypotheses": 3})
    pose = pose_to_dict(pose_local=local, origin_world=origin, crs="EPSG:25832")
    assert {k: d[k] for k in pose} == pose  # the one pose layout, in CRS coordinates
    np.testing.assert_allclose(d["position"], local.center + origin, rtol=0, atol=1e-9)
    assert d["frame"] == "crs" and d["crs"] == "EPSG:25832"
    assert done.to_dict(origin)["crs"] is None  # the key is there without a CRS too
    refused = LocalizationResult(status=NOT_LOCALIZED, reason=REASON_NO_GEOMETRY).to_dict(origin)
    assert refused["status"] == NOT_LOCALIZED and refused["reason"] == REASON_NO_GEOMETRY
    assert not {"position", "world_from_cam", "frame"} & set(refused)


def test_polish_estimate_is_the_mean_of_the_best_evaluations_with_angles_wrapped():
    from semcityloc.localization.refine import top_mean

    states = np.array(
        [
            [1.0, 2.0, 3.0, 0.0, 0.0, 179.8],
            [3.0, 2.0, 3.0, 0.2, 0.0, -179.8],  # 0.4 deg from the first across +-180
            [100.0, 0.0, 0.0, 0.0, 0.0, 0.0],  # the worst: left out
        ]
    )
    est = top_mean(states, np.array([0.9, 0.8, 0.1]), 2)
    assert est[:3] == pytest.approx([2.0, 2.0, 3.0])
    assert est[3] == pytest.approx(0.1) and est[5] == pytest.approx(180.0)  # not 0, the naive mean
    assert top_mean(states, np.array([0.9, 0.8, 0.1]), 1) == pytest.approx(states[0])


def test_polish_estimate_is_switchable_and_accurate(city, localizer, renderer):
    """``polish_estimate_top`` (default) returns the mean of the polish's best evaluations, 0 the single
    best one: different poses, both on the true one."""
    truth = view(city, *CASES["nadir"][0])
    out = renderer.render(CAMERA, truth, depth=True)
    labels, depth = out.labels[0], 0.37 * out.depth[0] + 12.0
    prior = perturbed(truth, np.array(CASES["nadir"][1]), 0.5, -0.5, 5.0)
    best_one = replace(localizer.config, refine=replace(localizer.config.refine, polish_estimate_top=0))
    a = localizer.localize(CAMERA, prior, labels, depth, config=best_one)
    b = localizer.localize(CAMERA, prior, labels, depth)
    assert b.pose_local is not None and a.pose_local is not None
    assert center_error_m(b.pose_local, truth) < 0.5 and rotation_error_deg(b.pose_local, truth) < 0.5
    assert center_error_m(a.pose_local, truth) < 0.5
    assert not np.allclose(a.pose_local.to_xyz_rpy(), b.pose_local.to_xyz_rpy())


def test_restarts_keep_the_best_scoring_run(city, localizer, renderer):
    """``refine.restarts``: its first run is the single run of the default, so the kept result scores at
    least as high, and every run's evaluations are counted (and the covariance's probe once); fewer than
    one run is refused."""
    truth = view(city, *CASES["nadir"][0])
    labels = renderer.render(CAMERA, truth).labels[0]
    prior = perturbed(truth, np.array(CASES["nadir"][1]), 1.0, -1.0, 5.0)
    cfg = localizer.config
    no_lookalike = replace(cfg.cascade, lookalike=replace(cfg.cascade.lookalike, enabled=False))
    # no second look and no look-alike's refinement: the runs' counts alone
    single = replace(cfg, map_eaves_flat_roofs="off", cascade=no_lookalike)
    one = localizer.localize(CAMERA, prior, labels, config=single)
    config = replace(single, refine=replace(single.refine, restarts=3))
    three = localizer.localize(CAMERA, prior, labels, config=config)
    assert three.score >= one.score
    per_run = one.counts["refine_evaluations"] - PROBES  # the covariance's probe runs once, after the runs
    assert three.counts["refine_evaluations"] == 3 * per_run + PROBES
    assert three.counts["coarse_hypotheses"] == one.counts["coarse_hypotheses"]
    assert center_error_m(three.pose_local, truth) < 0.5
    with pytest.raises(ParameterError, match="restarts"):
        replace(localizer.config.refine, restarts=0)


def test_score_poses_ranks_the_true_pose_first_and_includes_the_prior_term(city, renderer):
    """The refinement's own score of given poses: the true pose of a clean view scores highest; the prior's
    roll/pitch term lowers a pose tilted away from the prior. The query is the map's own render, so the
    localizer searches the map as it is (no eaves: ``map_eaves_m=0``)."""
    localizer = Localizer(city, LocalizerConfig(map_eaves_m=0.0))
    truth = view(city, *CASES["oblique"][0])
    out = renderer.render(CAMERA, truth, depth=True)
    labels, depth = out.labels[0], 2.0 * out.depth[0] + 5.0
    off = [perturbed(truth, np.array([d, 0.0, 0.0])) for d in (0.0, 1.0, 3.0)]
    s = localizer.score_poses(CAMERA, labels, depth, off)
    assert s["semantic"][0] > 0.97 and s["depth_cost"][0] < 0.01
    assert s["score"][0] > s["score"][1] > s["score"][2]
    tilted = perturbed(truth, np.zeros(3), 2.0, 0.0)
    with_prior = localizer.score_poses(CAMERA, labels, depth, [truth, tilted], prior_local=truth)
    without = localizer.score_poses(CAMERA, labels, depth, [truth, tilted])
    assert with_prior["score"][0] == pytest.approx(without["score"][0])
    assert with_prior["score"][1] < without["score"][1]
    with pytest.raises(ParameterError):
        localizer.score_poses(CAMERA, labels, depth, [])


@pytest.fixture(scope="module")
def city_lod3(tmp_path_factory):
    from semcityloc.citymodel.citygml import read_citygml
    from semcityloc.citymodel.generator import generate_city

    return read_citygml(generate_city(tmp_path_factory.mktemp("lod3"), seed=0)[3])


def test_openings_of_an_lod3_map_are_scored_as_wall_unless_asked(city_lod3):
    """By default (``score_openings=False``) window and door count as wall on both sides: the scene the
    localizer renders has none, the IoU takes ground / wall / roof only; asked, they are classes of their
    own; a query's openings then match the map's."""
    from semcityloc.classes import SemanticClass as K

    assert np.isin(city_lod3.classes, [K.WINDOW, K.DOOR]).any()  # an LoD3 map with openings
    merged = Localizer(city_lod3)
    assert not merged.has_openings and not np.isin(merged.scene.classes, [K.WINDOW, K.DOOR]).any()
    assert np.flatnonzero(merged.class_on).tolist() == [K.GROUND, K.WALL, K.ROOF]
    scored = Localizer(city_lod3, LocalizerConfig.preset("openings"))
    assert LocalizerConfig.preset("openings") == replace(LocalizerConfig(), score_openings=True)
    assert scored.has_openings and np.isin(scored.scene.classes, [K.WINDOW, K.DOOR]).any()
    assert np.flatnonzero(scored.class_on).tolist() == [K.GROUND, K.WALL, K.ROOF, K.WINDOW, K.DOOR]
    assert LocalizerConfig.preset("legacy").score_openings  # the first design, unchanged
    renderer = Renderer(city_lod3, engine="numba")
    truth = view(city_lod3, -30.0, 15.0, 60.0, 0.0, 50.0, 200.0)
    labels = renderer.render(CAMERA, truth).labels[0]
    assert np.isin(labels, [K.WINDOW, K.DOOR]).any()
    off = [perturbed(truth, np.array([d, 0.0, 0.0])) for d in (0.0, 1.5)]
    s_merged = merged.score_poses(CAMERA, labels, None, off)["score"]
    s_scored = scored.score_poses(CAMERA, labels, None, off)["score"]
    assert s_merged[0] > s_merged[1] and s_scored[0] > s_scored[1]  # the true pose first, either way
    # Even the map's own labels do not match at the refinement's resolution once openings are classes.
    assert s_merged[0] > 0.9 > s_scored[0]


@pytest.mark.parametrize("state", [[10.0, -5.0, 80.0, 1.0, 0.5, 30.0], [0.0, 0.0, 120.0, 0.0, 45.0, -100.0]])
def test_pivot_perturbation_keeps_the_pivot_point_on_the_optical_axis(state):
    """A roll / pitch / yaw step mapped by ``pivot_jacobian`` moves the camera so that the point
    ``depth`` ahead on the optical axis stays at the principal point (to first order: a step along the
    tilt-versus-shift ridge), while the same step without it moves that point across the image."""
    from semcityloc.localization.refine import pivot_jacobian

    state = np.array(state)
    depth = 75.0
    pose = Pose.from_xyz_rpy(state[:3], state[3], state[4], state[5])
    pivot = pose.center + depth * np.asarray(pose.R)[2]
    jac = pivot_jacobian(state, depth)
    assert jac[:3, :3] == pytest.approx(np.eye(3)) and jac[3:, 3:] == pytest.approx(np.eye(3))
    for k, step_deg in ((3, 0.5), (4, -0.5), (5, 0.5)):
        step = np.zeros(6)
        step[k] = step_deg
        for moved, stays in ((state + jac @ step, True), (state + step, False)):
            p = Pose.from_xyz_rpy(moved[:3], moved[3], moved[4], moved[5])
            uv, _ = CAMERA.project(p.transform(pivot[None]))
            off = float(np.hypot(*(uv[0] - [CAMERA.cx, CAMERA.cy])))
            if stays:
                assert off < 0.01
            elif k != 5 or abs(state[4]) > 10.0:  # a yaw step of a nadir view turns about its axis
                assert off > 1.0
    assert pivot_jacobian(state, 0.0) == pytest.approx(np.eye(6))  # nothing seen: plain steps


def test_pivot_refinement_localizes_and_unknown_pivot_is_refused(city, localizer, renderer):
    truth = view(city, *CASES["nadir"][0])
    labels = renderer.render(CAMERA, truth).labels[0]
    prior = perturbed(truth, np.array(CASES["nadir"][1]), 1.0, -1.0, 5.0)
    for pivot in ("none", "polish", "both"):
        config = replace(localizer.config, refine=replace(localizer.config.refine, pivot=pivot))
        r = localizer.localize(CAMERA, prior, labels, config=config)
        assert center_error_m(r.pose_local, truth) < 0.5 and rotation_error_deg(r.pose_local, truth) < 0.5
    with pytest.raises(ParameterError, match="pivot"):
        replace(localizer.config.refine, pivot="orbit")


def _largest_building_in_view(city, renderer, pose) -> tuple[int, bool]:
    """Index of the building that covers most pixels of the view from ``pose``, and whether its image
    region touches another building's (a building in a row or block)."""
    ids = renderer.render(CAMERA, pose, face_ids=True).face_ids[0]
    tri = np.where(ids >= 0, renderer.scene.source_triangle[np.maximum(ids, 0)], -1)
    building = np.where(tri >= 0, city.building_index[np.maximum(tri, 0)], -1)
    building[(tri < 0) | ~np.isin(city.classes[np.maximum(tri, 0)], list(BUILDING_CLASSES))] = -1
    largest = int(np.bincount(building[building >= 0]).argmax())
    regions, _ = ndimage.label(building >= 0, np.ones((3, 3), dtype=bool))
    its_regions = np.unique(regions[building == largest])
    return largest, bool(np.any((building != largest) & np.isin(regions, its_regions) & (building >= 0)))


def test_buildings_on_one_side_only_are_reported_with_the_pose(city, localizer, renderer):
    true = view(city, *CASES["nadir"][0])
    prior = perturbed(true, np.array([4.0, 3.0, 1.0]), 0.3, -0.3, 3.0)
    gone, attached = _largest_building_in_view(city, renderer, true)
    assert attached  # part of a row: its region merges with its neighbours', the change is a part of it
    without = city.select(city.building_index != gone)
    # The image shows a building the map lacks (built after the survey) ...
    result = Localizer(without).localize(CAMERA, prior, renderer.render(CAMERA, true).labels[0])
    assert center_error_m(result.found_pose_local, true) < 1.0
    assert result.confidence["unmapped_building_share"] >= 0.02
    assert result.confidence["unseen_building_share"] == 0.0
    assert any("the image shows buildings the map lacks" in w for w in result.warnings)
    # ... and the map has one the image does not show (torn down).
    labels = Renderer(without, engine="numba").render(CAMERA, true).labels[0]
    result = localizer.localize(CAMERA, prior, labels)
    assert center_error_m(result.found_pose_local, true) < 1.0
    assert result.confidence["unseen_building_share"] >= 0.02
    assert result.confidence["unmapped_building_share"] == 0.0
    assert any("the map has buildings the image does not show" in w for w in result.warnings)
    # The same view of an unchanged map says nothing of the kind.
    result = localizer.localize(CAMERA, prior, renderer.render(CAMERA, true).labels[0])
    assert result.confidence["unmapped_building_share"] == result.confidence["unseen_building_share"] == 0.0
    assert not any("buildings" in w for w in result.warnings)


def test_fine_camera_and_render_labels_reproduce_the_results_map_agreement(city, localizer, renderer):
    """The public way to what a result's building IoU and warnings compare: the query at
    ``fine_camera`` against ``render_labels`` at the found pose (``benchmarks/map_change_warnings.py``
    uses it to apply the same rule at the true pose)."""
    true = view(city, *CASES["oblique"][0])
    prior = perturbed(true, np.array([3.0, -2.0, 1.0]), 0.3, 0.3, 2.0)
    labels = renderer.render(CAMERA, true).labels[0]
    result = localizer.localize(CAMERA, prior, labels)
    fine = localizer.fine_camera(CAMERA)
    assert (fine.width, fine.height) == (128, 96)
    rendered = localizer.render_labels(fine, result.pose_local)
    assert rendered.shape == (96, 128) and np.isin(rendered, list(range(NUM_CLASSES))).all()
    agreement = building_agreement(downsample_labels(labels, fine.width, fine.height), rendered)
    assert agreement.building_iou == pytest.approx(result.confidence["building_iou"])
    assert agreement.unseen_share == pytest.approx(result.confidence["unseen_building_share"])
    assert agreement.unmapped_share == pytest.approx(result.confidence["unmapped_building_share"])
    distance = boundary_distance_px(downsample_labels(labels, fine.width, fine.height), rendered)
    assert distance == pytest.approx(result.confidence["boundary_distance_px"]) and distance < 1.0

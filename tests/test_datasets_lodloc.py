"""LoD-Loc data set folders: per-image and text files, round trips, splits, frames (z-up / shifted ECEF)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from semcityloc.classes import SemanticClass
from semcityloc.datasets.lodloc import (
    SWISS_EPFL_ECEF_ORIGIN_LLH,
    LodLocQuery,
    enu_from_ecef,
    read_lodloc,
    read_split,
    rotate_pose,
    write_lodloc_scene,
)
from semcityloc.errors import CameraError, InputFileError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.errors import center_error_m, rotation_error_deg
from semcityloc.geometry.pose import Pose

CAM = Camera(1125.0, 1125.0, 320.0, 256.0, 640, 512)
BOX_F = [(1, 4, 3, 2), (5, 6, 7, 8), (1, 2, 6, 5), (2, 3, 7, 6), (3, 4, 8, 7), (4, 1, 5, 8)]


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    """Models parsed here go to a throw-away cache, not the user's."""
    monkeypatch.setenv("SEMCITYLOC_CACHE", str(tmp_path / "cache"))


def boxes_obj(transform=None) -> str:
    """A few LoD1 blocks (z up, outward faces); ``transform`` maps (N, 3) points before writing."""
    lines, base = [], 0
    for x0, y0, w, d, h in [
        (0, 0, 20, 15, 12),
        (40, -10, 25, 20, 30),
        (-35, 25, 15, 15, 8),
        (10, 40, 30, 10, 18),
    ]:
        v = np.array(
            [(x0, y0, 0), (x0 + w, y0, 0), (x0 + w, y0 + d, 0), (x0, y0 + d, 0)]
            + [(x0, y0, h), (x0 + w, y0, h), (x0 + w, y0 + d, h), (x0, y0 + d, h)],
            dtype=np.float64,
        )
        if transform is not None:
            v = transform(v)
        lines += [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in v]
        lines += ["f " + " ".join(str(i + base) for i in f) for f in BOX_F]
        base += 8
    return "\n".join(lines) + "\n"


def queries(n: int = 3, with_prior: bool = True) -> list[LodLocQuery]:
    rng = np.random.default_rng(0)
    out = []
    for k in range(n):
        gt = Pose.from_xyz_rpy(
            rng.normal(0, 50, 3) + [0, 0, 200], *rng.uniform(-3, 3, 2), rng.uniform(-180, 180)
        )
        prior = Pose.from_xyz_rpy(gt.center + rng.normal(0, 10, 3), 1.0, 2.0, 30.0) if with_prior else None
        out.append(LodLocQuery(f"DJI_{k:04d}_T.JPG", "scene", CAM, gt_pose_world=gt, prior_pose_world=prior))
    return out


def make_scene(folder, qs, text_files=False, images=True, obj=True):
    write_lodloc_scene(folder, qs, text_files=text_files)
    if images:
        (folder / "Query_image").mkdir(parents=True, exist_ok=True)
        for q in qs:
            Image.new("RGB", (q.camera.width, q.camera.height)).save(folder / "Query_image" / q.name)
    if obj:
        (folder / "model.obj").write_text(boxes_obj())
    return folder


def same_pose(a: Pose, b: Pose, tol_m: float = 1e-6, tol_deg: float = 1e-6) -> bool:
    return center_error_m(a, b) < tol_m and rotation_error_deg(a, b) < tol_deg


def test_scene_written_and_read_back_equals_the_input(tmp_path):
    qs = queries()
    ds = read_lodloc(make_scene(tmp_path / "scene", qs))
    assert [q.name for q in ds.queries] == [q.name for q in qs]
    assert ds.model_path == tmp_path / "scene" / "model.obj" and ds.frame == "z-up"
    assert "detected" in ds.frame_note and not ds.warnings
    for got, want in zip(ds.queries, qs, strict=True):
        assert got.camera == want.camera  # size from the image, K from [K|0]
        written = np.loadtxt(tmp_path / "scene" / "GT_pose" / f"{want.stem}_pose.txt")
        assert np.array_equal(written, want.gt_pose_world.world_from_cam)  # %.18e is exact
        np.testing.assert_allclose(got.gt_pose_world.world_from_cam, written, rtol=0, atol=1e-9)
        assert same_pose(got.prior_pose_world, want.prior_pose_world)
        assert got.image_path.name == want.name


def test_text_files_alone_are_read_like_lodlocs_demo(tmp_path):
    """GT_pose.txt / GPS_pose.txt ('query/<name> qw qx qy qz tx ty tz', world-to-camera) + intrinsic.txt."""
    qs = queries(2)
    folder = tmp_path / "demo"
    make_scene(folder, qs, text_files=True)
    for sub in ("GT_pose", "GPS_pose", "intrinsic"):
        for f in (folder / sub).iterdir():
            f.unlink()
        (folder / sub).rmdir()
    gt = (folder / "GT_pose.txt").read_text().replace("DJI_", "query/DJI_")
    (folder / "GT_pose.txt").write_text(gt)
    ds = read_lodloc(folder)
    assert len(ds) == 2
    for got, want in zip(ds.queries, qs, strict=True):
        assert got.camera == want.camera
        assert same_pose(got.gt_pose_world, want.gt_pose_world, 1e-6, 1e-6)
        assert same_pose(got.prior_pose_world, want.prior_pose_world, 1e-6, 1e-6)


def test_per_image_files_win_and_a_disagreeing_text_file_is_reported(tmp_path):
    qs = queries(1)
    folder = make_scene(tmp_path / "s", qs, text_files=True)
    shifted = LodLocQuery(
        qs[0].name, "s", CAM, gt_pose_world=qs[0].gt_pose_world.shift_world([3.0, 0.0, 0.0])
    )
    write_lodloc_scene(tmp_path / "other", [shifted], text_files=True)
    (folder / "GT_pose.txt").write_text((tmp_path / "other" / "GT_pose.txt").read_text())
    ds = read_lodloc(folder)
    assert same_pose(ds.queries[0].gt_pose_world, qs[0].gt_pose_world)
    assert any("differ by 3.000 m" in w for w in ds.warnings)


def test_images_without_intrinsics_are_skipped_with_a_warning(tmp_path):
    qs = queries(2)
    folder = make_scene(tmp_path / "s", qs)
    (folder / "intrinsic" / f"{qs[1].stem}_intrinsic.txt").unlink()
    ds = read_lodloc(folder)
    assert [q.name for q in ds.queries] == [qs[0].name]
    assert any("no intrinsics" in w for w in ds.warnings)


def test_intrinsics_of_another_image_than_the_query_image_are_skipped_with_a_warning(tmp_path):
    """Stop 50's audit: intrinsics of another image (here: a principal point 25 % off the image's centre,
    the centre of a 320x320 image) were applied to the query image unchecked; now that query is skipped,
    the warning naming the file, the image and both sizes. Since stop 55 a K of the image at half its size
    (the centre of 320x256, an exact-factor resize) is that image's camera rescaled, as a stated size is."""
    qs = queries(2)
    folder = make_scene(tmp_path / "s", qs)
    other = Camera(CAM.fx / 2, CAM.fy / 2, 160.0, 160.0, 320, 320)
    k_file = folder / "intrinsic" / f"{qs[1].stem}_intrinsic.txt"
    np.savetxt(k_file, np.hstack([other.K, np.zeros((3, 1))]))
    ds = read_lodloc(folder)
    assert [q.name for q in ds.queries] == [qs[0].name]
    said = [w for w in ds.warnings if "principal point" in w]
    assert len(said) == 1 and str(k_file) in said[0] and f"photo {qs[1].name} (640x512" in said[0]
    assert "320x320 image" in said[0] and said[0].endswith("; skipped")
    np.savetxt(k_file, np.hstack([CAM.scale(0.5).K, np.zeros((3, 1))]))
    assert read_lodloc(folder).query(qs[1].name).camera == CAM


def test_a_photo_downscaled_by_an_exact_factor_takes_the_k_rescaled_and_every_skip_is_named(tmp_path):
    """Stop 55 audit: a LoD-Loc K of 640x512 (cx 320, cy 256) with its photo downscaled to 320x256 was
    refused (principal point 50 % off), though a COLMAP camera stating 640x512 is rescaled; and when no
    image survived, the data set said only "no query images with intrinsics". Now the K is rescaled the
    same way, and the refusal names why each image was skipped."""
    qs = queries(1)
    folder = make_scene(tmp_path / "s", qs)
    Image.new("RGB", (320, 256)).save(folder / "Query_image" / qs[0].name)
    assert read_lodloc(folder).queries[0].camera == CAM.scale(0.5)
    np.savetxt(
        folder / "intrinsic" / f"{qs[0].stem}_intrinsic.txt",
        [[500, 0, 400, 0], [0, 500, 256, 0], [0, 0, 1, 0]],
    )
    with pytest.raises(InputFileError, match="no query images with intrinsics") as exc:
        read_lodloc(folder)
    assert f"{qs[0].name}: " in str(exc.value) and "principal point (400, 256)" in str(exc.value)


def test_no_image_means_size_from_the_principal_point_or_an_error(tmp_path):
    qs = queries(1)
    folder = make_scene(tmp_path / "s", qs, images=False)
    assert read_lodloc(folder).queries[0].camera == CAM  # 2 cx x 2 cy
    odd = [LodLocQuery("a.JPG", "s", Camera(100, 100, 33.3, 20, 80, 40), gt_pose_world=qs[0].gt_pose_world)]
    write_lodloc_scene(tmp_path / "odd", odd)
    with pytest.raises(CameraError, match="pass the image width"):
        read_lodloc(tmp_path / "odd", frame="z-up")


def test_split_keeps_its_stage_and_a_folder_of_scenes_is_read(tmp_path):
    qs = queries(3)
    make_scene(tmp_path / "data" / "inTraj", qs[:2], obj=False)
    make_scene(tmp_path / "data" / "outTraj", qs[2:], obj=False)
    (tmp_path / "data" / "city.obj").write_text(boxes_obj())
    split = tmp_path / "split.json"
    split.write_text(
        json.dumps(
            {"train": {"inTraj": [qs[0].name]}, "val": {"inTraj": [qs[1].name], "outTraj": [qs[2].name]}}
        )
    )
    ds = read_lodloc(tmp_path / "data", split=split)
    assert [(q.scene, q.name) for q in ds.queries] == [("inTraj", qs[1].name), ("outTraj", qs[2].name)]
    assert ds.model_path == tmp_path / "data" / "city.obj"
    assert [q.name for q in read_lodloc(tmp_path / "data", split=split, stage="train").queries] == [
        qs[0].name
    ]
    # A single scene folder whose name is not in the split (the demo's scene is called "demo").
    single = read_lodloc(tmp_path / "data" / "inTraj", city=tmp_path / "data" / "city.obj", split=split)
    assert [q.name for q in single.queries] == [qs[1].name]
    with pytest.raises(InputFileError, match="no stage 'test'"):
        read_split(split, "test")
    (tmp_path / "bad.json").write_text('{"val": ["a"]}')
    with pytest.raises(InputFileError, match="a split must be"):
        read_split(tmp_path / "bad.json")


def test_not_a_dataset_and_missing_model_are_clear_errors(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputFileError, match="not a LoD-Loc data set"):
        read_lodloc(tmp_path / "empty")
    with pytest.raises(InputFileError, match="no such LoD-Loc"):
        read_lodloc(tmp_path / "absent")
    folder = make_scene(tmp_path / "s", queries(1), obj=False)
    ds = read_lodloc(folder)
    assert "assumed" in ds.frame_note and ds.model_path is None
    with pytest.raises(InputFileError, match="pass the model file"):
        ds.load_model()
    with pytest.raises(InputFileError, match="unknown frame 'ned'; known: auto, z-up, ecef"):
        read_lodloc(folder, frame="ned")
    with pytest.raises(InputFileError, match="only used with frame='ecef'"):
        read_lodloc(folder, ecef_origin_llh=(46.5, 6.5, 400.0))
    # A z-up model said to be ECEF: every wall and camera was tilted by the rotation, without a word.
    (folder / "city.obj").write_text(boxes_obj(lambda v: v))
    with pytest.raises(InputFileError, match="vertical in its own frame already.*drop frame='ecef'"):
        read_lodloc(folder, frame="ecef")
    assert read_lodloc(folder).frame == "z-up"


def test_shifted_ecef_frame_is_detected_and_rotated_back_into_enu(tmp_path):
    """The Swiss-EPFL case: the same blocks and cameras written in ECEF-minus-origin coordinates."""
    R = enu_from_ecef(*SWISS_EPFL_ECEF_ORIGIN_LLH)
    qs = queries(2)
    ecef_qs = [
        LodLocQuery(
            q.name,
            q.scene,
            q.camera,
            gt_pose_world=rotate_pose(q.gt_pose_world, R.T),
            prior_pose_world=rotate_pose(q.prior_pose_world, R.T),
        )
        for q in qs
    ]
    folder = make_scene(tmp_path / "swiss", ecef_qs, obj=False)
    (folder / "ecef.obj").write_text(boxes_obj(lambda v: v @ R))  # enu = R @ x  ->  x = R^T enu
    with pytest.raises(InputFileError, match="frame='ecef'"):
        read_lodloc(folder)
    ds = read_lodloc(folder, frame="ecef")
    assert ds.frame == "ecef" and ds.ecef_origin_llh == SWISS_EPFL_ECEF_ORIGIN_LLH
    for got, want in zip(ds.queries, qs, strict=True):
        assert same_pose(got.gt_pose_world, want.gt_pose_world, 1e-6, 1e-6)
    model = ds.load_model(cache=False)
    world = model.vertices.astype(np.float64) + model.origin
    assert abs(world[:, 2].min()) < 1e-3 and abs(world[:, 2].max() - 30.0) < 1e-3  # z is up again
    counts = model.class_triangle_counts()
    assert counts["roof"] == 8 and counts["wall"] == 32  # re-classified in ENU (ground: the floors)
    assert int(np.sum(model.classes == SemanticClass.GROUND)) == 8


def test_real_demo_folder(shared):
    folder = shared("real_uav_lodloc")
    ds = read_lodloc(folder)
    assert len(ds) == 1 and ds.frame == "z-up" and ds.model_path.name == "UAVD4L-LoD1.obj"
    q = ds.queries[0]
    assert q.camera == Camera(1125.0, 1125.0, 320.0, 256.0, 640, 512)
    np.testing.assert_allclose(
        q.gt_pose_world.center, [-466.2421195633942, 286.9394447095692, 224.5679498720671]
    )
    assert 21.0 < float(center_error_m(q.prior_pose_world, q.gt_pose_world)) < 21.2
    assert 4.0 < float(rotation_error_deg(q.prior_pose_world, q.gt_pose_world)) < 4.1
    assert q.points_path is not None and q.points_path.name.endswith("_points.npy")

"""Automatic labels: projection with occlusion, the IGNORE rules, the real UAV image, ``semcityloc label``."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest
from scipy import ndimage

from semcityloc.citymodel import read_pose_world
from semcityloc.classes import IGNORE, SemanticClass
from semcityloc.datasets.colmap import ColmapCamera, ColmapImage, ColmapModel, write_model
from semcityloc.errors import CRSError, InputFileError, ParameterError, PoseError, RenderError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.conventions import colmap_qvec_tvec
from semcityloc.geometry.distortion import LensDistortion, distort_image
from semcityloc.geometry.io import write_pose_json
from semcityloc.geometry.pose import Pose
from semcityloc.io.images import load_labels_png, save_rgb
from semcityloc.perception.autolabel import auto_label, auto_label_render, label_overlay
from semcityloc.perception.synthetic import generated_model
from semcityloc.render import Renderer
from semcityloc.render.overlay import class_boundaries

CAM = Camera.from_fov(160, 120, 70.0)
REAL = "real_uav_lodloc/"
REAL_STEM = "DJI_20230513163714_0033_T"


@pytest.fixture(scope="module")
def city():
    model = generated_model(seed=0, blocks=(2, 2), lod=2)
    return model, Renderer(model, engine="numba")


def _world_pose(model, local_xyz, roll=0.0, pitch=0.0, yaw=0.0) -> Pose:
    return Pose.from_xyz_rpy(model.to_world(np.asarray(local_xyz, dtype=np.float64)), roll, pitch, yaw)


def _centre(model, height):
    lo, hi = model.bounds_local
    return [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2] + height]


def test_nadir_labels_are_the_model_classes_where_not_ignored(city):
    model, renderer = city
    pose = _world_pose(model, _centre(model, 120.0))
    res = auto_label_render(model, CAM, pose, renderer=renderer)
    truth = renderer.render(CAM, model.pose_to_local(pose)).labels[0]  # world pose to the local frame
    labels = res.labels
    assert labels.shape == (120, 160) and labels.dtype == np.uint8
    kept = labels != IGNORE
    assert np.array_equal(labels[kept], truth[kept])
    assert {1, 2, 3} <= set(np.unique(labels[kept]).tolist())
    assert 0.6 < kept.mean() < 0.98
    assert np.all(labels[class_boundaries(truth, 1)] == IGNORE)  # the 1-px band on both sides
    assert res.reasons["boundary"] > 0 and res.reasons["too_far"] == 0
    assert np.array_equal(auto_label(model, CAM, pose, renderer=renderer), labels)


def test_a_pose_in_local_coordinates_is_not_silently_accepted_as_world(city):
    model, renderer = city
    local = Pose.from_xyz_rpy(np.asarray(_centre(model, 120.0)), 0.0, 0.0, 0.0)  # forgot the origin
    # 5.8e6 m away: an all-IGNORE mask before (a training set of empty labels, silently); now said
    with pytest.raises(PoseError, match=r"auto_label takes the pose in world \(CRS\) coordinates"):
        auto_label(model, CAM, local, renderer=renderer)


def test_boundary_band_width(city):
    model, renderer = city
    pose = _world_pose(model, _centre(model, 120.0))
    truth = renderer.render(CAM, model.pose_to_local(pose)).labels[0]
    none = auto_label(model, CAM, pose, renderer=renderer, boundary_px=0)
    one = auto_label(model, CAM, pose, renderer=renderer, boundary_px=1)
    two = auto_label(model, CAM, pose, renderer=renderer, boundary_px=2)
    n0, n1, n2 = ((x == IGNORE).sum() for x in (none, one, two))
    assert n0 < n1 < n2
    assert np.array_equal(one == IGNORE, (none == IGNORE) | class_boundaries(truth, 1))
    with pytest.raises(ParameterError):
        auto_label(model, CAM, pose, renderer=renderer, boundary_px=-1)


def test_too_far_is_ignored(city):
    model, renderer = city
    pose = _world_pose(model, _centre(model, 120.0))
    near = auto_label_render(model, CAM, pose, renderer=renderer, max_range_m=70.0, boundary_px=0)
    assert np.all(near.labels == IGNORE)
    assert near.reasons["too_far"] + near.reasons["outside_model"] == near.labels.size
    assert near.reasons["too_far"] > 0.99 * near.labels.size
    mid = auto_label_render(
        model, CAM, pose, renderer=renderer, max_range_m=125.0, boundary_px=0, min_incidence_deg=0.0
    )
    # Range (not z-depth) decides: the z-depth times the length of the pixel's ray (z = 1).
    rng = mid.render.depth[0] * np.linalg.norm(CAM.ray_directions(), axis=-1)
    assert np.array_equal(mid.labels == IGNORE, rng > 125.0)
    assert 0.2 < np.mean(rng > 125.0) < 0.9
    kept = mid.labels[mid.labels != IGNORE]
    assert np.mean(kept == SemanticClass.ROOF) > np.mean(mid.render.labels[0] == SemanticClass.ROOF)
    with pytest.raises(ParameterError):
        auto_label(model, CAM, pose, renderer=renderer, max_range_m=0.0)


def test_grazing_surfaces_are_ignored(city):
    model, renderer = city
    lo, hi = model.bounds_local
    # West of the district, 10 m up, looking east 4 degrees below the horizon: ground beyond ~57 m is
    # seen at less than 10 degrees.
    pose = _world_pose(model, [lo[0] - 150, (lo[1] + hi[1]) / 2, lo[2] + 10.0], pitch=86.0, yaw=-90.0)
    res = auto_label_render(model, CAM, pose, renderer=renderer, boundary_px=0, extent_margin_m=1e4)
    assert res.reasons["grazing"] > 500
    flat = auto_label_render(
        model, CAM, pose, renderer=renderer, boundary_px=0, extent_margin_m=1e4, min_incidence_deg=0.0
    )
    assert flat.reasons["grazing"] == 0
    # Each grazing pixel: the ray meets its triangle at less than 10 degrees.
    changed = (res.labels == IGNORE) & (flat.labels != IGNORE)
    faces = res.render.face_ids[0][changed]
    c = renderer.scene.corners[faces].astype(np.float64)
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    pose_local = model.pose_to_local(pose)
    rays = CAM.ray_directions(normalize=True)[changed] @ pose_local.R
    assert np.all(np.degrees(np.arcsin(np.abs(np.sum(n * rays, axis=1)))) < 10.0 + 1e-6)


def test_terrain_beyond_the_model_and_sky(city):
    model, renderer = city
    lo, hi = model.bounds_local
    # At the east edge looking east, slightly above the horizon: terrain far outside, then sky.
    pose = _world_pose(model, [hi[0], (lo[1] + hi[1]) / 2, lo[2] + 40.0], pitch=95.0, yaw=-90.0)
    res = auto_label_render(model, CAM, pose, renderer=renderer, boundary_px=0, max_range_m=1e5)
    assert res.reasons["outside_model"] > 0
    sky = res.render.face_ids[0] < 0
    up = (CAM.ray_directions() @ model.pose_to_local(pose).R)[..., 2] > 0
    assert np.all(res.labels[sky & up] == SemanticClass.BACKGROUND) and (sky & up).sum() > 100
    terrain = (res.render.face_ids[0] >= 0) & (renderer.scene.source_triangle[res.render.face_ids[0]] < 0)
    assert np.all(res.labels[terrain & (res.labels != IGNORE)] == SemanticClass.GROUND)
    wide = auto_label_render(
        model, CAM, pose, renderer=renderer, boundary_px=0, max_range_m=1e5, extent_margin_m=1e5
    )
    assert wide.reasons["outside_model"] < res.reasons["outside_model"]


def test_bad_inputs(city):
    model, renderer = city
    pose = _world_pose(model, _centre(model, 120.0))
    with pytest.raises(PoseError, match="one pose"):
        auto_label(model, CAM, Pose.stack([pose, pose]), renderer=renderer)
    with pytest.raises(ParameterError, match="min_incidence"):
        auto_label(model, CAM, pose, renderer=renderer, min_incidence_deg=90.0)
    other = generated_model(seed=1, blocks=(1, 1), lod=2)
    with pytest.raises(RenderError, match="another model"):
        auto_label(other, CAM, pose, renderer=renderer)
    with pytest.raises(ParameterError, match="differ in size"):
        label_overlay(np.zeros((5, 5, 3), np.uint8), np.zeros((4, 5), np.uint8))


# ---------------------------------------------------------------------------------------------- real data
@pytest.fixture
def real_uav(shared):
    from semcityloc.citymodel.io import load_city_model
    from semcityloc.geometry.io import read_intrinsics, read_pose
    from semcityloc.io.images import load_image

    root = shared(REAL + "UAVD4L-LoD1.obj").parent
    model = load_city_model(root / "UAVD4L-LoD1.obj")
    image = load_image(root / "Query_image" / f"{REAL_STEM}.JPG")
    camera = read_intrinsics(root / "intrinsic" / f"{REAL_STEM}_intrinsic.txt", width=640, height=512)
    gt = read_pose(root / "GT_pose" / f"{REAL_STEM}_pose.txt")
    prior = read_pose(root / "GPS_pose" / f"{REAL_STEM}_pose.txt")
    return root, model, Renderer(model, engine="numba"), image, camera, gt, prior


def test_real_uav_image_labels_line_up_with_the_photo(real_uav, tmp_path):
    root, model, renderer, image, camera, gt, prior = real_uav
    grey = image.astype(np.float64).mean(2)
    gradient = np.hypot(ndimage.sobel(grey, 0), ndimage.sobel(grey, 1))
    scores = {}
    for name, pose in (("gt", gt), ("prior", prior)):
        res = auto_label_render(model, camera, pose, renderer=renderer)
        edges = class_boundaries(res.render.labels[0], 1)
        roof, ground = res.labels == SemanticClass.ROOF, res.labels == SemanticClass.GROUND
        scores[name] = (gradient[edges].mean(), grey[roof].mean() - grey[ground].mean(), res.labels)
    labels = scores["gt"][2]
    assert labels.shape == (512, 640)
    assert (
        0.05 < np.mean(labels == SemanticClass.ROOF) < 0.3 and np.mean(labels == SemanticClass.GROUND) > 0.5
    )
    assert np.mean(labels == IGNORE) < 0.1
    # Model edges fall on image edges at the true pose (gradient well above the image's mean), and
    # clearly better than at the GPS prior (21 m, 4 degrees off); roofs stand out from the ground.
    assert scores["gt"][0] > 1.5 * gradient.mean()
    assert scores["gt"][0] > 1.2 * scores["prior"][0]
    assert scores["gt"][1] > 25 and scores["gt"][1] > scores["prior"][1] + 10
    overlay = label_overlay(image, labels)
    assert overlay.shape == image.shape and overlay.dtype == np.uint8
    assert np.all(overlay[labels == IGNORE] >= image[labels == IGNORE])  # photo, lightened by the hatch
    save_rgb(overlay, tmp_path / "overlay.png")
    assert (tmp_path / "overlay.png").stat().st_size > 10_000


def _label_parser():
    from semcityloc.cli import label

    parser = argparse.ArgumentParser()
    label.register(parser.add_subparsers(dest="command"))
    return parser


def test_label_cli_on_the_lodloc_folder_layout(real_uav, tmp_path, capsys):
    root, model, renderer, image, camera, gt, _ = real_uav
    args = _label_parser().parse_args(
        [
            "label",
            "--city",
            str(root / "UAVD4L-LoD1.obj"),
            "--images",
            str(root / "Query_image"),
            "--poses",
            str(root / "GT_pose"),  # intrinsics: the intrinsic/ folder beside it
            "--out",
            str(tmp_path / "labels"),
            "--overlay",
        ]
    )
    assert args.func(args) == 0
    written = load_labels_png(tmp_path / "labels" / f"{REAL_STEM}.png")
    assert np.array_equal(written, auto_label(model, camera, gt, renderer=renderer))
    assert (tmp_path / "labels" / "overlays" / f"{REAL_STEM}.png").is_file()
    assert '"labelled"' in capsys.readouterr().out


def test_label_cli_with_colmap_images_and_cameras(city, tmp_path):
    model, renderer = city
    photos = tmp_path / "photos"
    cam = Camera(150.0, 150.0, 80.0, 60.0, 160, 120)
    poses = {
        f"view_{i}.png": _world_pose(model, _centre(model, 90.0 + 20 * i), yaw=30.0 * i) for i in range(2)
    }
    lines = []
    for i, (name, pose) in enumerate(poses.items()):
        save_rgb(np.full((120, 160, 3), 100, np.uint8), photos / name)
        q, t = colmap_qvec_tvec(pose)
        lines.append(f"{i + 1} {' '.join(f'{v:.12g}' for v in (*q, *t))} 7 {name}\n\n")
    save_rgb(np.zeros((120, 160, 3), np.uint8), photos / "no_pose.png")
    (tmp_path / "images.txt").write_text("# COLMAP\n" + "".join(lines))
    (tmp_path / "cameras.txt").write_text("7 PINHOLE 320 240 300 300 160 120\n")  # rescaled to 160x120
    gml = tmp_path / "city.npz"
    model.save_npz(gml)
    args = _label_parser().parse_args(
        ["label", "--city", str(gml), "--images", str(photos), "--poses", str(tmp_path / "images.txt"),
         "--out", str(tmp_path / "out"), "--boundary-px", "0"]
    )  # fmt: skip
    assert args.func(args) == 0
    for name, pose in poses.items():
        written = load_labels_png(tmp_path / "out" / name)
        assert np.array_equal(written, auto_label(model, cam, pose, renderer=renderer, boundary_px=0))
    assert not (tmp_path / "out" / "no_pose.png").exists()
    # The same camera with a wide lens's distortion: the labels move onto the photo's distorted pixels.
    lens = LensDistortion(k1=-0.27, k2=0.11, p1=0.0008, p2=-0.0003)
    (tmp_path / "cameras.txt").write_text("7 OPENCV 320 240 300 300 160 120 -0.27 0.11 0.0008 -0.0003\n")
    args.out = str(tmp_path / "distorted")
    assert args.func(args) == 0
    for name, pose in poses.items():
        written = load_labels_png(tmp_path / "distorted" / name)
        pinhole = auto_label(model, cam, pose, renderer=renderer, boundary_px=0)
        assert np.array_equal(written, distort_image(pinhole, cam, lens, fill=IGNORE, nearest=True))
        assert (written != pinhole).mean() > 0.02 and written[0, 0] == IGNORE  # barrel: corners unseen


def test_label_skips_a_photo_whose_pose_lies_far_from_the_model_naming_it(city, tmp_path, capsys):
    """One pose of the batch in another CRS (5,818 km off: Berlin UTM numbers for a local model) stopped
    the whole ``label`` run with ``auto_label``'s Python-API advice naming neither photo nor file (stop 55
    audit). Now that photo is left out with the render check's words, naming photo, pose file and distance,
    and the others are labelled."""
    model, _ = city
    photos = tmp_path / "photos"
    lines = []
    for i in range(2):
        name, pose = f"view_{i}.png", _world_pose(model, _centre(model, 90.0), yaw=30.0 * i)
        if i == 1:
            pose = Pose(pose.R, pose.t - pose.R @ np.array([0.0, 5_818_000.0, 0.0]))  # centre moved north
        save_rgb(np.full((120, 160, 3), 100, np.uint8), photos / name)
        q, t = colmap_qvec_tvec(pose)
        lines.append(f"{i + 1} {' '.join(f'{v:.12g}' for v in (*q, *t))} 7 {name}\n\n")
    (tmp_path / "images.txt").write_text("# COLMAP\n" + "".join(lines))
    (tmp_path / "cameras.txt").write_text("7 PINHOLE 160 120 150 150 80 60\n")
    model.save_npz(tmp_path / "city.npz")
    args = _label_parser().parse_args(
        ["label", "--city", str(tmp_path / "city.npz"), "--images", str(photos), "--poses",
         str(tmp_path / "images.txt"), "--out", str(tmp_path / "out")]
    )  # fmt: skip
    assert args.func(args) == 0
    err = capsys.readouterr().err
    assert (
        f"not labelled: view_1.png: {tmp_path / 'images.txt'}: the camera lies 5,818 km from the model" in err
    )
    assert "auto_label" not in err
    assert (tmp_path / "out" / "view_0.png").is_file() and not (tmp_path / "out" / "view_1.png").exists()


def test_label_cli_reads_a_binary_colmap_model_as_its_text(city, tmp_path, capsys):
    """``--poses sparse/0/images.bin`` (what COLMAP and hloc write by default) was read as text: "cannot
    read". Now a binary model, its ``images.bin`` or its folder, labels exactly as the same model in text,
    the camera of each photo taken from ``cameras.bin`` by the image's camera id."""
    model, renderer = city
    photos = tmp_path / "photos"
    sfm = ColmapModel(cameras={7: ColmapCamera(7, "PINHOLE", 320, 240, [300.0, 300.0, 160.0, 120.0])})
    sfm.cameras[8] = ColmapCamera(8, "PINHOLE", 160, 120, [120.0, 120.0, 80.0, 60.0])
    for i in range(2):
        name, pose = f"view_{i}.png", _world_pose(model, _centre(model, 90.0 + 20 * i), yaw=30.0 * i)
        save_rgb(np.full((120, 160, 3), 100, np.uint8), photos / name)
        sfm.images[i + 1] = ColmapImage.from_pose(i + 1, name, 7 + i, pose)
    write_model(sfm, tmp_path / "bin", ext=".bin")
    write_model(sfm, tmp_path / "txt", ext=".txt")
    gml = tmp_path / "city.npz"
    model.save_npz(gml)
    outputs = {}
    for form, poses in (("txt", "txt/images.txt"), ("bin", "bin/images.bin"), ("folder", "bin")):
        args = _label_parser().parse_args(
            ["label", "--city", str(gml), "--images", str(photos), "--poses", str(tmp_path / poses),
             "--out", str(tmp_path / form), "--boundary-px", "0"]
        )  # fmt: skip
        assert args.func(args) == 0
        outputs[form] = [load_labels_png(tmp_path / form / f"view_{i}.png") for i in range(2)]
    wide = Camera(150.0, 150.0, 80.0, 60.0, 160, 120)  # camera 7 at the photo's size
    expected = auto_label(model, wide, sfm.images[1].pose, renderer=renderer, boundary_px=0)
    assert np.array_equal(outputs["bin"][0], expected)
    assert (outputs["bin"][0] != outputs["bin"][1]).any()
    for form in ("bin", "folder"):
        assert all(np.array_equal(a, b) for a, b in zip(outputs[form], outputs["txt"], strict=True))
    # images.txt beside cameras.bin (a model converted in part) finds its cameras; one image whose pose is
    # NaN in images.bin leaves its photo out, naming it, where it stopped the batch (adversarial test)
    (tmp_path / "bin" / "images.txt").write_bytes((tmp_path / "txt" / "images.txt").read_bytes())
    (tmp_path / "bin" / "images.bin").unlink()
    args = _label_parser().parse_args(
        ["label", "--city", str(gml), "--images", str(photos), "--poses",
         str(tmp_path / "bin" / "images.txt"), "--out", str(tmp_path / "mixed"), "--boundary-px", "0"]
    )  # fmt: skip
    assert args.func(args) == 0
    assert np.array_equal(load_labels_png(tmp_path / "mixed" / "view_0.png"), outputs["txt"][0])
    sfm.images[2].tvec[:] = np.nan
    write_model(sfm, tmp_path / "nan", ext=".bin")
    args = _label_parser().parse_args(
        ["label", "--city", str(gml), "--images", str(photos), "--poses", str(tmp_path / "nan"),
         "--out", str(tmp_path / "nan_out"), "--boundary-px", "0"]
    )  # fmt: skip
    assert args.func(args) == 0
    err = capsys.readouterr().err
    assert "images.bin: image 'view_1.png':" in err and "non-finite" in err
    assert (tmp_path / "nan_out" / "view_0.png").is_file() and not (
        tmp_path / "nan_out" / "view_1.png"
    ).exists()


def test_a_json_pose_of_another_crs_is_refused_by_label_and_by_read_pose_world(city, tmp_path, capsys):
    """``label --poses`` read a JSON pose's numbers whatever CRS it declared (``localize`` and ``render``
    checked it since stop 45): labels drawn from a WGS 84 pose taken as UTM metres. Now the single file is
    refused naming both CRSs, a folder's file leaves that photo out naming it (as does a malformed one:
    it stopped the batch), and ``citymodel.read_pose_world`` is the same check in Python."""
    model, _ = city
    photos, folder = tmp_path / "photos", tmp_path / "poses"
    folder.mkdir()
    cam = Camera(150.0, 150.0, 80.0, 60.0, 160, 120)
    (tmp_path / "cam.json").write_text(json.dumps(cam.as_dict()))
    pose = _world_pose(model, _centre(model, 100.0))
    for stem, crs in (("utm", "EPSG:25832"), ("wgs84", "EPSG:4326")):
        save_rgb(np.full((120, 160, 3), 100, np.uint8), photos / f"{stem}.png")
        write_pose_json(folder / f"{stem}_pose.txt", pose_world=pose, crs=crs)
    save_rgb(np.full((120, 160, 3), 100, np.uint8), photos / "broken.png")
    (folder / "broken_pose.txt").write_text("1 2 3\n")  # one malformed file stopped the whole batch
    model.save_npz(tmp_path / "c.npz")
    common = ["label", "--city", str(tmp_path / "c.npz"), "--images", str(photos), "--intrinsics"]
    common += [str(tmp_path / "cam.json"), "--boundary-px", "0"]
    args = _label_parser().parse_args([*common, "--poses", str(folder), "--out", str(tmp_path / "out")])
    assert args.func(args) == 0
    err = capsys.readouterr().err
    assert (tmp_path / "out" / "utm.png").is_file() and not (tmp_path / "out" / "wgs84.png").exists()
    assert "wgs84_pose.txt: the pose is in EPSG:4326 but the model in EPSG:25832" in err
    assert "broken_pose.txt" in err and not (tmp_path / "out" / "broken.png").exists()
    single = folder / "wgs84_pose.txt"
    args = _label_parser().parse_args([*common, "--poses", str(single), "--out", str(tmp_path / "o2")])
    with pytest.raises(CRSError, match="the pose is in EPSG:4326 but the model in EPSG:25832"):
        args.func(args)
    with pytest.raises(CRSError, match="the prior is in EPSG:4326"):
        read_pose_world(single, model.crs, "prior")
    np.testing.assert_allclose(read_pose_world(folder / "utm_pose.txt", model.crs).center, pose.center)
    assert read_pose_world(single, None).center.shape == (3,)  # a model without a CRS cannot check
    # A crs that is no name, a garbage one, a file with a BOM (adversarial test, stop 51): the first passed
    # unchecked, the second was refused naming no file, the third was read as a matrix ("non-numeric")
    data = json.loads(single.read_text())
    for crs, error, said in ((4326, PoseError, "is no CRS name"), ("garbage!!", CRSError, "the prior's crs")):
        (tmp_path / "odd.json").write_text(json.dumps({**data, "crs": crs}))
        with pytest.raises(error, match=f"odd.json: .*{said}"):
            read_pose_world(tmp_path / "odd.json", model.crs, "prior")
    (tmp_path / "bom.json").write_bytes(b"\xef\xbb\xbf" + single.read_bytes())
    with pytest.raises(CRSError, match="the prior is in EPSG:4326"):
        read_pose_world(tmp_path / "bom.json", model.crs, "prior")


def test_label_cli_errors(tmp_path, city):
    model, _ = city
    (tmp_path / "imgs").mkdir()
    model.save_npz(tmp_path / "c.npz")
    args = _label_parser().parse_args(
        [
            "label",
            "--city",
            str(tmp_path / "c.npz"),
            "--images",
            str(tmp_path / "imgs"),
            "--poses",
            "x",
            "--out",
            "o",
        ]
    )
    with pytest.raises(InputFileError, match="no images"):
        args.func(args)
    save_rgb(np.zeros((8, 8, 3), np.uint8), tmp_path / "imgs" / "a.png")
    (tmp_path / "poses").mkdir()
    args = _label_parser().parse_args(
        ["label", "--city", str(tmp_path / "c.npz"), "--images", str(tmp_path / "imgs"),
         "--poses", str(tmp_path / "poses"), "--out", str(tmp_path / "o")]
    )  # fmt: skip
    with pytest.raises(InputFileError, match=r"no intrinsics given \(intrinsics=\.\.\.\)"):
        args.func(args)


def test_label_cli_goes_on_past_a_photo_it_cannot_read(city, tmp_path, capsys):
    """A photo whose header does not read and one whose pixels do not decode: the first is not labelled,
    the second labelled without its overlay, each named on stderr; the good photo is labelled with its
    overlay. Before, the run stopped at the first of them."""
    model, renderer = city
    photos = tmp_path / "photos"
    cam = Camera(150.0, 150.0, 80.0, 60.0, 160, 120)
    poses = {f"view_{i}.jpg": _world_pose(model, _centre(model, 90.0), yaw=40.0 * i) for i in range(3)}
    lines = []
    for i, (name, pose) in enumerate(poses.items()):
        rng = np.random.default_rng(i)
        save_rgb(rng.integers(0, 255, (120, 160, 3), dtype=np.uint8), photos / name)
        q, t = colmap_qvec_tvec(pose)
        lines.append(f"{i + 1} {' '.join(f'{v:.12g}' for v in (*q, *t))} 7 {name}\n\n")
    (photos / "view_1.jpg").write_bytes(b"not a photo at all")
    data = (photos / "view_2.jpg").read_bytes()
    (photos / "view_2.jpg").write_bytes(data[: len(data) // 2])  # its header reads, its pixels do not
    (tmp_path / "images.txt").write_text("# COLMAP\n" + "".join(lines))
    (tmp_path / "cameras.txt").write_text("7 PINHOLE 160 120 150 150 80 60\n")
    model.save_npz(tmp_path / "city.npz")
    args = _label_parser().parse_args(
        ["label", "--city", str(tmp_path / "city.npz"), "--images", str(photos), "--poses",
         str(tmp_path / "images.txt"), "--out", str(tmp_path / "out"), "--overlay", "--boundary-px", "0"]
    )  # fmt: skip
    assert args.func(args) == 0
    out, err = capsys.readouterr()
    assert "wrote 2 label map(s)" in out
    assert "not labelled: " in err and "view_1.jpg" in err
    assert "labelled, no overlay: " in err and "view_2.jpg" in err
    assert (tmp_path / "out" / "overlays" / "view_0.png").is_file()
    assert not (tmp_path / "out" / "overlays" / "view_2.png").exists()
    written = load_labels_png(tmp_path / "out" / "view_2.png")
    assert np.array_equal(
        written, auto_label(model, cam, poses["view_2.jpg"], renderer=renderer, boundary_px=0)
    )


def test_label_reads_a_runs_pose_records_and_names_the_photo_it_could_not_label(city, tmp_path, capsys):
    """Stop 52's audit: ``label --poses run/poses`` (a run's own pose records, ``<stem>.json``) was refused,
    and a photo it could not label was said without its name ("not labelled: the image has no 35
    mm-equivalent focal length ..."). Both photos' records are read now; the one without EXIF focal length
    is named."""
    from dji_photo import dji_jpeg

    model, _ = city
    photos, poses = tmp_path / "photos", tmp_path / "poses"
    photos.mkdir()
    poses.mkdir()
    dji_jpeg(photos / "A.JPG", None, size=(160, 120), focal_35mm=24)
    dji_jpeg(photos / "NOEXIF.JPG", None, size=(160, 120))
    for stem in ("A", "NOEXIF"):
        pose = _world_pose(model, _centre(model, 90.0), pitch=20.0)
        write_pose_json(poses / f"{stem}.json", pose_world=pose, extra={"status": "localized"})
    model.save_npz(tmp_path / "city.npz")
    args = _label_parser().parse_args(
        ["label", "--city", str(tmp_path / "city.npz"), "--images", str(photos), "--poses", str(poses),
         "--intrinsics", "exif", "--out", str(tmp_path / "out")]
    )  # fmt: skip
    assert args.func(args) == 0
    out, err = capsys.readouterr()
    assert "wrote 1 label map(s)" in out
    assert "not labelled: NOEXIF.JPG: the image has no 35 mm-equivalent focal length" in err


def test_label_with_exif_intrinsics_says_once_that_the_35mm_focal_length_is_approximate(
    city, tmp_path, capsys
):
    """Stop 55 audit: ``label --intrinsics exif`` used the approximate 35 mm-equivalent focal length (2.3 %
    short on the thermal photo) without a word, where ``localize`` / ``run`` print the note; and ``exif``
    was not in ``label --help``. Now the note, once per run, naming how many photos."""
    from dji_photo import dji_jpeg
    from semcityloc.datasets.photos import APPROXIMATE_INTRINSICS_NOTE

    model, _ = city
    photos, poses = tmp_path / "photos", tmp_path / "poses"
    photos.mkdir()
    poses.mkdir()
    for stem in ("A", "B"):
        dji_jpeg(photos / f"{stem}.JPG", None, size=(160, 120), focal_35mm=24)
        pose = _world_pose(model, _centre(model, 90.0), pitch=20.0)
        write_pose_json(poses / f"{stem}.json", pose_world=pose, extra={"status": "localized"})
    model.save_npz(tmp_path / "city.npz")
    parser = _label_parser()
    args = parser.parse_args(
        ["label", "--city", str(tmp_path / "city.npz"), "--images", str(photos), "--poses", str(poses),
         "--intrinsics", "exif", "--out", str(tmp_path / "out")]
    )  # fmt: skip
    assert args.func(args) == 0
    err = capsys.readouterr().err
    assert err.count(APPROXIMATE_INTRINSICS_NOTE) == 1
    assert f"semcityloc: note: 2 photos: {APPROXIMATE_INTRINSICS_NOTE}" in err
    sub = next(a for a in parser._actions if a.dest == "command")
    assert "'exif'" in sub.choices["label"].format_help()


@pytest.mark.parametrize("margin", [-50.0, float("nan"), float("inf")])
def test_an_extent_margin_that_is_no_distance_is_refused(city, margin):
    """``--extent-margin -50`` / nan / inf were taken, all giving the same labels (stop 50's audit)."""
    model, renderer = city
    pose = _world_pose(model, _centre(model, 120.0))
    with pytest.raises(ParameterError, match="extent_margin_m must be a number of metres >= 0"):
        auto_label(model, CAM, pose, renderer=renderer, extent_margin_m=margin)

"""COLMAP models: text and binary round trips, the binary layout byte by byte, poses, errors, pycolmap."""

from __future__ import annotations

import struct
from types import SimpleNamespace

import numpy as np
import pytest

from semcityloc.datasets import colmap_pycolmap
from semcityloc.datasets.colmap import (
    CAMERA_MODELS,
    ColmapCamera,
    ColmapImage,
    ColmapModel,
    ColmapPoint3D,
    read_cameras_binary,
    read_images_binary,
    read_images_text,
    read_model,
    write_model,
)
from semcityloc.errors import CameraError, InputFileError, OptionalDependencyError, UnsupportedFormatError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.errors import center_error_m, rotation_error_deg
from semcityloc.geometry.pose import Pose


def sample_model(seed: int = 0) -> ColmapModel:
    rng = np.random.default_rng(seed)
    model = ColmapModel()
    model.cameras[1] = ColmapCamera(1, "PINHOLE", 640, 512, [1125.0, 1125.5, 320.0, 256.0])
    model.cameras[7] = ColmapCamera(
        7, "OPENCV", 5280, 3956, [3778.4, 3767.3, 2663.6, 1919.7, 0.01, -0.02, 1e-4, 0]
    )
    model.cameras[3] = ColmapCamera(3, "SIMPLE_RADIAL", 100, 80, [90.0, 50.0, 40.0, 0.0])
    names = ["DJI_0001.JPG", "query/DJI 0002 with spaces.jpg", "ünïcode.png"]
    for k, name in enumerate(names, start=1):
        pose = Pose.from_xyz_rpy(rng.normal(0, 300, 3), *rng.uniform(-30, 30, 2), rng.uniform(-180, 180))
        image = ColmapImage.from_pose(10 + k, name, [1, 7, 3][k - 1], pose)
        n = [0, 5, 2][k - 1]
        image.xys = rng.uniform(0, 500, (n, 2)) + rng.random((n, 2)) * 1e-9
        image.point3D_ids = np.array([-1, 4, 8, -1, 4][:n], dtype=np.int64)
        model.images[image.image_id] = image
    model.points3D[4] = ColmapPoint3D(4, rng.normal(0, 100, 3), [255, 0, 17], 0.731, [12, 13], [1, 4])
    model.points3D[8] = ColmapPoint3D(8, [1e7 + 0.125, -3.3e6, 42.0], [1, 2, 3], 1.5, [12], [2])
    model.points3D[9] = ColmapPoint3D(9, [0.0, 0.0, 0.0], [0, 0, 0], -1.0)
    return model


@pytest.mark.parametrize("ext", [".txt", ".bin"])
def test_model_written_and_read_back_equals_the_input(tmp_path, ext):
    model = sample_model()
    folder = write_model(model, tmp_path / "sparse", ext=ext)
    back = read_model(folder)
    assert back.cameras == model.cameras
    assert back.images == model.images  # bit-exact floats, names with spaces and unicode, 2D points
    assert back.points3D == model.points3D
    assert list(back.images) == list(model.images)  # file order kept


def test_text_and_binary_give_the_same_model(tmp_path):
    model = sample_model(1)
    via_bin = read_model(write_model(model, tmp_path / "b", ".bin"))
    via_txt = read_model(write_model(via_bin, tmp_path / "t", ".txt"))
    assert via_txt.cameras == model.cameras and via_txt.images == model.images
    assert via_txt.points3D == model.points3D


def test_binary_layout_matches_colmaps_documented_format(tmp_path):
    """Files packed by hand from the format description (not by our writer) read correctly."""
    cams = (
        struct.pack("<Q", 1) + struct.pack("<iiQQ", 5, 1, 640, 512) + struct.pack("<4d", 1125, 1126, 320, 256)
    )
    (tmp_path / "cameras.bin").write_bytes(cams)
    images = struct.pack("<Q", 1) + struct.pack("<I7dI", 3, 1, 0, 0, 0, 1.5, -2.5, 3.5, 5)
    images += b"a/b.jpg\x00" + struct.pack("<Q", 2) + struct.pack("<ddq", 10.5, 20.25, -1)
    images += struct.pack("<ddq", 1.0, 2.0, 77)
    (tmp_path / "images.bin").write_bytes(images)
    cam = read_cameras_binary(tmp_path / "cameras.bin")[5]
    assert cam.model == "PINHOLE" and (cam.width, cam.height) == (640, 512)
    assert cam.to_camera() == Camera(1125, 1126, 320, 256, 640, 512)
    im = read_images_binary(tmp_path / "images.bin")[3]
    assert im.name == "a/b.jpg" and im.camera_id == 5
    np.testing.assert_array_equal(im.tvec, [1.5, -2.5, 3.5])
    np.testing.assert_array_equal(im.xys, [[10.5, 20.25], [1.0, 2.0]])
    np.testing.assert_array_equal(im.point3D_ids, [-1, 77])
    # Our writer produces exactly these bytes again.
    write_model(ColmapModel({5: cam}, {3: im}), tmp_path / "again", ".bin")
    assert (tmp_path / "again" / "cameras.bin").read_bytes() == cams
    assert (tmp_path / "again" / "images.bin").read_bytes() == images


def test_images_txt_as_colmap_writes_it(tmp_path):
    text = (
        "# Image list with two lines of data per image:\n"
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
        "#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
        "# Number of images: 2, mean observations per image: 1\n"
        "1 0.851773 0.0165051 0.503764 -0.142941 -0.737434 1.02973 3.74354 1 P1180141.JPG\n"
        "2362.39 248.498 58396 1784.7 268.254 59027\n"
        "2 0.851773 0.0165051 0.503764 -0.142941 -0.737434 1.02973 3.74354 1 P1180142.JPG\n"
        "\n"
    )
    (tmp_path / "images.txt").write_text(text)
    images = read_images_text(tmp_path / "images.txt")
    assert [im.name for im in images.values()] == ["P1180141.JPG", "P1180142.JPG"]
    np.testing.assert_array_equal(images[1].point3D_ids, [58396, 59027])
    assert len(images[2].xys) == 0


def test_poses_and_cameras_convert_both_ways():
    cam = Camera(1125.0, 1125.0, 320.0, 256.0, 640, 512)
    poses = {
        "a.jpg": (cam, Pose.from_xyz_rpy([10.0, -4.0, 225.0], 0.8, 0.3, 102.5)),
        "b.jpg": (cam, Pose.from_xyz_rpy([-466.2, 286.9, 224.6], 2.0, 40.0, -170.0)),
        "c.jpg": (cam.scaled(320, 256), Pose.from_xyz_rpy([0.0, 0.0, 100.0], 0.0, 0.0, 0.0)),
    }
    model = ColmapModel.from_poses(poses)
    assert len(model.cameras) == 2  # identical cameras share one id
    back = model.poses()
    for name, (camera, pose) in poses.items():
        assert back[name][0] == camera
        assert center_error_m(back[name][1], pose) < 1e-9
        assert rotation_error_deg(back[name][1], pose) < 1e-6


def test_camera_models_that_are_not_a_pinhole_refuse_to_convert():
    assert ColmapCamera(1, "OPENCV", 10, 10, [5, 6, 5, 5, 0, 0, 0, 0]).to_camera() == Camera(
        5, 6, 5, 5, 10, 10
    )
    assert ColmapCamera(1, "SIMPLE_RADIAL", 10, 10, [5, 5, 5, 0]).to_camera() == Camera(5, 5, 5, 5, 10, 10)
    with pytest.raises(CameraError, match="undistort"):
        ColmapCamera(1, "OPENCV", 10, 10, [5, 6, 5, 5, 0.1, 0, 0, 0]).to_camera()
    with pytest.raises(CameraError, match="not a pinhole"):
        ColmapCamera(1, "OPENCV_FISHEYE", 10, 10, np.zeros(8)).to_camera()
    with pytest.raises(CameraError, match="needs 4 params"):
        ColmapCamera(1, "PINHOLE", 10, 10, [1, 2, 3])
    with pytest.raises(UnsupportedFormatError, match="unknown COLMAP camera model"):
        ColmapCamera(1, "KANNALA", 10, 10, [1, 2, 3])
    assert {name: mid for name, (mid, _) in CAMERA_MODELS.items()}["FULL_OPENCV"] == 6


def test_broken_files_raise_typed_errors(tmp_path):
    write_model(sample_model(), tmp_path / "m", ".bin")
    data = (tmp_path / "m" / "images.bin").read_bytes()
    (tmp_path / "m" / "images.bin").write_bytes(data[:-5])
    with pytest.raises(InputFileError, match="truncated"):
        read_model(tmp_path / "m")
    (tmp_path / "m" / "images.bin").write_bytes(data + b"xx")
    with pytest.raises(InputFileError, match="after the last record"):
        read_model(tmp_path / "m")
    (tmp_path / "m" / "cameras.bin").write_bytes(struct.pack("<Q", 1) + struct.pack("<iiQQ", 1, 99, 1, 1))
    with pytest.raises(UnsupportedFormatError, match="model id 99"):
        read_cameras_binary(tmp_path / "m" / "cameras.bin")
    (tmp_path / "m" / "cameras.bin").write_bytes(struct.pack("<Q", 1 << 40))
    with pytest.raises(InputFileError, match="implausible"):
        read_cameras_binary(tmp_path / "m" / "cameras.bin")

    write_model(sample_model(), tmp_path / "t", ".txt")
    text_images = (tmp_path / "t" / "images.txt").read_bytes()  # text under a binary name (stop 51): it was
    (tmp_path / "m" / "images.bin").write_bytes(text_images)  # "implausible number of images (2334385650...)"
    with pytest.raises(
        InputFileError, match=r"images.bin: COLMAP text under a binary file's name .* images.txt"
    ):
        read_images_binary(tmp_path / "m" / "images.bin")
    (tmp_path / "t" / "cameras.txt").write_text("1 PINHOLE 640 512 1125 1125 320 abc\n")
    with pytest.raises(InputFileError, match="line 1"):
        read_model(tmp_path / "t")
    with pytest.raises(InputFileError, match="no COLMAP model"):
        read_model(tmp_path)
    with pytest.raises(InputFileError, match="no such COLMAP model folder"):
        read_model(tmp_path / "absent")
    with pytest.raises(UnsupportedFormatError):
        write_model(sample_model(), tmp_path / "x", ext=".json")
    bad = ColmapModel(images={1: ColmapImage(1, [1, 0, 0, 0], [0, 0, 0], 1, " lead")})
    with pytest.raises(InputFileError, match="white space"):
        write_model(bad, tmp_path / "y", ".txt")


def test_missing_camera_of_an_image_is_reported():
    model = ColmapModel(images={1: ColmapImage(1, [1, 0, 0, 0], [0, 0, 0], 9, "a.jpg")})
    with pytest.raises(InputFileError, match="missing camera 9"):
        model.poses()


def _fake_reconstruction(new_api: bool):
    """Objects shaped like pycolmap's, old (qvec/tvec, model_name) and new (cam_from_world(), enum)."""
    q_xyzw = np.array([0.1, 0.2, 0.3, 0.9])
    q_xyzw /= np.linalg.norm(q_xyzw)
    t = np.array([1.0, 2.0, 3.0])
    if new_api:
        rigid = SimpleNamespace(rotation=SimpleNamespace(quat=q_xyzw), translation=t)
        image = SimpleNamespace(name="x.jpg", camera_id=2, cam_from_world=lambda: rigid)
        cam = SimpleNamespace(model=SimpleNamespace(name="PINHOLE"), width=10, height=8, params=[5, 5, 5, 4])
    else:
        image = SimpleNamespace(name="x.jpg", camera_id=2, qvec=q_xyzw[[3, 0, 1, 2]], tvec=t)
        cam = SimpleNamespace(model_name="PINHOLE", model=1, width=10, height=8, params=[5, 5, 5, 4])
    return SimpleNamespace(cameras={2: cam}, images={4: image}), q_xyzw[[3, 0, 1, 2]], t


@pytest.mark.parametrize("new_api", [False, True])
def test_pycolmap_adapter_handles_both_api_generations(new_api):
    rec, qvec, tvec = _fake_reconstruction(new_api)
    model = colmap_pycolmap.from_reconstruction(rec)
    assert model.cameras[2] == ColmapCamera(2, "PINHOLE", 10, 8, [5, 5, 5, 4])
    np.testing.assert_allclose(model.images[4].qvec, qvec)
    np.testing.assert_allclose(model.images[4].tvec, tvec)


def test_pycolmap_bridge_reads_our_files_or_names_the_install(tmp_path):
    folder = write_model(sample_model(), tmp_path / "m", ".bin")
    if colmap_pycolmap.pycolmap_available():
        assert colmap_pycolmap.roundtrip_check(folder)
    else:
        with pytest.raises(OptionalDependencyError, match=r"pip install 'semcityloc\[colmap\]'"):
            colmap_pycolmap.read_with_pycolmap(folder)


def test_a_camera_with_its_lens_is_written_as_opencv_or_full_opencv():
    from semcityloc.geometry.distortion import LensDistortion

    camera = Camera(1200.0, 1201.0, 640.5, 480.5, 1280, 960)
    radial = LensDistortion(k1=-0.1, k2=0.02, p1=0.001, p2=-0.0005)
    assert ColmapCamera.from_camera(camera).model == "PINHOLE"
    assert ColmapCamera.from_camera(camera, 1, LensDistortion()).model == "PINHOLE"
    opencv = ColmapCamera.from_camera(camera, 1, radial)
    assert opencv.model == "OPENCV" and list(opencv.params) == [
        1200.0,
        1201.0,
        640.5,
        480.5,
        -0.1,
        0.02,
        0.001,
        -0.0005,
    ]
    full = ColmapCamera.from_camera(camera, 2, LensDistortion(k1=-0.1, k3=0.004))
    assert full.model == "FULL_OPENCV" and list(full.params[8:]) == [0.004, 0.0, 0.0, 0.0]
    pose = Pose.from_xyz_rpy([0.0, 0.0, 50.0], 0.0, 0.0, 0.0)
    model = ColmapModel.from_poses({"a.jpg": (camera, pose), "b.jpg": (camera, pose)}, {"b.jpg": radial})
    assert sorted(c.model for c in model.cameras.values()) == ["OPENCV", "PINHOLE"]  # one lens, one not


@pytest.mark.parametrize("ext", [".txt", ".bin"])
def test_a_model_with_lenses_reads_back_with_them(tmp_path, ext):
    from semcityloc.geometry.distortion import LensDistortion

    camera = Camera(363.7, 363.7, 256.0, 192.0, 512, 384)
    lenses = {"a.jpg": LensDistortion(), "b.jpg": LensDistortion(k1=-0.1, k2=0.02, p1=0.001, p2=-0.0005)}
    lenses["c.jpg"] = LensDistortion(k1=-0.1, k3=0.004)
    pose = Pose.from_xyz_rpy([10.0, -5.0, 80.0], 1.0, 30.0, 45.0)
    written = ColmapModel.from_poses({name: (camera, pose) for name in lenses}, lenses)
    read = read_model(write_model(written, tmp_path / "m", ext=ext)).lens_poses()
    for name, lens in lenses.items():
        cam, back, p = read[name]
        assert cam == camera and back == lens and np.allclose(p.cam_from_world, pose.cam_from_world)
    with pytest.raises(CameraError, match="to_lens_camera"):
        read_model(tmp_path / "m").poses()  # the pinhole reader still refuses a lens, naming the way
    simple = ColmapCamera(1, "SIMPLE_RADIAL", 512, 384, [363.7, 256.0, 192.0, -0.05]).to_lens_camera()
    assert simple == (Camera(363.7, 363.7, 256.0, 192.0, 512, 384), LensDistortion(k1=-0.05))
    rational = ColmapCamera(1, "FULL_OPENCV", 512, 384, [363.7, 363.7, 256, 192, 0, 0, 0, 0, 0, 0.1, 0, 0])
    with pytest.raises(CameraError, match="rational distortion terms"):
        rational.to_lens_camera()
    with pytest.raises(CameraError, match="not a pinhole camera"):
        ColmapCamera(1, "OPENCV_FISHEYE", 512, 384, np.zeros(8)).to_lens_camera()
    with pytest.raises(CameraError):  # folds over inside the image
        ColmapCamera(1, "SIMPLE_RADIAL", 512, 384, [363.7, 256.0, 192.0, -0.5]).to_lens_camera()

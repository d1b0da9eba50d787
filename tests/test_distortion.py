"""Lens distortion (``geometry/distortion.py``): the model, its inverse, and images resampled both ways."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from semcityloc.classes import IGNORE
from semcityloc.errors import CameraError, ShapeError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.distortion import (
    UNDISTORT_TOL_PX,
    LensDistortion,
    distort_image,
    pinhole_canvas,
    undistort_image,
    unseen_by_photo,
)
from semcityloc.geometry.io import read_lens

# A DJI wide camera's DewarpData coefficients (k1, k2, p1, p2, k3), the order OpenCV uses.
DJI = LensDistortion(k1=-0.2698, k2=0.1100, p1=0.0008, p2=-0.0003, k3=-0.0301)
CAMERA = Camera(363.7, 363.7, 256.0, 192.0, 512, 384)


def test_the_model_by_hand():
    radial = LensDistortion(k1=-0.2).distort([0.5, 0.0])  # r2 = 0.25: x (1 - 0.05)
    assert radial == pytest.approx([0.475, 0.0])
    tangential = LensDistortion(p1=0.01).distort([0.5, 0.0])  # y_d = p1 (r2 + 2 y2)
    assert tangential == pytest.approx([0.5, 0.0025])
    other = LensDistortion(p2=0.01).distort([0.0, 0.5])  # x_d = p2 (r2 + 2 x2)
    assert other == pytest.approx([0.0025, 0.5])
    assert LensDistortion.from_params({"f": 1.0, "k": -0.1}) == LensDistortion(k1=-0.1)


def test_undistort_inverts_distort_over_the_image():
    uv = CAMERA.pixel_centers().reshape(-1, 2)
    there = DJI.distorted_pixels(CAMERA, uv)
    assert np.abs(there - uv).max() > 20  # a real wide lens moves the corners by tens of pixels here
    assert np.abs(DJI.pinhole_pixels(CAMERA, there) - uv).max() < 1e-6
    assert DJI.max_inverse_error_px(CAMERA) < UNDISTORT_TOL_PX
    DJI.check(CAMERA)


def _dots(camera: Camera, uv: np.ndarray) -> np.ndarray:
    image = np.zeros((camera.height, camera.width), np.uint8)
    for k, (u, v) in enumerate(uv, 1):
        image[int(v), int(u)] = k
    return image


def test_a_photo_is_resampled_onto_the_pinhole_camera():
    """Points seen by the lens land, once undistorted, where the pinhole projects them."""
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(-0.5, 0.5, (12, 2)), np.ones(12)]) * rng.uniform(20, 90, (12, 1))
    pinhole_uv, _ = CAMERA.project(points)
    xy = points[:, :2] / points[:, 2:]
    photo_uv = np.column_stack([CAMERA.fx, CAMERA.fy]) * DJI.distort(xy) + [CAMERA.cx, CAMERA.cy]
    photo = _dots(CAMERA, photo_uv)
    pinhole = undistort_image(photo, CAMERA, DJI, fill=IGNORE, nearest=True)
    for k, (u, v) in enumerate(pinhole_uv, 1):
        found = np.argwhere(pinhole == k)
        assert len(found) >= 1
        assert np.abs(found.mean(0) + 0.5 - [v, u]).max() <= 1.5  # within the dot's own rounding


def test_round_trip_of_labels_and_the_fill():
    labels = np.random.default_rng(1).integers(0, 5, (48, 64)).repeat(8, 0).repeat(8, 1).astype(np.uint8)
    photo = distort_image(labels, CAMERA, DJI, fill=IGNORE, nearest=True)
    assert (photo[0, 0] == IGNORE) and (photo[192, 256] == labels[192, 256])  # barrel: corners unseen
    assert (photo != labels).mean() > 0.05
    back = undistort_image(photo, CAMERA, DJI, fill=IGNORE, nearest=True)
    seen = back != IGNORE
    assert seen.mean() > 0.9 and (back[seen] == labels[seen]).mean() > 0.97


def test_a_wider_canvas_fills_the_barrel_corners_and_agrees_inside():
    canvas = pinhole_canvas(CAMERA, DJI)
    assert canvas.fx == CAMERA.fx and canvas.width > CAMERA.width and canvas.height > CAMERA.height
    assert canvas.cx - CAMERA.cx == (canvas.width - CAMERA.width) / 2  # the same principal ray
    assert pinhole_canvas(CAMERA, LensDistortion(k1=0.05)) == CAMERA  # pincushion: nothing outside
    assert pinhole_canvas(CAMERA, LensDistortion()) == CAMERA
    # A scene drawn on the canvas: label k in the k-th 8 px column band (so it continues beyond CAMERA).
    u = np.arange(canvas.width) - (canvas.cx - CAMERA.cx)
    wide = np.tile((np.floor(u / 8) % 5).astype(np.uint8), (canvas.height, 1))
    mx, my = int(canvas.cx - CAMERA.cx), int(canvas.cy - CAMERA.cy)
    narrow = wide[my : my + CAMERA.height, mx : mx + CAMERA.width]
    photo = distort_image(wide, CAMERA, DJI, fill=IGNORE, nearest=True, source=canvas)
    assert photo.shape == (CAMERA.height, CAMERA.width) and (photo != IGNORE).all()  # corners seen
    alone = distort_image(narrow, CAMERA, DJI, fill=IGNORE, nearest=True)
    seen = alone != IGNORE
    assert not seen[0, 0] and (photo[seen] == alone[seen]).all()  # the same where both see
    with pytest.raises(ShapeError, match="canvas"):
        distort_image(narrow, CAMERA, DJI, fill=IGNORE, nearest=True, source=canvas)


def test_a_photo_keeps_its_dtype_and_any_resolution_works():
    photo = np.random.default_rng(2).integers(0, 256, (96, 128, 3)).astype(np.uint8)  # a quarter the size
    out = undistort_image(photo, CAMERA, DJI, fill=0, nearest=False)
    assert out.shape == photo.shape and out.dtype == np.uint8
    depth = np.full((384, 512), 50.0, np.float32)
    depth[:10] = np.nan
    out = undistort_image(depth, CAMERA, LensDistortion(k1=0.05), fill=np.nan, nearest=True)
    assert out.dtype == np.float32 and np.isnan(out[0, 0]) and out[192, 256] == 50.0  # pincushion: corners


def test_no_distortion_changes_nothing():
    labels = np.arange(12, dtype=np.uint8).reshape(3, 4)
    cam = Camera(4.0, 4.0, 2.0, 1.5, 4, 3)
    assert undistort_image(labels, cam, LensDistortion(), fill=IGNORE, nearest=True) is labels
    assert LensDistortion().is_zero and not DJI.is_zero


def test_bad_coefficients_and_shapes_are_refused():
    with pytest.raises(CameraError, match="k1"):
        LensDistortion(k1=float("nan"))
    with pytest.raises(CameraError, match="p2"):
        LensDistortion(p2="0.1")
    with pytest.raises(CameraError, match="cannot be inverted"):
        LensDistortion(k1=-1.5).check(CAMERA)  # folds over inside the image
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a hostile value: refused, without numpy's overflow warnings
        with pytest.raises(CameraError, match="cannot be inverted"):
            LensDistortion(k1=1e308).check(CAMERA)
    with pytest.raises(ShapeError):
        undistort_image(np.zeros((2, 3, 4, 5)), CAMERA, DJI, fill=0, nearest=True)
    with pytest.raises(ShapeError):
        DJI.distort(np.zeros((4, 3)))


def test_read_lens_reads_colmap_and_json_distortion(tmp_path):
    camera, lens = read_lens("1 OPENCV 5280 3956 3700 3700 2640 1978 -0.27 0.11 0.0008 -0.0003")
    assert camera.size == (5280, 3956) and lens == LensDistortion(-0.27, 0.11, 0.0008, -0.0003, 0.0)
    camera, lens = read_lens("1 SIMPLE_RADIAL 640 512 1125 320 256 0.01", width=320, height=256)
    assert camera.fx == pytest.approx(562.5) and lens == LensDistortion(k1=0.01)  # same at any size
    full = "FULL_OPENCV 640 512 1125 1125 320 256 -0.1 0.01 0 0 0.002 0 0 0"
    assert read_lens(full)[1] == LensDistortion(k1=-0.1, k2=0.01, k3=0.002)
    path = tmp_path / "camera.json"
    path.write_text(json.dumps({**CAMERA.as_dict(), **DJI.as_dict()}))
    assert read_lens(path) == (CAMERA, DJI)
    assert read_lens("363.7,363.7,256,192,512,384") == (CAMERA, LensDistortion())
    with pytest.raises(CameraError, match=r"camera.json.*cannot be inverted"):
        path.write_text(json.dumps({**CAMERA.as_dict(), "k1": -1.5}))
        read_lens(path)
    with pytest.raises(CameraError, match=r"camera.json: 'k2' must be a number"):
        path.write_text(json.dumps({**CAMERA.as_dict(), "k2": "big"}))
        read_lens(path)


def test_unseen_by_photo_is_a_pincushion_border_only():
    assert not unseen_by_photo((384, 512), CAMERA, DJI).any()  # barrel: the photo sees more than the pinhole
    assert not unseen_by_photo((384, 512), CAMERA, LensDistortion()).any()
    unseen = unseen_by_photo((96, 128), CAMERA, LensDistortion(k1=0.08))  # any resolution
    assert unseen[0, 0] and unseen[-1, -1] and unseen[48, 0] and not unseen[48, 64]
    assert not unseen[10:-10, 10:-10].any() and 0.01 < unseen.mean() < 0.2

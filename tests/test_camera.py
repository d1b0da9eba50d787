"""Camera intrinsics: validation, scaling, pixel-centre convention, projection and rays."""

from __future__ import annotations

import math

import numpy as np
import pytest

from semcityloc.errors import ArgumentTypeError, CameraError, ShapeError
from semcityloc.geometry.camera import Camera

LODLOC_K34 = np.array([[1125.0, 0.0, 320.0, 0.0], [0.0, 1125.0, 256.0, 0.0], [0.0, 0.0, 1.0, 0.0]])


def random_points_in_view(camera: Camera, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    uv = rng.uniform([0, 0], [camera.width, camera.height], (n, 2))
    return camera.unproject(uv, rng.uniform(1.0, 500.0, n))


# ------------------------------------------------------------------------------------- construction
def test_from_K_3x4_equals_3x3():
    a = Camera.from_K(LODLOC_K34, 640, 512)
    b = Camera.from_K(LODLOC_K34[:, :3], 640, 512)
    assert a == b
    assert (a.fx, a.fy, a.cx, a.cy, a.width, a.height) == (1125.0, 1125.0, 320.0, 256.0, 640, 512)
    np.testing.assert_array_equal(a.K, LODLOC_K34[:, :3])
    assert Camera.from_K(a.K, *a.size) == a


def test_from_K_bad_shape_and_skew():
    with pytest.raises(ShapeError):
        Camera.from_K(np.eye(4), 10, 10)
    skewed = LODLOC_K34[:, :3].copy()
    skewed[0, 1] = 3.0
    with pytest.raises(CameraError, match="skew"):
        Camera.from_K(skewed, 640, 512)


def test_from_fov_round_trip():
    cam = Camera.from_fov(640, 480, 70.0)
    assert math.isclose(cam.hfov_deg, 70.0, rel_tol=1e-12)
    assert cam.fx == cam.fy and (cam.cx, cam.cy) == (320.0, 240.0)
    assert math.isclose(cam.vfov_deg, math.degrees(2 * math.atan(240 / cam.fy)), rel_tol=1e-12)
    for bad in (0.0, 180.0, -5.0):
        with pytest.raises(CameraError):
            Camera.from_fov(640, 480, bad)
    with pytest.raises(CameraError, match=r"looks like radians.*math.degrees\(1.2\) = 68.8"):
        Camera.from_fov(640, 480, 1.2)  # math.radians(68.8): built a 1.2 degree camera silently
    assert math.isclose(Camera.from_fov(640, 480, 3.2).hfov_deg, 3.2)
    with pytest.raises(CameraError, match=r"looks like radians \(at most pi\): give degrees in \(0, 180\)$"):
        Camera.from_fov(640, 480, math.pi)  # suggested math.degrees(pi) = 180.0, itself refused
    with pytest.raises(ArgumentTypeError, match="must be a number of degrees, got '70'"):
        Camera.from_fov(640, 480, "70")  # a bare TypeError from the comparison


@pytest.mark.parametrize(
    "kwargs",
    [
        {"fx": 0.0},
        {"fy": -1.0},
        {"fx": float("nan")},
        {"cx": float("inf")},
        {"cy": float("nan")},
        {"width": 0},
        {"height": -4},
        {"width": 640.5},
        {"height": "512"},
        {"fx": "1000"},
    ],
)
def test_invalid_intrinsics_raise(kwargs):
    params = {"fx": 1000.0, "fy": 1000.0, "cx": 320.0, "cy": 256.0, "width": 640, "height": 512} | kwargs
    with pytest.raises(CameraError):
        Camera(**params)


@pytest.mark.parametrize("name", ["fx", "fy", "cx", "cy", "width", "height"])
def test_a_bool_is_no_camera_parameter(name):
    """Stop 56's audit: ``Camera(True, 300, 256, 192, 512, 384)`` was a camera of fx = 1.0 (a bool is an
    int to Python); ``from_fov`` refused bools already."""
    params = {"fx": 300.0, "fy": 300.0, "cx": 256.0, "cy": 192.0, "width": 512, "height": 384}
    with pytest.raises(CameraError, match=f"^camera {name} must be a .*, got True$"):
        Camera(**{**params, name: True})


def test_integer_valued_float_size_is_accepted():
    cam = Camera(1000, 1000, 320, 256, 640.0, 512.0)
    assert (cam.width, cam.height) == (640, 512)
    assert isinstance(cam.width, int) and isinstance(cam.fx, float)


# ------------------------------------------------------------------------------------- scaling
@pytest.mark.parametrize(("w", "h"), [(320, 256), (1280, 1024), (160, 128), (64, 51)])
def test_scaling_keeps_field_of_view_and_maps_points_consistently(w, h):
    cam = Camera.from_K(LODLOC_K34, 640, 512)
    small = cam.scaled(w, h)
    sx, sy = w / 640, h / 512
    assert math.isclose(small.hfov_deg, cam.hfov_deg, rel_tol=1e-12)
    assert math.isclose(small.vfov_deg, cam.vfov_deg, rel_tol=1e-12)
    pts = random_points_in_view(cam, 500, seed=w)
    uv, _ = cam.project(pts)
    uv_s, _ = small.project(pts)
    np.testing.assert_allclose(uv_s[:, 0], uv[:, 0] * sx, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(uv_s[:, 1], uv[:, 1] * sy, rtol=1e-12, atol=1e-9)


def test_pixel_centres_map_across_scales():
    """Pixel j at scale 1 covers pixels 2j and 2j+1 at scale 2: its centre j+0.5 is their shared edge."""
    cam = Camera(500, 500, 320, 256, 640, 512)
    big = cam.scale(2.0)
    assert big.size == (1280, 1024)
    centres = cam.pixel_centers()
    points = cam.unproject(centres, 10.0)
    uv_big, _ = big.project(points)
    np.testing.assert_allclose(uv_big, 2 * centres, atol=1e-9)
    j = 7
    assert uv_big[0, j, 0] == pytest.approx(2 * j + 1)  # edge between big pixels 2j and 2j+1


def test_scale_rounds_to_whole_pixels():
    cam = Camera(500, 500, 320, 256, 640, 512)
    third = cam.scale(1 / 3)
    assert third.size == (213, 171)
    assert math.isclose(third.fx, 500 * 213 / 640)
    assert cam.scale(1e-6).size == (1, 1)


# ------------------------------------------------------------------------------------- geometry
def test_pixel_centres_top_left_is_half_pixel():
    cam = Camera(100, 100, 2, 1.5, 4, 3)
    c = cam.pixel_centers()
    assert c.shape == (3, 4, 2)
    np.testing.assert_array_equal(c[0, 0], [0.5, 0.5])
    np.testing.assert_array_equal(c[2, 3], [3.5, 2.5])


@pytest.mark.parametrize("normalize", [False, True])
def test_ray_directions_reproject_to_pixel_centres(normalize):
    cam = Camera(812.3, 790.1, 301.7, 260.2, 64, 48)
    rays = cam.ray_directions(normalize=normalize)
    assert rays.shape == (48, 64, 3)
    if normalize:
        np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1.0, atol=1e-12)
    else:
        np.testing.assert_array_equal(rays[..., 2], 1.0)
    uv, in_front = cam.project(rays * 37.0)
    assert in_front.all()
    np.testing.assert_allclose(uv, cam.pixel_centers(), atol=1e-9)


def test_principal_point_ray_is_optical_axis():
    cam = Camera(1000, 1000, 2.5, 1.5, 5, 3)  # principal point at the centre of pixel (row 1, col 2)
    rays = cam.ray_directions()
    np.testing.assert_allclose(rays[1, 2], [0, 0, 1], atol=1e-15)


def test_unproject_uses_z_depth():
    cam = Camera(900, 900, 320, 256, 640, 512)
    pts = cam.unproject(np.array([[0.5, 0.5], [639.5, 511.5], [320, 256]]), np.array([2.0, 3.0, 4.0]))
    np.testing.assert_allclose(pts[:, 2], [2.0, 3.0, 4.0])  # z, not the distance along the ray
    assert np.linalg.norm(pts[0]) > 2.0
    uv, _ = cam.project(pts)
    np.testing.assert_allclose(uv, [[0.5, 0.5], [639.5, 511.5], [320, 256]], atol=1e-9)


def test_project_behind_camera_is_masked():
    cam = Camera(900, 900, 320, 256, 640, 512)
    _, in_front = cam.project(np.array([[0.0, 0.0, -5.0], [0.0, 0.0, 0.0], [1.0, 1.0, 5.0]]))
    np.testing.assert_array_equal(in_front, [False, False, True])
    with pytest.raises(ShapeError):
        cam.project(np.zeros((4, 2)))


def test_in_image_bounds_are_half_open():
    cam = Camera(900, 900, 320, 256, 640, 512)
    uv = np.array([[0.0, 0.0], [639.999, 511.999], [640.0, 10.0], [10.0, 512.0], [-1e-9, 5.0]])
    np.testing.assert_array_equal(cam.in_image(uv), [True, True, False, False, False])


def test_as_dict():
    cam = Camera.from_K(LODLOC_K34, 640, 512)
    assert cam.as_dict() == {
        "model": "PINHOLE",
        "width": 640,
        "height": 512,
        "fx": 1125.0,
        "fy": 1125.0,
        "cx": 320.0,
        "cy": 256.0,
    }

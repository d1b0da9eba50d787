"""Pose conventions (LoD-Loc, COLMAP, DJI), pose errors, pose / intrinsics I/O, and the real LoD-Loc demo."""

from __future__ import annotations

import errno
import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semcityloc.errors import CameraError, InputFileError, PoseError, ShapeError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.conventions import (
    colmap_qvec_tvec,
    dji_gimbal_angles,
    dji_world_from_cam,
    lodloc_c2w,
    odm_angles,
    pose_from_colmap,
    pose_from_dji,
    pose_from_lodloc_c2w,
    state_difference,
    wrap_deg,
)
from semcityloc.geometry.errors import center_error_m, rotation_error_deg, yaw_error_deg
from semcityloc.geometry.io import read_intrinsics, read_pose, read_poses, write_pose_json
from semcityloc.geometry.pose import Pose, rotation_about_world_z

GT_POSE = "real_uav_lodloc/GT_pose/DJI_20230513163714_0033_T_pose.txt"
GPS_POSE = "real_uav_lodloc/GPS_pose/DJI_20230513163714_0033_T_pose.txt"
INTRINSIC = "real_uav_lodloc/intrinsic/DJI_20230513163714_0033_T_intrinsic.txt"
POINTS = "real_uav_lodloc/Points_GT/DJI_20230513163714_0033_T_points.npy"


def random_poses(seed: int, n: int, with_special: bool = True) -> Pose:
    """Random poses plus nadir, near-nadir, horizontal and near-horizontal ones."""
    rng = np.random.default_rng(seed)
    roll = rng.uniform(-89.0, 89.0, n)
    pitch = rng.uniform(-179.0, 179.0, n)
    yaw = rng.uniform(-179.0, 179.0, n)
    if with_special:
        special = np.array(
            [
                [0, 0, 0],
                [0, 0, 90],
                [0, 1e-7, -45],
                [0, 90, 0],
                [0, 89.999, 170],
                [0.5, 90.001, -10],
                [0, 0, 180],
            ]
        )
        roll, pitch, yaw = (np.concatenate([a, special[:, i]]) for i, a in enumerate((roll, pitch, yaw)))
    xyz = rng.uniform([-2000, -2000, 0], [2000, 2000, 500], (len(roll), 3))
    return Pose.from_xyz_rpy(xyz, roll, pitch, yaw)


def assert_same_pose(a: Pose, b: Pose, atol_R: float = 1e-10, atol_t: float = 1e-7) -> None:
    np.testing.assert_allclose(a.R, b.R, atol=atol_R)
    np.testing.assert_allclose(a.center, b.center, atol=atol_t)


def quaternion_matrix_wxyz(q: np.ndarray) -> np.ndarray:
    """Hamilton R(q) written out (COLMAP's qvec2rotmat), independent of scipy."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * y * y - 2 * z * z, 2 * x * y - 2 * w * z, 2 * z * x + 2 * w * y],
            [2 * x * y + 2 * w * z, 1 - 2 * x * x - 2 * z * z, 2 * y * z - 2 * w * x],
            [2 * z * x - 2 * w * y, 2 * y * z + 2 * w * x, 1 - 2 * x * x - 2 * y * y],
        ]
    )


# ============================================================================================ helpers
def test_wrap_deg():
    a = np.array([0.0, 180.0, -180.0, 190.0, -190.0, 360.0, 540.0, -540.0, 359.5, 1e-12])
    np.testing.assert_allclose(wrap_deg(a), [0, 180, 180, -170, 170, 0, 180, 180, -0.5, 1e-12], atol=1e-12)
    assert isinstance(wrap_deg(-180.0), float) and wrap_deg(-180.0) == 180.0
    rng = np.random.default_rng(0)
    x = rng.uniform(-5000, 5000, 10000)
    w = wrap_deg(x)
    assert np.all((w > -180) & (w <= 180))
    np.testing.assert_allclose(np.cos(np.radians(w)), np.cos(np.radians(x)), atol=1e-9)
    np.testing.assert_allclose(np.sin(np.radians(w)), np.sin(np.radians(x)), atol=1e-9)


def test_state_difference_wraps_the_angles_as_wrap_deg_and_every_copy_agrees():
    """Stop 51: four inline copies wrapped to [-180, 180), ``wrap_deg`` to (-180, 180]: a difference of
    exactly 180 deg came out with opposite signs depending on which copy ran. One rule now."""
    from semcityloc.benchmark.photo_exports import yaw_moves_deg
    from semcityloc.localization.covariance import state_error
    from semcityloc.localization.refine import top_mean

    a = np.array([[1.0, 2.0, 3.0, 10.0, -20.0, 179.0], [0.0, 0.0, 0.0, 90.0, 0.0, 180.0]])
    b = np.array([0.5, 0.0, 1.0, -10.0, 20.0, -179.0])
    d = state_difference(a, b)
    np.testing.assert_allclose(d[0], [0.5, 2.0, 2.0, 20.0, -40.0, -2.0], atol=1e-12)
    np.testing.assert_array_equal(d[:, 3:], wrap_deg(a[:, 3:] - b[3:]))
    np.testing.assert_allclose(d[1, 3:], [100.0, -20.0, -1.0], atol=1e-12)  # 359 deg: -1
    with pytest.raises(ShapeError, match=r"\(\.\.\., 6\)"):
        state_difference(np.zeros(5), np.zeros(5))
    # Exactly 180 deg apart: +180 everywhere (wrap_deg's interval), whichever user asks.
    centre = np.array([0.0, 0.0, 80.0])
    yaw_0, yaw_180 = Pose.from_xyz_rpy(centre, 0.0, 30.0, 0.0), Pose.from_xyz_rpy(centre, 0.0, 30.0, 180.0)
    assert state_difference([0, 0, 0, 0, 0, 180.0], np.zeros(6))[5] == 180.0
    assert state_error(yaw_180, yaw_0)[5] == pytest.approx(180.0)
    assert yaw_moves_deg([yaw_180], [yaw_0])[0] == pytest.approx(180.0)
    states = np.array([[0.0, 0, 0, 0, 0, 0], [0.0, 0, 0, 0, 0, 180.0]])
    assert top_mean(states, np.array([0.9, 0.8]), 2)[5] == pytest.approx(90.0)  # [-180, 180): -90


def test_rotation_about_world_z():
    np.testing.assert_allclose(
        rotation_about_world_z(90.0) @ [1, 0, 0], [0, 1, 0], atol=1e-15
    )  # east -> north
    angles = np.array([-30.0, 0.0, 45.0, 200.0])
    Rz = rotation_about_world_z(angles)
    assert Rz.shape == (4, 3, 3)
    np.testing.assert_allclose(
        Rz, Rotation.from_euler("z", angles[:, None], degrees=True).as_matrix(), atol=1e-15
    )
    with pytest.raises(PoseError):
        rotation_about_world_z(np.nan)


def test_rotation_about_world_z_matches_pose_rotate_world_z():
    pose = random_poses(1, 20)
    rotated = pose.rotate_world_z(np.full(len(pose), 33.0))
    np.testing.assert_allclose(
        rotated.R_world_from_cam, rotation_about_world_z(33.0) @ pose.R_world_from_cam, atol=1e-12
    )


# ============================================================================================ LoD-Loc
def test_lodloc_c2w_round_trip_batched_and_single():
    pose = random_poses(2, 500)
    T = lodloc_c2w(pose)
    assert T.shape == (507, 4, 4)
    np.testing.assert_array_equal(T[:, 3], np.tile([0, 0, 0, 1.0], (507, 1)))
    assert_same_pose(pose_from_lodloc_c2w(T), pose)
    single = pose_from_lodloc_c2w(T[3])
    assert single.batch_shape == ()
    assert_same_pose(single, pose[3])
    assert_same_pose(pose_from_lodloc_c2w(T[:, :3]), pose)  # 3x4


def _hand_rotation(axis: str, deg: float) -> np.ndarray:
    """The elementary rotation about x, y or z, written out (no scipy)."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return {
        "x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis]


@pytest.mark.parametrize("roll, pitch, yaw", [(0.0, 30.0, 90.0), (0.8, 62.5, -140.0), (-12.0, 3.0, 17.0)])
def test_lodloc_euler_is_our_pitch_roll_yaw_on_hand_built_matrices(roll, pitch, yaw):
    # The module docstring's R_world_from_cam = Rz(yaw) Ry(roll) Rx(pitch) diag(1, -1, -1), multiplied out by
    # hand: LoD-Loc's line on its camera-to-world matrix gives (pitch, roll, yaw), and to_xyz_rpy the same.
    Rwc = _hand_rotation("z", yaw) @ _hand_rotation("y", roll) @ _hand_rotation("x", pitch)
    Rwc = Rwc @ np.diag([1.0, -1.0, -1.0])
    pose = Pose.from_rotation_center(Rwc, [10.0, -20.0, 150.0])
    c2w = lodloc_c2w(pose)
    literal = Rotation.from_matrix(c2w[:3, :3] @ np.diag([1, -1, -1])).as_euler("xyz", degrees=True)
    np.testing.assert_allclose(literal, [pitch, roll, yaw], atol=1e-9)
    np.testing.assert_allclose(pose.to_xyz_rpy(), [10.0, -20.0, 150.0, roll, pitch, yaw], atol=1e-9)


def test_lodloc_bad_matrices():
    T = lodloc_c2w(random_poses(4, 1, with_special=False)[0])
    bad = T.copy()
    bad[3, 0] = 0.5
    with pytest.raises(PoseError, match="last row"):
        pose_from_lodloc_c2w(bad)
    with pytest.raises(ShapeError):
        pose_from_lodloc_c2w(T[:3, :3])
    nan = T.copy()
    nan[0, 3] = np.nan
    with pytest.raises(PoseError, match="non-finite"):
        pose_from_lodloc_c2w(nan)
    scaled = T.copy()
    scaled[:3, :3] *= 1.01
    with pytest.raises(PoseError, match="rotation"):
        pose_from_lodloc_c2w(scaled)


# ============================================================================================ COLMAP
def test_colmap_round_trip_batched():
    pose = random_poses(5, 500)
    qvec, tvec = colmap_qvec_tvec(pose)
    assert qvec.shape == (507, 4) and tvec.shape == (507, 3)
    np.testing.assert_allclose(np.linalg.norm(qvec, axis=1), 1.0, atol=1e-12)
    assert np.all(qvec[:, 0] >= 0)
    back = pose_from_colmap(*qvec.T, *tvec.T)
    assert_same_pose(back, pose)


def test_colmap_matches_written_out_quaternion_and_c2w():
    rng = np.random.default_rng(6)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        t = rng.uniform(-100, 100, 3)
        pose = pose_from_colmap(*q, *t)
        R = quaternion_matrix_wxyz(q)
        np.testing.assert_allclose(pose.R, R, atol=1e-12)
        np.testing.assert_allclose(pose.t, t, atol=1e-12)
        c2w = lodloc_c2w(pose)  # LoD-Loc's trans_euler: R^T, -R^T t
        np.testing.assert_allclose(c2w[:3, :3], R.T, atol=1e-12)
        np.testing.assert_allclose(c2w[:3, 3], -R.T @ t, atol=1e-9)
        # q and -q are the same rotation.
        assert_same_pose(pose_from_colmap(*(-q), *t), pose)


def test_colmap_identity_and_single_shapes():
    pose = pose_from_colmap(1, 0, 0, 0, 1, 2, 3)
    assert pose.batch_shape == ()
    np.testing.assert_array_equal(pose.R, np.eye(3))
    np.testing.assert_allclose(pose.center, [-1, -2, -3])
    qvec, tvec = colmap_qvec_tvec(pose)
    np.testing.assert_allclose(qvec, [1, 0, 0, 0])
    np.testing.assert_allclose(tvec, [1, 2, 3])


def test_colmap_rejects_non_unit_and_nan():
    with pytest.raises(PoseError, match="unit norm"):
        pose_from_colmap(0, 0, 0, 0, 1, 2, 3)
    with pytest.raises(PoseError, match="unit norm"):
        pose_from_colmap(1, 1, 0, 0, 1, 2, 3)
    with pytest.raises(PoseError, match="non-finite"):
        pose_from_colmap(1, 0, 0, 0, np.nan, 2, 3)
    # Rounded text quaternions are fine.
    pose_from_colmap(0.70711, 0.70711, 0, 0, 0, 0, 0)


# ============================================================================================ DJI
def test_dji_nadir_north_up_is_our_zero():
    pose = pose_from_dji([10, 20, 150], 0, -90, 0)
    np.testing.assert_allclose(pose.to_xyz_rpy(), [10, 20, 150, 0, 0, 0], atol=1e-9)
    np.testing.assert_allclose(pose.viewing_direction, [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(-pose.R_world_from_cam[:, 1], [0, 1, 0], atol=1e-12)  # image up = north


def test_dji_yaw_east_horizontal():
    pose = pose_from_dji([0, 0, 0], 90, 0, 0)
    np.testing.assert_allclose(pose.viewing_direction, [1, 0, 0], atol=1e-12)  # optical axis east
    np.testing.assert_allclose(pose.R_world_from_cam[:, 0], [0, -1, 0], atol=1e-12)  # image right = south
    np.testing.assert_allclose(pose.R_world_from_cam[:, 1], [0, 0, -1], atol=1e-12)  # image down = down
    _, _, _, roll, pitch, yaw = pose.to_xyz_rpy()
    assert (roll, pitch, yaw) == pytest.approx((0, 90, -90), abs=1e-9)


def test_dji_north_45_down():
    pose = pose_from_dji([0, 0, 0], 0, -45, 0)
    r = np.sqrt(0.5)
    np.testing.assert_allclose(pose.viewing_direction, [0, r, -r], atol=1e-12)
    np.testing.assert_allclose(pose.to_xyz_rpy()[3:], [0, 45, 0], atol=1e-9)


def test_dji_roll_right_side_down():
    pose = pose_from_dji([0, 0, 0], 0, 0, 30)  # looking north, horizontal, rolled 30 right-side-down
    s, c = 0.5, np.sqrt(3) / 2
    np.testing.assert_allclose(pose.viewing_direction, [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(pose.R_world_from_cam[:, 0], [c, 0, -s], atol=1e-12)  # image right dips


def test_dji_nadir_yaw_is_image_up_heading():
    pose = pose_from_dji([0, 0, 0], 30, -90, 0)
    up = -pose.R_world_from_cam[:, 1]
    heading = np.degrees(np.arctan2(up[0], up[1]))  # clockwise from north
    assert heading == pytest.approx(30.0)
    assert pose.to_xyz_rpy()[5] == pytest.approx(-30.0)


def test_dji_to_our_angles_without_roll():
    rng = np.random.default_rng(7)
    n = 400
    dyaw = rng.uniform(-180, 180, n)
    dpitch = rng.uniform(-90, 0, n)
    pose = pose_from_dji(rng.normal(size=(n, 3)), dyaw, dpitch, 0.0)
    ours = pose.to_xyz_rpy()
    np.testing.assert_allclose(ours[:, 3], 0.0, atol=1e-9)
    np.testing.assert_allclose(ours[:, 4], 90 + dpitch, atol=1e-9)
    np.testing.assert_allclose(wrap_deg(ours[:, 5] + dyaw), 0.0, atol=1e-9)  # our yaw = -dji yaw mod 360


def test_dji_closed_form_matches_composition():
    rng = np.random.default_rng(8)
    y, p, r = rng.uniform(-180, 180, 200), rng.uniform(-90, 30, 200), rng.uniform(-40, 40, 200)
    F = np.diag([1.0, -1.0, -1.0])
    Rz = Rotation.from_euler("z", -y[:, None], degrees=True).as_matrix()
    Rx = Rotation.from_euler("x", 90 + p[:, None], degrees=True).as_matrix()
    Rroll = Rotation.from_euler("z", r[:, None], degrees=True).as_matrix()
    np.testing.assert_allclose(dji_world_from_cam(y, p, r), Rz @ Rx @ F @ Rroll, atol=1e-12)


def test_dji_round_trip():
    rng = np.random.default_rng(9)
    n = 500
    ypr = np.stack([rng.uniform(-179, 179, n), rng.uniform(-89, 60, n), rng.uniform(-60, 60, n)], 1)
    pose = pose_from_dji(np.zeros(3), *ypr.T)
    assert pose.batch_shape == (n,)
    np.testing.assert_allclose(dji_gimbal_angles(pose), ypr, atol=1e-7)
    # At the gimbal lock (nadir) the angles differ but the rotation comes back.
    nadir = pose_from_dji([1, 2, 3], 40, -90, 25)
    again = dji_gimbal_angles(nadir)
    assert_same_pose(pose_from_dji([1, 2, 3], *again), nadir, atol_R=1e-7)


def test_dji_bad_input():
    with pytest.raises(PoseError):
        pose_from_dji([0, 0, 0], np.nan, -90, 0)
    with pytest.raises(ShapeError):
        pose_from_dji([0, 0], 0, -90, 0)


# ============================================================================================ errors
def test_center_error():
    a = Pose.from_xyz_rpy([0, 0, 0], 0, 0, 0)
    b = Pose.from_xyz_rpy([3, 4, 12], 10, 20, 30)
    assert center_error_m(a, b) == pytest.approx(13.0)
    batch = random_poses(10, 30)
    np.testing.assert_allclose(center_error_m(batch, batch), 0.0, atol=1e-9)
    assert center_error_m(batch, a).shape == (37,)


def test_rotation_error_known_angles():
    rng = np.random.default_rng(11)
    base = random_poses(12, 300)
    angles = np.concatenate([rng.uniform(0, 180, 300), [0, 1e-5, 1e-3, 90, 179.9999, 180, 45, 0.5]])[:307]
    axes = rng.normal(size=(307, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    delta = Rotation.from_rotvec(axes * np.radians(angles)[:, None]).as_matrix()
    # Perturb in the camera frame and in the world frame: the error is the same angle.
    est_cam = Pose(delta @ base.R, base.t)
    est_world = Pose.from_rotation_center(delta @ base.R_world_from_cam, base.center)
    np.testing.assert_allclose(rotation_error_deg(est_cam, base), angles, atol=1e-6)
    np.testing.assert_allclose(rotation_error_deg(est_world, base), angles, atol=1e-6)
    np.testing.assert_allclose(rotation_error_deg(base, est_cam), angles, atol=1e-6)  # symmetric


def test_rotation_error_tiny_angles_are_accurate():
    base = Pose.from_xyz_rpy([0, 0, 0], 1, 2, 3)
    for deg in (1e-6, 1e-4, 1e-2):
        est = Pose.from_xyz_rpy([0, 0, 0], 1, 2, 3 + deg)
        assert rotation_error_deg(est, base) == pytest.approx(deg, rel=1e-4)
    assert rotation_error_deg(base, base) == 0.0


def test_yaw_error_wraps():
    a = Pose.from_xyz_rpy([0, 0, 0], 0, 30, 179)
    b = Pose.from_xyz_rpy([0, 0, 0], 0, 30, -179)
    assert yaw_error_deg(a, b) == pytest.approx(2.0)
    c = Pose.from_xyz_rpy([0, 0, 0], 0, 0, 90)
    d = Pose.from_xyz_rpy([0, 0, 0], 0, 0, -90)
    assert yaw_error_deg(c, d) == pytest.approx(180.0)
    batch = random_poses(13, 50)
    turned = batch.rotate_world_z(np.full(len(batch), -7.5))
    np.testing.assert_allclose(yaw_error_deg(turned, batch), 7.5, atol=1e-8)
    np.testing.assert_allclose(rotation_error_deg(turned[:50], batch[:50]), 7.5, atol=1e-8)


# ============================================================================================ pose I/O
def test_read_pose_all_forms_agree(tmp_path):
    pose = random_poses(14, 1, with_special=False)[0]
    x, y, z, roll, pitch, yaw = pose.to_xyz_rpy()
    qvec, tvec = colmap_qvec_tvec(pose)
    c2w = lodloc_c2w(pose)
    txt = tmp_path / "x_pose.txt"
    np.savetxt(txt, c2w)
    specs = {
        "lodloc file": txt,
        "lodloc file as str": str(txt),
        "3x4 text": "\n".join(" ".join(repr(float(v)) for v in row) for row in c2w[:3]),
        "16 numbers": " ".join(repr(float(v)) for v in c2w.ravel()),
        "colmap named": "img.jpg " + " ".join(repr(float(v)) for v in [*qvec, *tvec]),
        "colmap bare": " ".join(repr(float(v)) for v in [*qvec, *tvec]),
        "inline rpy": ",".join(repr(float(v)) for v in (x, y, z, roll, pitch, yaw)),
        "json c2w": json.dumps({"world_from_cam": c2w.tolist()}),
        "json w2c": json.dumps({"cam_from_world": pose.cam_from_world.tolist()}),
        "json rpy": json.dumps({"xyz": [x, y, z], "roll": roll, "pitch": pitch, "yaw": yaw}),
        "json q": json.dumps({"qvec": qvec.tolist(), "tvec": tvec.tolist()}),
    }
    for what, spec in specs.items():
        got = read_pose(spec)
        assert got.batch_shape == (), what
        assert_same_pose(got, pose, atol_R=1e-9, atol_t=1e-6)


def test_read_pose_multi_line_files(tmp_path):
    poses = random_poses(15, 3, with_special=False)
    names = ["a/DJI_1.JPG", "DJI_2.JPG", "DJI_3.JPG"]
    lines = []
    for i, name in enumerate(names):
        q, t = colmap_qvec_tvec(poses[i])
        lines.append(name + " " + " ".join(repr(float(v)) for v in [*q, *t]))
    path = tmp_path / "GT_pose.txt"
    path.write_text("# LoD-Loc style\n" + "\n".join(lines) + "\n")
    assert list(read_poses(path)) == names
    assert_same_pose(read_pose(path, name="DJI_2.JPG"), poses[1])
    assert_same_pose(read_pose(path, name="DJI_1.JPG"), poses[0])  # by file name
    assert_same_pose(read_pose(path, name="DJI_3"), poses[2])  # by stem
    with pytest.raises(
        PoseError, match=r"choose one by its image name \(read_pose\(\.\.\., name=.NAME.\)\)"
    ) as exc:
        read_pose(path)
    assert str(path) in str(exc.value)
    with pytest.raises(PoseError, match="no pose for image 'nope.JPG'"):
        read_pose(path, name="nope.JPG")
    ambiguous = tmp_path / "two.txt"
    ambiguous.write_text(lines[1] + "\n" + lines[1].replace("DJI_2.JPG", "DJI_2.png") + "\n")
    with pytest.raises(PoseError, match="ambiguous"):
        read_pose(ambiguous, name="DJI_2")
    assert_same_pose(read_pose(ambiguous, name="DJI_2.png"), poses[1])


def test_read_pose_colmap_images_txt(tmp_path):
    poses = random_poses(16, 2, with_special=False)
    text = [
        "# Image list with two lines of data per image:",
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
    ]
    for i in range(2):
        q, t = colmap_qvec_tvec(poses[i])
        text.append(f"{i + 1} " + " ".join(repr(float(v)) for v in [*q, *t]) + f" 1 img{i}.jpg")
        text.append("" if i == 0 else "12.5 30.25 -1 100.0 7.0 4")
    path = tmp_path / "images.txt"
    path.write_text("\n".join(text) + "\n")
    assert_same_pose(read_pose(path, name="img1.jpg"), poses[1])
    assert_same_pose(read_pose(path, name="img0.jpg"), poses[0])


@pytest.mark.parametrize(
    ("spec", "error", "message"),
    [
        ("missing_pose.txt", InputFileError, "no such pose file"),
        ("", PoseError, "empty"),
        ("1,2,3", PoseError, "3 numbers is not a pose"),
        ("1,2,3,0,0,x", PoseError, "non-numeric value 'x'"),
        ("1,2,3,0,nan,0", PoseError, "non-finite"),
        ("{not json", InputFileError, "invalid JSON"),
        ("[1, 2]", PoseError, "pose JSON must be an object, got list"),
        ('{"foo": 1}', PoseError, "pose JSON needs"),
        ('{"xyz": [1, 2, 3], "roll": 0}', PoseError, "missing pitch, yaw"),
        ('{"xyz": [1, 2], "roll": 0, "pitch": 0, "yaw": 0}', PoseError, "list of 3 numbers"),
        ('{"xyz": [1, 2, 3], "roll": "0", "pitch": 0, "yaw": 0}', PoseError, "must be a number"),
        ('{"world_from_cam": [[1, 0], [0, 1]]}', ShapeError, "4x4 or 3x4"),
        ('{"world_from_cam": [[2,0,0,0],[0,2,0,0],[0,0,2,0],[0,0,0,1]]}', PoseError, "not a rotation"),
        ('{"world_from_cam": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,1,1]]}', PoseError, "last row"),
        ('{"qvec": [1, 0, 0, 0]}', PoseError, "needs 'tvec'"),
        ('{"qvec": [2, 0, 0, 0], "tvec": [0, 0, 0]}', PoseError, "unit norm"),
        ("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 2", PoseError, "last row"),
        ("img 1 0 0 0 1 2", PoseError, "has 6 numbers"),
        ("img 1 0 0 0 1 2 3\n1 0 0 0 1 2 3", PoseError, "mixes named and unnamed"),
    ],
)
def test_read_pose_errors_name_the_input(spec, error, message):
    with pytest.raises(error, match=message) as exc:
        read_pose(spec)
    text = str(exc.value)
    assert "\n" not in text
    if spec:
        assert spec.split()[0][:10] in text


def test_read_pose_file_errors(tmp_path):
    binary = tmp_path / "image.jpg"
    binary.write_bytes(b"\xff\xd8\xff\xe0" + bytes(range(256)))
    with pytest.raises(InputFileError, match="not a UTF-8 text file") as exc:
        read_pose(binary)
    assert str(binary) in str(exc.value)
    folder = tmp_path / "dir"
    folder.mkdir()
    with pytest.raises(InputFileError, match="cannot read|no such"):
        read_pose(folder)
    bad = tmp_path / "bad_pose.txt"
    bad.write_text("1 2 3\n4 5 6\n")
    with pytest.raises(PoseError) as exc:
        read_pose(bad)
    assert str(exc.value).startswith(str(bad))
    with pytest.raises(PoseError, match="path or a string"):
        read_pose(12)


def test_write_pose_json_round_trip_with_origin(tmp_path):
    origin = np.array([391234.0, 5817456.0, 0.0])
    local = Pose.from_xyz_rpy([12.25, -40.5, 180.0], 1.5, 35.0, -120.0)
    path = tmp_path / "pose.json"
    data = write_pose_json(
        path, pose_local=local, origin_world=origin, crs="EPSG:25833", extra={"score": np.float32(0.5)}
    )
    on_disk = json.loads(path.read_text())
    assert on_disk == data
    assert data["frame"] == "crs" and data["crs"] == "EPSG:25833" and data["extra"] == {"score": 0.5}
    assert data["position"] == pytest.approx([391246.25, 5817415.5, 180.0], rel=0, abs=1e-8)  # float64
    assert data["position_local"] == pytest.approx([12.25, -40.5, 180.0])
    assert [data["roll"], data["pitch"], data["yaw"]] == pytest.approx([1.5, 35.0, -120.0], abs=1e-9)
    back = read_pose(path)  # in the CRS frame
    np.testing.assert_allclose(back.center, local.center + origin, rtol=0, atol=1e-7)  # a few ulps at 6e6
    assert_same_pose(back.shift_world(origin), local, atol_t=1e-8)
    # The COLMAP fields of the same file give the same pose.
    q_only = read_pose(json.dumps({"qvec": data["qvec_wxyz"], "tvec": data["tvec"]}))
    assert_same_pose(q_only, back, atol_t=1e-6)


def test_write_pose_json_without_origin_and_errors(tmp_path):
    pose = Pose.from_xyz_rpy([1.0, 2.0, 3.0], 0, 10, 20)
    data = write_pose_json(tmp_path / "p.json", pose_world=pose)
    assert data["frame"] == "model" and "origin" not in data and "crs" not in data
    assert_same_pose(read_pose(tmp_path / "p.json"), pose)
    with pytest.raises(ShapeError, match="one pose"):
        write_pose_json(tmp_path / "b.json", pose_world=random_poses(17, 2))
    with pytest.raises(ShapeError, match="origin_world"):
        write_pose_json(tmp_path / "b.json", pose_local=pose, origin_world=[1.0, 2.0])
    with pytest.raises(ShapeError, match="JSON-serialisable"):
        write_pose_json(tmp_path / "b.json", pose_world=pose, extra={"x": object()})
    with pytest.raises(InputFileError, match="cannot write"):
        write_pose_json(tmp_path / "no_dir" / "p.json", pose_world=pose)


def test_a_pose_json_is_strict_json_and_written_whole(tmp_path, monkeypatch):
    """``extra`` holding NaN (a refused pose's depth cost, a run without depth) was written as ``NaN``
    tokens, which jq and JavaScript refuse; and a failed write left half a file."""
    pose = Pose.from_xyz_rpy([1.0, 2.0, 3.0], 0, 10, 20)
    data = write_pose_json(
        tmp_path / "p.json", pose_world=pose, extra={"depth_cost": float("nan"), "a": [np.inf, 1.0]}
    )
    assert math.isnan(data["extra"]["depth_cost"])  # the returned dict keeps the value

    def no_constants(name):
        raise AssertionError(f"{name} in a pose file")

    written = json.loads((tmp_path / "p.json").read_text(), parse_constant=no_constants)
    assert written["extra"] == {"depth_cost": None, "a": [None, 1.0]}
    assert_same_pose(read_pose(tmp_path / "p.json"), pose)
    from semcityloc.io import files

    def full_disk(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(files.os, "fsync", full_disk)
    with pytest.raises(InputFileError, match="cannot write pose JSON: No space left"):
        write_pose_json(tmp_path / "p.json", pose_world=Pose.from_xyz_rpy([9.0, 9.0, 9.0], 0, 0, 0))
    assert_same_pose(read_pose(tmp_path / "p.json"), pose)  # the old file whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.json"]


def test_inconsistent_json_matrices_are_rejected():
    pose = random_poses(18, 1, with_special=False)[0]
    other = pose.rotate_world_z(1.0)
    spec = json.dumps(
        {"world_from_cam": pose.world_from_cam.tolist(), "cam_from_world": other.cam_from_world.tolist()}
    )
    with pytest.raises(PoseError, match="not inverses"):
        read_pose(spec)


# ============================================================================================ intrinsics I/O
def test_read_intrinsics_forms(tmp_path):
    k34 = tmp_path / "x_intrinsic.txt"
    np.savetxt(k34, np.array([[1125.0, 0, 320, 0], [0, 1125, 256, 0], [0, 0, 1, 0]]))
    expected = Camera(1125, 1125, 320, 256, 640, 512)
    specs = {
        "lodloc 3x4 file": k34,
        "3x3 text": "1125 0 320\n0 1125 256\n0 0 1",
        "colmap line": "DJI.JPG PINHOLE 640 512 1125 1125 320 256",
        "colmap cameras.txt line": "1 PINHOLE 640 512 1125 1125 320 256",
        "model first": "PINHOLE 640 512 1125 1125 320 256",
        "simple pinhole": "DJI.JPG SIMPLE_PINHOLE 640 512 1125 320 256",
        "zero distortion": "1 OPENCV 640 512 1125 1125 320 256 0 0 0 0",
        "json": json.dumps(expected.as_dict()),
        "json K": json.dumps({"K": expected.K.tolist(), "width": 640, "height": 512}),
        "json K no size": json.dumps({"K": expected.K.tolist()}),
        "inline": "1125,1125,320,256,640,512",
        "inline 4": "1125,1125,320,256",
    }
    for what, spec in specs.items():
        assert read_intrinsics(spec) == expected, what


def test_read_intrinsics_size_rules():
    # LoD-Loc K: size from the arguments when given, else 2cx x 2cy.
    k = "1000 0 320 0\n0 1000 256 0\n0 0 1 0"
    assert read_intrinsics(k, width=700).size == (700, 512)
    # Own size + requested size: resampled, same field of view.
    cam = read_intrinsics("a PINHOLE 5280 3956 3778.4 3767.4 2663.6 1919.7", width=1320, height=989)
    assert cam.size == (1320, 989)
    assert cam.fx == pytest.approx(3778.4 / 4) and cam.cx == pytest.approx(2663.6 / 4)
    with pytest.raises(CameraError, match="both width and height"):
        read_intrinsics("a PINHOLE 5280 3956 3778.4 3767.4 2663.6 1919.7", width=1320)
    with pytest.raises(CameraError, match="cannot infer the image width from cx=2663.6") as exc:
        read_intrinsics("3778.4 0 2663.6\n0 3767.4 1919.7\n0 0 1")
    assert "pass the image width" in str(exc.value)
    with pytest.raises(CameraError, match="positive integer"):
        read_intrinsics(k, width=0)


def test_intrinsics_of_another_image_do_not_fit_a_photo(tmp_path):
    """Stop 50's audit: the thermal camera's K (640x512, cx 320, cy 256) was used on a 2325x1742 photo with
    no check. Read for a photo, intrinsics must be of its size or of it resized, with a principal point
    within ``PRINCIPAL_POINT_TOLERANCE`` of the centre; else a typed error naming file, photo and sizes."""
    from semcityloc.errors import IntrinsicsMismatchError
    from semcityloc.geometry.camera import PRINCIPAL_POINT_TOLERANCE

    k = tmp_path / "T_intrinsic.txt"
    np.savetxt(k, np.array([[1125.0, 0, 320, 0], [0, 1125, 256, 0], [0, 0, 1, 0]]))
    photo = ("D.JPG", 2325, 1742)
    with pytest.raises(IntrinsicsMismatchError, match="principal point") as exc:
        read_intrinsics(k, 2325, 1742, photo=photo)
    said = str(exc.value)
    assert said.startswith(f"{k}: ") and "photo D.JPG (2325x1742" in said and "640x512 image" in said
    stated = '{"fx": 1125, "fy": 1125, "cx": 320, "cy": 256, "width": 640, "height": 512}'
    with pytest.raises(
        IntrinsicsMismatchError, match=r"of a 640x512 image do not fit photo D\.JPG \(2325x1742\)"
    ):
        read_intrinsics(stated, 2325, 1742, photo=photo)
    # The same image resized (each side rounded): rescaled, as before; its own size: as it is.
    assert read_intrinsics(stated, 1280, 1024, photo=("T.JPG", 1280, 1024)) == Camera(
        2250, 2250, 640, 512, 1280, 1024
    )
    big = "a PINHOLE 5280 3956 3778.4 3767.4 2663.6 1919.7"
    assert read_intrinsics(big, 1320, 989, photo=("s.JPG", 1320, 989)).size == (1320, 989)
    assert read_intrinsics(k, 640, 512, photo=("T.JPG", 640, 512)).cx == 320
    # The bound: a principal point just within it fits, just beyond it does not.
    within = 320 + (PRINCIPAL_POINT_TOLERANCE - 0.001) * 640
    assert read_intrinsics(f"1125,1125,{within},256,640,512", photo=("T.JPG", 640, 512)).cx == within
    beyond = 320 + (PRINCIPAL_POINT_TOLERANCE + 0.001) * 640
    with pytest.raises(IntrinsicsMismatchError, match="principal point"):
        read_intrinsics(f"1125,1125,{beyond},256,640,512", photo=("T.JPG", 640, 512))
    # Without a photo (render at a chosen size): resampled to any size, as before.
    assert read_intrinsics(stated, 2325, 1742).size == (2325, 1742)
    # A LoD-Loc K states no size: a photo that is its 2 cx x 2 cy resized by an exact factor (a downscaled
    # copy) takes it rescaled, as a stated size is (stop 55 audit: refused, principal point 50 % off).
    assert read_intrinsics(k, 320, 256, photo=("h.JPG", 320, 256)) == Camera(562.5, 562.5, 160, 128, 320, 256)
    assert read_intrinsics(k, 1280, 1024, photo=("T.JPG", 1280, 1024)) == Camera(
        2250, 2250, 640, 512, 1280, 1024
    )


def test_read_intrinsics_multi_camera_file(tmp_path):
    path = tmp_path / "intrinsic.txt"
    path.write_text("a.JPG PINHOLE 640 512 1125 1125 320 256\nb.JPG PINHOLE 1280 1024 2250 2250 640 512\n")
    assert read_intrinsics(path, name="b.JPG").size == (1280, 1024)
    assert read_intrinsics(path, name="a").size == (640, 512)
    with pytest.raises(CameraError, match="pass the image name"):
        read_intrinsics(path)


@pytest.mark.parametrize(
    ("spec", "error", "message"),
    [
        ("missing_intrinsic.txt", InputFileError, "no such intrinsics file"),
        ("0,1125,320,256,640,512", CameraError, "focal lengths must be positive"),
        ("-5,-5,320,256,640,512", CameraError, "focal lengths must be positive"),
        ("1125,1125,320,256,0,512", CameraError, "width must be a positive integer"),
        ("1125,1125,nan,256,640,512", CameraError, "finite"),
        ("1125,1125,320,256,640.5,512", CameraError, "whole pixels"),
        ("1 2 3", CameraError, "not intrinsics"),
        ("a PINHOLE 640 512 1125 1125 320", CameraError, "needs 'w h fx fy cx cy'"),
        ("a FISHEYE 640 512 1125 1125 320", CameraError, "unsupported camera model 'FISHEYE'"),
        ("a SIMPLE_RADIAL 640 512 1125 320 256 0.01", CameraError, "non-zero lens distortion.*undistort"),
        ("a FULL_OPENCV 640 512 1125 1125 320 256 0 0 0 0 0 0.1 0 0", CameraError, "rational .*k4=0.1"),
        ("1125 5 320\n0 1125 256\n0 0 1", CameraError, "skewed"),
        ("1125 0 320 1\n0 1125 256 0\n0 0 1 0", CameraError, r"\[K\|0\]"),
        ("1125 0 320\n0 1125 256\n0 0 2", CameraError, "not an intrinsic matrix"),
        ('{"fx": 1125, "fy": 1125, "cx": 320}', CameraError, "missing cy"),
        ('{"fx": 1125, "fy": 1125, "cx": 320, "cy": 256, "width": 640}', CameraError, "only one of"),
        ('{"fx": true, "fy": 1125, "cx": 320, "cy": 256}', CameraError, "must be a number"),
        ('{"K": [[1, 0], [0, 1]]}', ShapeError, "3x3 or 3x4"),
        ("[1125, 1125]", CameraError, "intrinsics JSON must be an object, got list"),
    ],
)
def test_read_intrinsics_errors_name_the_input(spec, error, message):
    with pytest.raises(error, match=message) as exc:
        read_intrinsics(spec)
    assert "\n" not in str(exc.value)
    assert spec.split()[0][:8] in str(exc.value)


# ============================================================================================ real data
def test_real_gt_pose_reads_and_lodloc_euler_equals_ours(shared):
    pose = read_pose(shared(GT_POSE))
    c2w = np.loadtxt(shared(GT_POSE))
    np.testing.assert_allclose(pose.world_from_cam, c2w, atol=1e-12)
    literal = Rotation.from_matrix(c2w[:3, :3] @ np.diag([1, -1, -1])).as_euler("xyz", degrees=True)
    x, y, z, roll, pitch, yaw = pose.to_xyz_rpy()
    np.testing.assert_allclose(literal, [pitch, roll, yaw], atol=1e-9)
    # The angles by hand from the file's matrix R: R = Rz(yaw) Ry(roll) Rx(pitch) diag(1, -1, -1) has the
    # first column (cos roll cos yaw, cos roll sin yaw, -sin roll) and the bottom row (-sin roll,
    # -cos roll sin pitch, -cos roll cos pitch).
    R = c2w[:3, :3]
    assert roll == pytest.approx(math.degrees(-math.asin(R[2, 0])), abs=1e-9)  # 0.817
    assert pitch == pytest.approx(math.degrees(math.atan2(-R[2, 1], -R[2, 2])), abs=1e-9)  # 0.333
    assert yaw == pytest.approx(math.degrees(math.atan2(R[1, 0], R[0, 0])), abs=1e-9)  # 102.497
    np.testing.assert_allclose([x, y, z], c2w[:3, 3], atol=1e-9)  # the centre is the file's last column
    # So: 224.568 m up (the file's z), nearly nadir, image-up turned 102.5 deg counterclockwise from north.
    assert z == pytest.approx(224.568, abs=1e-3)
    assert abs(pitch) < 1 and abs(roll) < 1 and yaw == pytest.approx(102.497, abs=1e-3)


def test_real_gt_points_project_into_image(shared):
    pose = read_pose(shared(GT_POSE))
    camera = read_intrinsics(shared(INTRINSIC))
    assert camera == Camera(1125, 1125, 320, 256, 640, 512)
    points = np.load(shared(POINTS)).astype(np.float64)
    assert points.ndim == 2 and points.shape[1] == 3 and len(points) > 1000
    uv, in_front = camera.project(pose.transform(points))
    inside = in_front & camera.in_image(uv)
    # Points_GT are the model points LoD-Loc's authors took as seen in this very image: at the true pose
    # every one of them lands inside the 640 x 512 frame.
    assert inside.all()
    # The points spread over the image, not a corner of it.
    assert np.ptp(uv[inside, 0]) > 300 and np.ptp(uv[inside, 1]) > 300


def test_real_prior_is_about_21m_and_4deg_off(shared):
    gt = read_pose(shared(GT_POSE))
    prior = read_pose(shared(GPS_POSE))
    assert center_error_m(prior, gt) == pytest.approx(21.10, abs=0.01)
    assert rotation_error_deg(prior, gt) == pytest.approx(4.03, abs=0.01)
    assert yaw_error_deg(prior, gt) == pytest.approx(3.83, abs=0.01)
    assert yaw_error_deg(prior, gt) <= rotation_error_deg(prior, gt) + 1e-9


def test_a_world_pose_written_with_the_origin_is_refused_not_shifted_twice():
    """``write_pose_json(pose_world, origin=model.origin)`` added the origin a second time (a Berlin
    northing of 11.6e6 written as CRS coordinates); with an origin the pose must be the local one (since
    stop 52 the parameters say so: ``pose_local=``, ``origin_world=``)."""
    from semcityloc.geometry.io import pose_to_dict

    origin = np.array([391000.0, 5817000.0, 0.0])
    local = Pose.from_xyz_rpy([10.25, -3.75, 156.5], 0.5, 29.0, 22.0)
    written = pose_to_dict(pose_local=local, origin_world=origin)
    assert written["position"] == pytest.approx([391010.25, 5816996.25, 156.5])
    with pytest.raises(PoseError, match=r"with an origin the pose must be in the local frame"):
        pose_to_dict(pose_local=local.shift_world(-origin), origin_world=origin)


def test_a_pose_file_names_the_frame_its_numbers_are_in_and_old_files_read_as_they_were(tmp_path):
    """A pose written by ``run --offset`` (the model's frame: the CRS minus an offset), or of a model
    without a CRS, said ``"frame": "crs"`` over numbers that were no CRS coordinates (stop 52). Now the frame
    says what they are: "crs", "crs_offset" (with ``offset_crs`` and ``crs_offset``, no ``crs`` label) or
    "model"; ``declared_pose_frame`` reads it, and the layouts written before read as what they were."""
    from semcityloc.geometry.io import PoseFrame, declared_pose_frame, pose_to_dict

    origin = np.array([100.0, -50.0, 0.0])
    local = Pose.from_xyz_rpy([12.25, -40.5, 180.0], 1.5, 35.0, -120.0)
    offset = [695672.0, 3131199.0, 0.0]
    shifted = write_pose_json(
        tmp_path / "o.json", pose_local=local, origin_world=origin, crs="EPSG:32649", crs_offset=offset
    )
    assert shifted["frame"] == "crs_offset" and "crs" not in shifted
    assert shifted["offset_crs"] == "EPSG:32649" and shifted["crs_offset"] == offset
    assert shifted["position"] == pytest.approx((local.center + origin).tolist())  # the numbers: CRS - offset
    assert declared_pose_frame(tmp_path / "o.json") == PoseFrame("crs_offset", "EPSG:32649", tuple(offset))
    assert declared_pose_frame(tmp_path / "o.json").describe() == "EPSG:32649 minus (695672, 3131199, 0)"
    in_crs = pose_to_dict(pose_local=local, origin_world=origin, crs="EPSG:32649", crs_offset=np.zeros(3))
    assert in_crs["frame"] == "crs" and in_crs["crs"] == "EPSG:32649"  # a zero offset is none
    unnamed = pose_to_dict(pose_world=local)
    assert unnamed["frame"] == "model" and "crs" not in unnamed
    with pytest.raises(PoseError, match="crs_offset needs crs"):
        pose_to_dict(pose_world=local, crs_offset=offset)
    for wrong in ({}, {"pose_local": local}, {"pose_world": local, "origin_world": origin}):
        with pytest.raises(TypeError, match="pose_local|origin_world"):
            pose_to_dict(**wrong)

    def frame_of(data: dict) -> PoseFrame:
        (tmp_path / "x.json").write_text(json.dumps(data))
        return declared_pose_frame(tmp_path / "x.json")

    pose = {k: shifted[k] for k in ("position", "roll", "pitch", "yaw")}
    # Written before stop 52: run --offset, a model without a CRS, dataset dji-prior with and without --offset
    old_run = {
        **pose,
        "frame": "crs",
        "extra": {"crs": None, "crs_offset": offset, "offset_crs": "EPSG:32649"},
    }
    assert frame_of(old_run) == PoseFrame("crs_offset", "EPSG:32649", tuple(offset))
    assert frame_of({**pose, "frame": "crs", "extra": {"crs_offset": offset, "offset_crs": None}}).crs is None
    assert frame_of({**pose, "frame": "crs"}) == PoseFrame("model")
    old_dji = {**pose, "frame": "world", "extra": {"offset": offset, "crs": "EPSG:32649"}}
    assert frame_of(old_dji) == PoseFrame("crs_offset", "EPSG:32649", tuple(offset))
    old_dji_crs = {**pose, "frame": "world", "crs": "EPSG:32649", "extra": {"offset": [0, 0, 0]}}
    assert frame_of(old_dji_crs) == PoseFrame("crs", "EPSG:32649")
    assert frame_of({**pose, "crs": "EPSG:25832"}) == PoseFrame("crs", "EPSG:25832")  # a hand-written one
    assert frame_of(pose) == PoseFrame(None) and declared_pose_frame("1,2,3,0,0,0") == PoseFrame(None)
    for bad, said in (
        ({**pose, "frame": "local"}, "its frame 'local' is none of crs, crs_offset, model"),
        ({**pose, "frame": "model", "crs": "EPSG:25832"}, "names a crs"),
        ({**pose, "frame": "crs_offset", "offset_crs": "EPSG:32649"}, "it has no 'crs_offset'"),
        ({**pose, "frame": "crs_offset", "offset_crs": "EPSG:32649", "crs_offset": [1, 2]}, "a list of 3"),
        ({**pose, "frame": "crs_offset", "crs_offset": offset}, "'crs_offset' needs 'offset_crs'"),
    ):
        with pytest.raises(PoseError, match=f"x.json: .*{said}"):
            frame_of(bad)


def test_a_json_pose_file_is_read_once_for_its_frame_and_its_pose(tmp_path, monkeypatch):
    """``read_pose_world`` (``localize --prior``, ``render --pose``, a photo folder's pose files) read a pose
    file twice, once for the frame it declares and once for its numbers; a pose file of ``run --poses``
    three times (its camera ids too); ``benchmark`` reading a run's record parsed it, then read it again
    for the pose. Each reads it once now, with the same results and the same refusals."""
    from pathlib import Path

    import pyproj

    from semcityloc.benchmark.photo_exports import read_record
    from semcityloc.citymodel.pose_crs import read_pose_world
    from semcityloc.datasets.photos import PoseFiles
    from semcityloc.errors import CRSError
    from semcityloc.localization.result import LOCALIZED

    pose = Pose.from_xyz_rpy([500100.25, 5800200.5, 80.0], 1.0, -30.0, 45.0)
    path = tmp_path / "a.json"
    write_pose_json(path, pose_world=pose, crs="EPSG:25833", extra={"status": LOCALIZED, "image": "a.jpg"})
    expected = read_pose(path).cam_from_world  # what read_pose reads, to the last bit
    reads: list[Path] = []
    read_text = Path.read_text

    def counted(self, *args, **kwargs):
        if self == path:
            reads.append(self)
        return read_text(self, *args, **kwargs)

    monkeypatch.setattr(Path, "read_text", counted)
    crs = pyproj.CRS.from_epsg(25833)
    np.testing.assert_array_equal(read_pose_world(path, crs).cam_from_world, expected)
    assert len(reads) == 1
    reads.clear()
    files = PoseFiles(path, crs)
    np.testing.assert_array_equal(files.entries[""].cam_from_world, expected)
    assert files.camera_ids == {} and len(reads) == 1
    reads.clear()
    record, found = read_record(path, "a.jpg")
    assert record["extra"]["image"] == "a.jpg" and len(reads) == 1
    np.testing.assert_array_equal(found.cam_from_world, expected)
    with pytest.raises(CRSError, match="the prior is in EPSG:25833 but the model in EPSG:25832"):
        read_pose_world(path, pyproj.CRS.from_epsg(25832), "prior")
    with pytest.raises(CRSError, match="EPSG:25833 but the model in EPSG:25832"):
        PoseFiles(path, pyproj.CRS.from_epsg(25832))


def test_odm_angles_invert_opendronemaps_own_rotation():
    """OpenDroneMap's ``Photo.compute_opk`` builds the body rotation from (yaw, pitch, roll) with
    Baeumker's YPR matrix and maps its camera (x right, y image top, z backwards) into the body with
    ``cbb`` (swap x / y, flip z). Written out here from those two matrices, not from our code:
    ``odm_angles`` gives back the angles, and DJI's angles are ODM's with pitch + 90 (the geo.txt of a
    run was written in DJI's convention, which ODM reads as a camera tilted by 90 degrees)."""
    rng = np.random.default_rng(5)
    angles = np.stack([rng.uniform(-179, 179, 50), rng.uniform(-80, 80, 50), rng.uniform(-60, 60, 50)], -1)
    for y, p, r in angles:
        cy, sy, cp, sp, cr, sr = (f(np.radians(a)) for a in (y, p, r) for f in (np.cos, np.sin))
        cnb = np.array(
            [
                [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                [-sp, cp * sr, cp * cr],
            ]
        )
        cbb = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
        ned_to_enu = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
        R_world_from_cam = ned_to_enu @ cnb @ cbb @ np.diag([1.0, -1.0, -1.0])  # OpenCV camera axes
        np.testing.assert_allclose(odm_angles(R_world_from_cam), [y, p, r], atol=1e-9)
    for dji in [(0.0, -90.0, 0.0), (30.0, -60.0, 0.0), (-102.3, -88.0, 0.0), (170.0, -10.0, 0.0)]:
        np.testing.assert_allclose(
            odm_angles(dji_world_from_cam(*dji)), [dji[0], dji[1] + 90.0, 0.0], atol=1e-9
        )
    nadir = Pose.from_xyz_rpy([0.0, 0.0, 100.0], 0.0, 0.0, 0.0)  # our (0, 0, 0): down, image top north
    np.testing.assert_allclose(odm_angles(nadir.R_world_from_cam), [0.0, 0.0, 0.0], atol=1e-12)

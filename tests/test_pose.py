"""Pose: construction checks, Euler round trips, frames and the world-frame operations."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semcityloc.errors import PoseError, ShapeError
from semcityloc.geometry.pose import CAM_FROM_BODY_FLIP, Pose, euler_xyz_matrices


def random_angles(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """roll, pitch, yaw away from the representation's edges (roll = ±90, angle wrap at ±180)."""
    roll = rng.uniform(-89.0, 89.0, n)
    pitch = rng.uniform(-179.0, 179.0, n)
    yaw = rng.uniform(-179.0, 179.0, n)
    return roll, pitch, yaw


def random_poses(seed: int, n: int) -> Pose:
    rng = np.random.default_rng(seed)
    roll, pitch, yaw = random_angles(rng, n)
    return Pose.from_xyz_rpy(rng.uniform(-1000, 1000, (n, 3)), roll, pitch, yaw)


# ------------------------------------------------------------------------------------- Euler convention
def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64).view(np.uint64)


def test_euler_matrices_are_scipys_within_rounding_and_the_same_bits_in_any_batch():
    """``euler_xyz_matrices`` (stop 54's speed-up of every ``Pose.from_state``) is scipy's rotation (its
    arithmetic: the same bits as scipy 1.17, checked then; held here within rounding, so that another scipy
    cannot fail this), and a rotation's bits do not depend on the batch it is made in."""
    rng = np.random.default_rng(3)
    special = np.array([0.0, -0.0, 1e-300, -1e-300, 30.0, 45.0, 90.0, -90.0, 180.0, -180.0, 270.0, 360.0])
    cases = [
        rng.normal(size=(20_000, 3)) * [5.0, 5.0, 100.0],
        rng.uniform(-720.0, 720.0, (20_000, 3)),
        rng.integers(-360, 361, (5_000, 3)).astype(float) / 2.0,
        rng.normal(size=(5_000, 3)) * 1e-7,
        np.array(np.meshgrid(special, special, special)).reshape(3, -1).T,
        rng.normal(size=(3, 3)) * 30.0,
    ]
    for angles in cases:
        ours = euler_xyz_matrices(angles)
        theirs = Rotation.from_euler("xyz", angles, degrees=True).as_matrix()
        assert ours.shape == theirs.shape
        np.testing.assert_allclose(ours, theirs, rtol=0.0, atol=1e-15)
        one_by_one = np.stack([euler_xyz_matrices(a[None])[0] for a in angles[:50]])
        assert np.array_equal(_bits(one_by_one), _bits(ours[:50]))


def test_from_state_batch_has_the_bits_of_its_rotations_and_of_single_poses():
    rng = np.random.default_rng(4)
    states = rng.normal(size=(128, 6)) * [30.0, 30.0, 30.0, 2.0, 40.0, 120.0]
    pose = Pose.from_state(states)
    R_body = euler_xyz_matrices(states[:, [4, 3, 5]])
    R = np.swapaxes(R_body @ CAM_FROM_BODY_FLIP, -1, -2)
    assert np.array_equal(_bits(pose.R), _bits(R))
    assert np.array_equal(_bits(pose.t), _bits(-np.einsum("...ij,...j->...i", R, states[:, :3])))
    scipys = Rotation.from_euler("xyz", states[:, [4, 3, 5]], degrees=True).as_matrix()
    np.testing.assert_allclose(R_body, scipys, rtol=0.0, atol=1e-15)
    single = Pose.from_state(states[5])
    assert np.array_equal(_bits(single.R), _bits(pose.R[5]))


def test_xyz_rpy_round_trip_batched():
    rng = np.random.default_rng(0)
    n = 2000
    xyz = rng.uniform(-5e5, 5e5, (n, 3))
    roll, pitch, yaw = random_angles(rng, n)
    out = Pose.from_xyz_rpy(xyz, roll, pitch, yaw).to_xyz_rpy()
    assert out.shape == (n, 6)
    np.testing.assert_allclose(out[:, :3], xyz, atol=1e-8)
    np.testing.assert_allclose(out[:, 3], roll, atol=1e-8)
    np.testing.assert_allclose(out[:, 4], pitch, atol=1e-8)
    np.testing.assert_allclose(out[:, 5], yaw, atol=1e-8)


def test_state_vectors_round_trip_single_and_batched_and_a_wrong_width_is_refused():
    """``Pose.from_state`` is the one reading of the search's (x, y, z, roll, pitch, yaw) vectors (three
    private copies before): the inverse of ``to_xyz_rpy`` for one state and for a batch."""
    rng = np.random.default_rng(3)
    roll, pitch, yaw = random_angles(rng, 50)
    states = np.column_stack([rng.uniform(-1e3, 1e3, (50, 3)), roll, pitch, yaw])
    np.testing.assert_allclose(Pose.from_state(states).to_xyz_rpy(), states, atol=1e-8)
    one = Pose.from_state(states[7])
    assert one.batch_shape == ()
    np.testing.assert_array_equal(one.R, Pose.from_state(states)[7].R)
    with pytest.raises(ShapeError, match=r"\(\.\.\., 6\), got \(5,\)"):
        Pose.from_state(states[0, :5])


@pytest.mark.parametrize(
    "rpy",
    [
        (0.0, 0.0, 0.0),
        (0.0, 0.0, 90.0),
        (0.0, 0.0, -135.0),
        (3.0, 0.0, 12.0),
        (0.0, 89.9, 45.0),
        (0.0, 90.0, 0.0),
        (-20.0, 60.0, 170.0),
        (0.0, 0.001, -0.001),
    ],
)
def test_xyz_rpy_round_trip_single_including_nadir_and_horizontal(rpy):
    roll, pitch, yaw = rpy
    pose = Pose.from_xyz_rpy([1.0, 2.0, 3.0], roll, pitch, yaw)
    assert pose.batch_shape == ()
    out = pose.to_xyz_rpy()
    assert out.shape == (6,)
    np.testing.assert_allclose(out, [1.0, 2.0, 3.0, roll, pitch, yaw], atol=1e-9)


def test_nadir_camera_axes():
    pose = Pose.from_xyz_rpy([0, 0, 100], 0, 0, 0)
    Rwc = pose.R_world_from_cam
    np.testing.assert_allclose(pose.viewing_direction, [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(Rwc[:, 0], [1, 0, 0], atol=1e-12)  # image right = east
    np.testing.assert_allclose(-Rwc[:, 1], [0, 1, 0], atol=1e-12)  # image up = north


def test_pitch_tilts_towards_image_up_and_yaw_turns_counter_clockwise():
    horizontal = Pose.from_xyz_rpy([0, 0, 0], 0, 90, 0)
    np.testing.assert_allclose(horizontal.viewing_direction, [0, 1, 0], atol=1e-12)  # looks north
    np.testing.assert_allclose(-horizontal.R_world_from_cam[:, 1], [0, 0, 1], atol=1e-12)  # image up = sky
    nadir_yaw90 = Pose.from_xyz_rpy([0, 0, 0], 0, 0, 90)
    np.testing.assert_allclose(-nadir_yaw90.R_world_from_cam[:, 1], [-1, 0, 0], atol=1e-12)  # image up = west
    tilted = Pose.from_xyz_rpy([0, 0, 0], 0, 30, 90)
    np.testing.assert_allclose(tilted.viewing_direction, [-0.5, 0, -np.sqrt(3) / 2], atol=1e-12)
    # Roll at nadir tips the optical axis about the north axis: Ry(10) (0, 0, -1) = (-sin 10, 0, -cos 10),
    # i.e. toward west, and image right (east) dips down.
    rolled = Pose.from_xyz_rpy([0, 0, 0], 10, 0, 0)
    s, c = np.sin(np.radians(10)), np.cos(np.radians(10))
    np.testing.assert_allclose(rolled.viewing_direction, [-s, 0, -c], atol=1e-12)
    np.testing.assert_allclose(rolled.R_world_from_cam[:, 0], [c, 0, -s], atol=1e-12)


# ------------------------------------------------------------------------------------- matrices and frames
def test_matrices_are_inverse_and_center_maps_to_origin():
    pose = random_poses(1, 50)
    eye = pose.world_from_cam @ pose.cam_from_world
    np.testing.assert_allclose(eye, np.broadcast_to(np.eye(4), eye.shape), atol=1e-9)
    np.testing.assert_allclose(pose.transform(np.zeros((1, 3)))[:, 0], pose.t, atol=1e-12)
    centre_cam = np.einsum("nij,nj->ni", pose.R, pose.center) + pose.t
    np.testing.assert_allclose(centre_cam, 0.0, atol=1e-9)
    # A point one metre along the optical axis is at camera (0, 0, 1).
    ahead = pose.center + pose.viewing_direction
    np.testing.assert_allclose(
        np.einsum("nij,nj->ni", pose.R, ahead) + pose.t, np.tile([0, 0, 1.0], (50, 1)), atol=1e-9
    )


def test_constructor_round_trips():
    pose = random_poses(2, 20)
    for other in (
        Pose.from_world_from_cam(pose.world_from_cam),
        Pose.from_cam_from_world(pose.cam_from_world),
        Pose.from_cam_from_world(pose.cam_from_world[:, :3, :]),
        Pose.from_world_from_cam(pose.world_from_cam[:, :3, :]),
        Pose.from_rotation_center(pose.R_world_from_cam, pose.center),
    ):
        np.testing.assert_allclose(other.R, pose.R, atol=1e-12)
        np.testing.assert_allclose(other.t, pose.t, atol=1e-9)


def test_transform_shapes_single_and_batched():
    pts = np.random.default_rng(3).normal(size=(7, 3))
    batch = random_poses(3, 4)
    assert batch.transform(pts).shape == (4, 7, 3)
    np.testing.assert_allclose(batch.transform(pts)[2], batch[2].transform(pts), atol=1e-12)
    assert batch[2].transform(pts).shape == (7, 3)


def test_points_to_world_inverts_transform_and_directions_only_rotate():
    pts = np.random.default_rng(4).normal(size=(7, 3)) * 50.0
    pose = random_poses(5, 1)[0]
    np.testing.assert_allclose(pose.points_to_world(pose.transform(pts)), pts, atol=1e-9)
    # A camera 10 m up looking straight down (nadir, image-up north): its optical axis points to -z, and
    # the point 10 m along it is on the ground below the camera.
    nadir = Pose.from_xyz_rpy(np.array([3.0, 4.0, 10.0]), 0.0, 0.0, 0.0)
    np.testing.assert_allclose(nadir.directions_to_world([0.0, 0.0, 1.0]), [0.0, 0.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(nadir.points_to_world([[0.0, 0.0, 10.0]]), [[3.0, 4.0, 0.0]], atol=1e-12)
    assert nadir.points_to_world(np.zeros((2, 5, 3))).shape == (2, 5, 3)  # any leading shape


def test_stack_index_len():
    batch = random_poses(4, 5)
    again = Pose.stack([batch[i] for i in range(5)])
    np.testing.assert_array_equal(again.R, batch.R)
    assert len(again) == 5
    assert again[1:3].batch_shape == (2,)
    with pytest.raises(TypeError):
        len(batch[0])
    assert "batch=(5,)" in repr(batch)
    assert "pitch=" in repr(batch[0])


# ------------------------------------------------------------------------------------- invalid input
@pytest.mark.parametrize("where", ["R", "t"])
def test_nan_pose_raises(where):
    R, t = np.eye(3), np.zeros(3)
    if where == "R":
        R = R.copy()
        R[0, 0] = np.nan
    else:
        t = np.array([0.0, np.inf, 0.0])
    with pytest.raises(PoseError, match="non-finite"):
        Pose(R, t)


def test_nan_angles_and_center_raise():
    with pytest.raises(PoseError):
        Pose.from_xyz_rpy([0, 0, 0], np.nan, 0, 0)
    with pytest.raises(PoseError):
        Pose.from_xyz_rpy([0, np.nan, 0], 0, 0, 0)
    with pytest.raises(PoseError):
        Pose.from_rotation_center(np.eye(3), [np.nan, 0, 0])


@pytest.mark.parametrize(
    "R",
    [
        2.0 * np.eye(3),  # scaled
        np.diag([1.0, 1.0, -1.0]),  # reflection, det -1
        np.array([[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),  # sheared
        np.zeros((3, 3)),
    ],
)
def test_non_rotation_raises(R):
    with pytest.raises(PoseError, match="not a rotation"):
        Pose(R, np.zeros(3))


def test_slightly_noisy_rotation_is_accepted():
    R = Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_matrix() + 1e-7
    Pose(R, np.zeros(3))


@pytest.mark.parametrize(
    ("R", "t"),
    [(np.eye(4), np.zeros(3)), (np.eye(3), np.zeros(4)), (np.stack([np.eye(3)] * 2), np.zeros(3))],
)
def test_wrong_shapes_raise(R, t):
    with pytest.raises(ShapeError):
        Pose(R, t)


def test_wrong_matrix_shape_raises():
    with pytest.raises(ShapeError):
        Pose.from_world_from_cam(np.eye(3))
    with pytest.raises(ShapeError):
        Pose.from_cam_from_world(np.eye(5))


# ------------------------------------------------------------------------------------- world operations
def test_rotate_world_z_adds_to_yaw_and_keeps_center_roll_pitch():
    rng = np.random.default_rng(5)
    n = 300
    roll = rng.uniform(-60, 60, n)
    pitch = rng.uniform(-170, 170, n)
    yaw = rng.uniform(-179, 179, n)
    delta = rng.uniform(-360, 360, n)
    xyz = rng.uniform(-100, 100, (n, 3))
    out = Pose.from_xyz_rpy(xyz, roll, pitch, yaw).rotate_world_z(delta).to_xyz_rpy()
    np.testing.assert_allclose(out[:, :3], xyz, atol=1e-9)
    np.testing.assert_allclose(out[:, 3], roll, atol=1e-8)
    np.testing.assert_allclose(out[:, 4], pitch, atol=1e-8)
    dyaw = (out[:, 5] - yaw - delta + 180.0) % 360.0 - 180.0
    np.testing.assert_allclose(dyaw, 0.0, atol=1e-8)


def test_rotate_world_z_single_and_scalar_angle():
    pose = Pose.from_xyz_rpy([5, 6, 7], 0, 0, 10)
    out = pose.rotate_world_z(25.0)
    assert out.batch_shape == ()
    np.testing.assert_allclose(out.to_xyz_rpy(), [5, 6, 7, 0, 0, 35], atol=1e-9)


def test_rotate_world_z_scalar_angle_on_batch():
    batch = random_poses(7, 4)
    out = batch.rotate_world_z(15.0)
    assert out.batch_shape == (4,)
    np.testing.assert_allclose(out.R_world_from_cam, batch.rotate_world_z(np.full(4, 15.0)).R_world_from_cam)


def test_shift_world_moves_center_only():
    pose = random_poses(6, 10)
    offset = np.array([391000.0, 5817000.0, 0.0])
    shifted = pose.shift_world(offset)
    np.testing.assert_array_equal(shifted.R, pose.R)
    np.testing.assert_allclose(shifted.center, pose.center - offset, atol=1e-9)
    pts = np.random.default_rng(6).uniform(-50, 50, (20, 3)) + offset
    np.testing.assert_allclose(shifted.transform(pts - offset), pose.transform(pts), atol=1e-6)
    back = shifted.shift_world(-offset)
    np.testing.assert_allclose(back.t, pose.t, atol=1e-6)


def test_world_coordinates_in_float32_are_refused_not_rounded():
    """A UTM northing of 5.8e6 in float32 is 0.5 m coarse: a Pose (and ``CityModel.to_local``) cast it to
    float64 after the metres were lost, silently (0.2 m off in the audit). Small (local) float32 values
    pass."""
    centre = np.array([391500.37, 5817846.37, 30.0])
    with pytest.raises(PoseError, match=r"camera centre in float32 at a magnitude of 5\.818e\+06 m"):
        Pose.from_rotation_center(np.eye(3), centre.astype(np.float32))
    with pytest.raises(PoseError, match="subtract a float64 origin"):
        Pose.from_xyz_rpy(centre.astype(np.float32), 0.0, 0.0, 0.0)
    local = Pose.from_xyz_rpy(np.array([10.25, -3.5, 30.0], np.float32), 0.0, 0.0, 0.0)
    np.testing.assert_array_equal(local.center, [10.25, -3.5, 30.0])
    assert Pose.from_rotation_center(np.eye(3), centre).center[1] == 5817846.37


def test_a_matrix_that_is_no_rigid_transform_or_a_short_centre_is_a_typed_error():
    """A 4x4 whose last row is not [0, 0, 0, 1] was taken as a pose by the Pose constructors (the LoD-Loc
    reader refused it); a 2-vector centre failed inside numpy's einsum."""
    T = np.array([[1, 0, 0, 1], [0, 1, 0, 2], [0, 0, 1, 3], [5, 5, 5, 9.0]])
    for make in (Pose.from_world_from_cam, Pose.from_cam_from_world):
        with pytest.raises(PoseError, match=r"last row .* must be \[0, 0, 0, 1\]"):
            make(T)
    with pytest.raises(ShapeError, match=r"camera centre\(s\) must have shape \(\.\.\., 3\), got \(2,\)"):
        Pose.from_xyz_rpy([1, 2], 0, 0, 0)
    with pytest.raises(ShapeError, match=r"a rotation \(\.\.\., 3, 3\) and a centre \(\.\.\., 3\)"):
        Pose.from_rotation_center(np.eye(3), [1, 2])


def test_a_single_pose_is_not_iterable():
    """Iterating a single pose went through ``__getitem__`` and failed as a ShapeError about R and t."""
    pose = Pose.from_xyz_rpy([1, 2, 3], 0, 0, 0)
    with pytest.raises(TypeError, match="a single Pose cannot be indexed or iterated"):
        [p for p in pose]
    batch = Pose.stack([pose, pose])
    assert [p.center.tolist() for p in batch] == [[1, 2, 3], [1, 2, 3]]

"""Conversions between ``Pose`` and the pose conventions users bring (LoD-Loc, COLMAP, DJI gimbal angles).

``Pose`` (``geometry/pose.py``) is the one internal representation: ``cam_from_world`` with OpenCV camera
axes (x right, y down, z forward) in a metric world with x east, y north, z up. Every other convention
is converted here, at the boundary, with the formula in the function's docstring; nothing else in the
library should know about quaternion orders or NED frames. See docs/conventions.md for the big picture.

Angles are in degrees everywhere. All functions accept a single pose or a batch (leading dimensions).
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial.transform import Rotation

from semcityloc.errors import PoseError, ShapeError
from semcityloc.geometry.pose import Pose

# ENU (x east, y north, z up) from NED (x north, y east, z down): x_enu = y_ned, y_enu = x_ned,
# z_enu = -z_ned. A proper rotation (det +1): 180 degrees about the axis (1, 1, 0) / sqrt(2).
ENU_FROM_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])

# The camera frame expressed in the gimbal (aerospace body) frame; its columns are the camera axes:
# x (image right) = gimbal right (+y_g), y (image down) = gimbal down (+z_g),
# z (optical axis) = gimbal forward (+x_g).
GIMBAL_FROM_CAM = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

# The OpenCV camera in OpenDroneMap's body frame (x forward, y right, z down); its columns are the camera
# axes: x (image right) = body right, y (image down) = body backward, z (optical axis) = body down. That is
# ODM ``Photo.compute_opk``'s ``cbb`` (its camera: x right, y image top, z out of the lens) times
# diag(1, -1, -1): a nadir camera whose image top points forward.
ODM_BODY_FROM_CAM = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])

# A quaternion whose norm is further than this from 1 is rejected rather than silently normalised.
QUATERNION_NORM_TOLERANCE = 1e-2


# ---------------------------------------------------------------------------------------------- helpers
def wrap_deg(angle: np.ndarray | float) -> np.ndarray | float:
    """Angle(s) in degrees wrapped to (-180, 180]: ``180 - ((180 - a) mod 360)``."""
    a = np.asarray(angle, dtype=np.float64)
    out = 180.0 - np.mod(180.0 - a, 360.0)
    return float(out) if out.ndim == 0 else out


def state_difference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a - b`` of search states (..., 6) (x, y, z m; roll, pitch, yaw deg: ``Pose.to_xyz_rpy``) with the
    three angle differences wrapped to (-180, 180] (``wrap_deg``), so that 179 deg minus -179 deg is -2 deg,
    not 358. Float64; ``a`` and ``b`` broadcast (N states minus one centre)."""
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    if d.shape[-1:] != (6,):
        raise ShapeError(f"search states must have shape (..., 6), got {d.shape}")
    d[..., 3:] = wrap_deg(d[..., 3:])
    return d


def _matrices(T: np.ndarray, what: str) -> np.ndarray:
    T = np.asarray(T, dtype=np.float64)
    if T.ndim < 2 or T.shape[-2:] not in ((4, 4), (3, 4)):
        raise ShapeError(f"{what} must have shape (..., 4, 4) or (..., 3, 4), got {T.shape}")
    if not np.all(np.isfinite(T)):
        raise PoseError(f"{what} has non-finite entries")
    if T.shape[-2] == 4 and np.abs(T[..., 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max() > 1e-9:
        raise PoseError(f"{what}: the last row of a 4x4 rigid transform must be [0, 0, 0, 1]")
    return T


# ---------------------------------------------------------------------------------------------- LoD-Loc
def pose_from_lodloc_c2w(T_world_from_cam: np.ndarray) -> Pose:
    """From LoD-Loc's ``*_pose.txt`` matrix: 4x4 (or 3x4) camera-to-world, OpenCV camera axes.

    ``x_world = T[:3, :3] @ x_cam + T[:3, 3]``; so ``R_cam_from_world = T[:3, :3]^T`` and the camera
    centre is ``T[:3, 3]``.
    """
    return Pose.from_world_from_cam(_matrices(T_world_from_cam, "LoD-Loc camera-to-world matrix"))


def lodloc_c2w(pose: Pose) -> np.ndarray:
    """(..., 4, 4) camera-to-world matrix as LoD-Loc writes it: ``[[R^T, C], [0, 0, 0, 1]]``."""
    return pose.world_from_cam


# ---------------------------------------------------------------------------------------------- COLMAP
def pose_from_colmap(qw, qx, qy, qz, tx, ty, tz) -> Pose:
    """From a COLMAP image pose: world-to-camera ``x_cam = R(q) x_world + t``.

    ``q = (qw, qx, qy, qz)`` is a Hamilton quaternion, scalar first, with
    ``R(q) = [[1-2(qy²+qz²), 2(qx qy - qw qz), 2(qx qz + qw qy)],
              [2(qx qy + qw qz), 1-2(qx²+qz²), 2(qy qz - qw qx)],
              [2(qx qz - qw qy), 2(qy qz + qw qx), 1-2(qx²+qy²)]]``.
    COLMAP's camera axes are OpenCV's, so ``R(q), t`` is directly our ``cam_from_world``. Arguments may be
    scalars or arrays of one batch shape. Quaternions are normalised; a norm more than
    ``QUATERNION_NORM_TOLERANCE`` away from 1 (a wrong column, a zero quaternion) raises ``PoseError``.
    """
    q = np.stack(np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (qw, qx, qy, qz))), -1)
    t = np.stack(np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (tx, ty, tz))), -1)
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(t))):
        raise PoseError("COLMAP quaternion/translation has non-finite entries")
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(np.abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE):
        raise PoseError(
            f"COLMAP quaternion (qw, qx, qy, qz) must have unit norm, got norm {norm.ravel()[0]:.6g}"
        )
    q = q / norm
    # scipy wants scalar-last (x, y, z, w): the only place the order changes.
    R = Rotation.from_quat(q[..., [1, 2, 3, 0]].reshape(-1, 4)).as_matrix().reshape(q.shape[:-1] + (3, 3))
    batch = np.broadcast_shapes(q.shape[:-1], t.shape[:-1])
    return Pose(np.broadcast_to(R, batch + (3, 3)), np.broadcast_to(t, batch + (3,)))


def colmap_qvec_tvec(pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    """``(qvec, tvec)``: (..., 4) Hamilton quaternion ``(qw, qx, qy, qz)`` of ``R_cam_from_world`` with
    ``qw >= 0`` and (..., 3) ``t_cam_from_world``, as in COLMAP's ``images.txt``."""
    xyzw = Rotation.from_matrix(pose.R.reshape(-1, 3, 3)).as_quat()
    qvec = xyzw[:, [3, 0, 1, 2]]
    qvec *= np.where(qvec[:, :1] < 0, -1.0, 1.0)
    return qvec.reshape(pose.batch_shape + (4,)), pose.t.copy()


# ---------------------------------------------------------------------------------------------- DJI
def dji_world_from_cam(yaw_deg, pitch_deg, roll_deg) -> np.ndarray:
    """(..., 3, 3) ``R_world_from_cam`` (world ENU) for DJI gimbal angles (NED, degrees).

    ``R = ENU_FROM_NED @ Rz(yaw) @ Ry(pitch) @ Rx(roll) @ GIMBAL_FROM_CAM``, with the aerospace
    body frame (x forward, y right, z down) rotated from NED by yaw (about down, clockwise from north seen
    from above), pitch (about right, nose up positive: -90 = straight down) and roll (about forward,
    right side down positive). Equivalently ``R = Rz(-yaw) @ Rx(90 + pitch) @ diag(1, -1, -1) @ Rz(roll)``
    in ENU: DJI roll turns the image about the optical axis (camera frame), unlike our roll.
    """
    return _world_from_ned_angles(yaw_deg, pitch_deg, roll_deg, GIMBAL_FROM_CAM, "DJI gimbal angles")


def _world_from_ned_angles(yaw_deg, pitch_deg, roll_deg, body_from_cam: np.ndarray, what: str) -> np.ndarray:
    """(..., 3, 3) ``ENU_FROM_NED @ Rz(yaw) Ry(pitch) Rx(roll) @ body_from_cam``: the inverse of
    ``_ned_yaw_pitch_roll``; ``what`` names the angles in the error for a non-finite one."""
    angles = np.stack(
        np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (yaw_deg, pitch_deg, roll_deg))), -1
    )
    if not np.all(np.isfinite(angles)):
        raise PoseError(f"{what} have non-finite entries")
    # Intrinsic 'ZYX' (yaw, pitch, roll) = Rz(yaw) @ Ry(pitch) @ Rx(roll).
    R_ned_from_body = Rotation.from_euler("ZYX", angles.reshape(-1, 3), degrees=True).as_matrix()
    R = ENU_FROM_NED @ R_ned_from_body @ body_from_cam
    return R.reshape(angles.shape[:-1] + (3, 3))


def pose_from_dji(position_xyz, gimbal_yaw_deg, gimbal_pitch_deg, gimbal_roll_deg) -> Pose:
    """From a camera position in the metric world (x east, y north, z up) and DJI gimbal angles.

    DJI's ``GimbalYawDegree`` / ``GimbalPitchDegree`` / ``GimbalRollDegree`` (XMP) are absolute angles in
    NED: yaw clockwise from north, pitch -90 = looking straight down, 0 = horizon, roll about the optical
    axis with right-side-down positive. The camera looks along the gimbal's forward axis, image x = gimbal
    right, image y = gimbal down (formula in ``dji_world_from_cam``). In our angles: yaw = -gimbal_yaw,
    pitch = 90 + gimbal_pitch when gimbal roll is 0. The geodesy (GPS -> model CRS) is not done here.
    """
    R_world_from_cam = dji_world_from_cam(gimbal_yaw_deg, gimbal_pitch_deg, gimbal_roll_deg)
    C = np.asarray(position_xyz, dtype=np.float64)
    if C.shape[-1:] != (3,):
        raise ShapeError(f"DJI camera position must have shape (..., 3), got {C.shape}")
    batch = np.broadcast_shapes(R_world_from_cam.shape[:-2], C.shape[:-1])
    return Pose.from_rotation_center(
        np.broadcast_to(R_world_from_cam, batch + (3, 3)), np.broadcast_to(C, batch + (3,))
    )


def dji_gimbal_angles(pose: Pose) -> np.ndarray:
    """(..., 3) DJI gimbal ``(yaw, pitch, roll)`` in degrees (NED) of a pose; inverse of ``pose_from_dji``.

    ``Rz(yaw) Ry(pitch) Rx(roll) = ENU_FROM_NED^T @ R_world_from_cam @ GIMBAL_FROM_CAM^T`` decomposed as
    intrinsic 'ZYX'. DJI's parametrisation is gimbal-locked at pitch = ±90 (nadir / zenith): there only
    yaw + roll (nadir) is defined; we return it all as yaw with roll 0. Yaw is wrapped to (-180, 180].
    """
    return _ned_yaw_pitch_roll(pose.R_world_from_cam, GIMBAL_FROM_CAM)


def _ned_yaw_pitch_roll(R_world_from_cam: np.ndarray, body_from_cam: np.ndarray) -> np.ndarray:
    """(..., 3) ``(yaw, pitch, roll)`` in degrees of a body carrying the camera as ``body_from_cam``:
    ``Rz Ry Rx = ENU_FROM_NED^T @ R_world_from_cam @ body_from_cam^T`` as intrinsic 'ZYX', yaw wrapped to
    (-180, 180]; at a gimbal lock the whole turn about the vertical is yaw (SciPy's choice, its warning
    silenced). DJI's and OpenDroneMap's angles differ only in ``body_from_cam``."""
    R = np.asarray(R_world_from_cam, dtype=np.float64)
    R_body = ENU_FROM_NED.T @ R @ body_from_cam.T
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Gimbal lock detected")
        ypr = Rotation.from_matrix(R_body.reshape(-1, 3, 3)).as_euler("ZYX", degrees=True)
    ypr[:, 0] = wrap_deg(ypr[:, 0])
    return ypr.reshape(R.shape[:-2] + (3,))


# ---------------------------------------------------------------------------------------------- ODM
def odm_angles(R_world_from_cam: np.ndarray) -> np.ndarray:
    """(..., 3) OpenDroneMap's ``(yaw, pitch, roll)`` in degrees of cameras ``R_world_from_cam`` (world
    ENU, OpenCV camera axes): what its ``geo.txt`` holds.

    ODM normalises every source to this (``opendm/photo.py``: "Yaw 0: top of image points north; Pitch 0:
    nadir camera, 90: looking forward; Roll 0 (assuming gimbal)"; DJI's gimbal pitch gets + 90) and
    builds ``R_ned_from_body = Rz(yaw) Ry(pitch) Rx(roll)`` with its camera as ``ODM_BODY_FROM_CAM``. So
    ``Rz Ry Rx = ENU_FROM_NED^T @ R_world_from_cam @ ODM_BODY_FROM_CAM^T``, decomposed as intrinsic
    'ZYX'. Unlike DJI's angles this is well-conditioned at nadir (pitch and roll are the two tilts, yaw
    the heading of the image top); it is gimbal-locked for a camera looking at the horizon. Yaw is
    wrapped to (-180, 180], measured from the world's y axis (true north when the world is a local ENU).
    The same definition as Pix4D's yaw, pitch, roll (its image geolocation import) and Metashape's
    reference rotation (rest pose looking down): a run's ``geotags.csv`` writes these too
    (``docs/data-formats.md``).
    """
    return _ned_yaw_pitch_roll(R_world_from_cam, ODM_BODY_FROM_CAM)


def odm_world_from_cam(yaw_deg, pitch_deg, roll_deg) -> np.ndarray:
    """(..., 3, 3) ``R_world_from_cam`` (world ENU, OpenCV camera axes) of OpenDroneMap / Pix4D angles
    (degrees): the inverse of ``odm_angles``, ``ENU_FROM_NED @ Rz(yaw) Ry(pitch) Rx(roll) @
    ODM_BODY_FROM_CAM``."""
    return _world_from_ned_angles(yaw_deg, pitch_deg, roll_deg, ODM_BODY_FROM_CAM, "yaw / pitch / roll")

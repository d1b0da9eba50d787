"""Pose errors between an estimate and a ground truth: position, full rotation and yaw.

These are the numbers the benchmarks report (recall at (m, deg) thresholds), so each has one definition
here. All functions take ``Pose`` objects of broadcastable batch shapes and return float64 arrays of the
broadcast batch shape (a 0-d array for two single poses).

About yaw: our Euler angles (``R_world_from_cam = Rz(yaw) Ry(roll) Rx(pitch) diag(1, -1, -1)``) are
gimbal-locked only at roll = ±90, not at nadir. A nadir camera (roll = pitch = 0) has a well-defined yaw:
the heading of image-up (yaw 0: image-up north; compass heading of image-up = -yaw). For tilted cameras,
yaw is the heading of the horizontal part of the optical axis (compass heading -yaw) as long as roll is
small. ``yaw_error_deg`` is meaningless only near roll = ±90 (a camera lying on its side).
"""

from __future__ import annotations

import numpy as np

from semcityloc.errors import ArgumentTypeError, ShapeError
from semcityloc.geometry.conventions import wrap_deg
from semcityloc.geometry.pose import Pose


def _poses(est: Pose, gt: Pose) -> None:
    """Both arguments are ``Pose`` objects of broadcastable batch shapes, else a typed error saying which."""
    for name, pose in (("est", est), ("gt", gt)):
        if not isinstance(pose, Pose):
            raise ArgumentTypeError(f"{name} must be a semcityloc Pose, got {type(pose).__name__}")
    try:
        np.broadcast_shapes(est.batch_shape, gt.batch_shape)
    except ValueError:
        raise ShapeError(
            f"est and gt batch shapes {est.batch_shape} and {gt.batch_shape} do not broadcast"
        ) from None


def center_error_m(est: Pose, gt: Pose) -> np.ndarray:
    """Euclidean distance between the camera centres, in world units (metres)."""
    _poses(est, gt)
    return np.linalg.norm(est.center - gt.center, axis=-1)


def rotation_error_deg(est: Pose, gt: Pose) -> np.ndarray:
    """Geodesic angle of ``M = R_est @ R_gt^T`` in degrees, in [0, 180].

    ``angle = atan2(|w| / 2, (trace(M) - 1) / 2)`` with ``w = (M32 - M23, M13 - M31, M21 - M12)``: the same
    angle as ``arccos((trace - 1) / 2)`` but numerically safe without clipping and accurate for tiny
    errors too (arccos loses half the digits near 0). Identical whether R is cam_from_world or
    world_from_cam.
    """
    _poses(est, gt)
    M = est.R @ np.swapaxes(gt.R, -1, -2)
    cos = (np.trace(M, axis1=-2, axis2=-1) - 1.0) / 2.0
    w = np.stack([M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]], -1)
    return np.degrees(np.arctan2(np.linalg.norm(w, axis=-1) / 2.0, cos))


def yaw_error_deg(est: Pose, gt: Pose) -> np.ndarray:
    """Absolute difference of our yaw angles, wrapped to [0, 180] degrees (module docstring: meaning)."""
    _poses(est, gt)
    yaw_est = est.to_xyz_rpy()[..., 5]
    yaw_gt = gt.to_xyz_rpy()[..., 5]
    return np.abs(wrap_deg(yaw_est - yaw_gt))

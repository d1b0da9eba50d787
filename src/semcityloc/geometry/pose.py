"""Rigid camera poses named by their frames.

A ``Pose`` stores ``cam_from_world``: ``x_cam = R @ x_world + t``. Camera axes are OpenCV's (x right,
y down, z forward); the world is a metric frame with z up (the city model's local frame or its CRS).
A ``Pose`` may hold one pose or a batch (leading dimension N); every method works on both.

Euler convention (the paper's ``(x, y, z, roll, pitch, yaw)``, identical to LoD-Loc's):
``R_world_from_cam = Rz(yaw) @ Ry(roll) @ Rx(pitch) @ diag(1, -1, -1)``, angles in degrees.
At roll = pitch = yaw = 0 the camera looks straight down (nadir) with image-up pointing north (+y) and
image-right east (+x). Pitch tilts the optical axis from nadir toward image-up (90 = horizontal);
yaw turns the camera counter-clockwise about world +z (yaw 90: image-up points west). The compass heading
of the optical axis (clockwise from north) is ``-yaw``. See docs/conventions.md for a worked example.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from semcityloc.errors import ArgumentTypeError, PoseError, ShapeError

# The camera frame expressed in the "body" frame whose Euler angles we report (LoD-Loc's flip).
CAM_FROM_BODY_FLIP = np.diag([1.0, -1.0, -1.0])


def rotation_about_world_z(angle_deg: np.ndarray | float) -> np.ndarray:
    """(..., 3, 3) float64 rotation(s) ``Rz(a) = [[cos a, -sin a, 0], [sin a, cos a, 0], [0, 0, 1]]``.

    Counter-clockwise seen from above (+z up): it turns +x (east) toward +y (north). The one z rotation of
    the library (``Pose.rotate_world_z``, the coarse search's yaw fans, rotation reuse, the generated
    city's turned rectangles).
    """
    a = np.radians(np.asarray(angle_deg, dtype=np.float64))
    if not np.all(np.isfinite(a)):
        raise PoseError("rotation angle has non-finite entries")
    c, s = np.cos(a), np.sin(a)
    Rz = np.zeros(a.shape + (3, 3))
    Rz[..., 0, 0], Rz[..., 0, 1], Rz[..., 1, 0], Rz[..., 1, 1], Rz[..., 2, 2] = c, -s, s, c, 1.0
    return Rz


def euler_xyz_matrices(angles_deg: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices of extrinsic x, y, z Euler angles (N, 3) in degrees: scipy's
    ``Rotation.from_euler("xyz", angles, degrees=True).as_matrix()``, in numpy.

    Why not scipy's: its per-rotation loop and per-call checks were half of every ``Pose.from_state`` of
    the refinement's particle batches (stop 54). The arithmetic is scipy 1.17's: its elementary
    quaternions ``(sin(a/2) e_axis, cos(a/2))``, composed ``q_z (q_y q_x)`` by its product
    ``(p_w q_v + q_w p_v + p_v x q_v, p_w q_w - p_v . q_v)`` with the zero components' terms kept (they
    decide the sign of a zero), then its quaternion-to-matrix formula, every operation in its order: the
    same bits as that version's (checked at stop 54), and ours whatever scipy a machine installs, so
    a scipy upgrade cannot move a pose; ``tests/test_pose.py`` holds it to scipy within rounding."""
    a = np.asarray(angles_deg, dtype=np.float64).reshape(-1, 3)
    h = np.deg2rad(a) / 2.0
    s, c = np.sin(h), np.cos(h)
    sx, sy, sz = s[:, 0], s[:, 1], s[:, 2]
    cx, cy, cz = c[:, 0], c[:, 1], c[:, 2]
    # q1 = q_y q_x, with q_y = (0, sy, 0, cy) and q_x = (sx, 0, 0, cx) as (x, y, z, w)
    zsx, zsy, zcx, zcy = sx * 0.0, sy * 0.0, cx * 0.0, cy * 0.0
    x1 = cy * sx + zcx + (zsy - 0.0)
    y1 = zcy + cx * sy + (zsx - 0.0)
    z1 = zcy + zcx + (0.0 - sy * sx)
    w1 = cy * cx - zsx - zsy - 0.0
    # q = q_z q1, with q_z = (0, 0, sz, cz)
    x = cz * x1 + w1 * 0.0 + (0.0 * z1 - sz * y1)
    y = cz * y1 + w1 * 0.0 + (sz * x1 - 0.0 * z1)
    z = cz * z1 + w1 * sz + (0.0 * y1 - 0.0 * x1)
    w = cz * w1 - 0.0 * x1 - 0.0 * y1 - sz * z1
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    m = np.empty((len(a), 3, 3))
    m[:, 0, 0] = x2 - y2 - z2 + w2
    m[:, 1, 0] = 2 * (xy + zw)
    m[:, 2, 0] = 2 * (xz - yw)
    m[:, 0, 1] = 2 * (xy - zw)
    m[:, 1, 1] = -x2 + y2 - z2 + w2
    m[:, 2, 1] = 2 * (yz + xw)
    m[:, 0, 2] = 2 * (xz + yw)
    m[:, 1, 2] = 2 * (yz - xw)
    m[:, 2, 2] = -x2 - y2 + z2 + w2
    return m


# float32 holds a coordinate of this magnitude to about 1 cm; beyond, world (CRS) coordinates lose metres
# (a UTM northing of 5.8e6 to 0.5 m): they must reach a Pose in float64 (``float64_coordinates``).
FLOAT32_SAFE_M = 1.0e5
# A local frame's cameras lie within this of its origin (the model's centre; a city's tile store spans tens
# of km); farther out a pose is in world (CRS) coordinates given as local (``local_frame_problem``).
LOCAL_FRAME_REACH_M = 1.0e5


def float64_coordinates(values, what: str) -> np.ndarray:
    """``values`` as float64, refused (``PoseError``) when they come in a narrower float type at a magnitude
    that type cannot hold to a centimetre: the float64 origin was not subtracted before the cast, and the
    metres lost cannot be given back here."""
    arr = np.asarray(values)
    if arr.dtype.kind == "f" and arr.dtype.itemsize < 8 and arr.size:
        finite = arr[np.isfinite(arr)]
        largest = float(np.abs(finite).max()) if finite.size else 0.0
        if largest > FLOAT32_SAFE_M:
            step = float(np.spacing(arr.dtype.type(largest)))
            raise PoseError(
                f"{what} in {arr.dtype} at a magnitude of {largest:.4g} m (its resolution there: "
                f"{step:g} m): world coordinates must stay float64; subtract a float64 origin "
                "(model.to_local) before anything becomes float32"
            )
    return np.asarray(arr, dtype=np.float64)


def local_frame_problem(centers: np.ndarray) -> str | None:
    """Why camera centres (..., 3) cannot be in a model's local frame (more than ``LOCAL_FRAME_REACH_M``
    from its origin: world coordinates given as local), or None."""
    c = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    far = np.abs(c).max(axis=1) > LOCAL_FRAME_REACH_M if len(c) else np.zeros(0, bool)
    if not far.any():
        return None
    x, y, z = c[np.argmax(far)]
    return (
        f"camera centre ({x:.1f}, {y:.1f}, {z:.1f}) lies more than {LOCAL_FRAME_REACH_M:g} m from the "
        "local frame's origin: a pose in world (CRS) coordinates? model.pose_to_local(pose_world) gives the "
        "local one"
    )


def _check_rotation(R: np.ndarray, what: str) -> None:
    if R.size == 0:  # an empty batch is valid
        return
    if not np.all(np.isfinite(R)):
        raise PoseError(f"{what} has non-finite entries")
    should_be_eye = np.einsum("...ji,...jk->...ik", R, R)
    if np.abs(should_be_eye - np.eye(3)).max() > 1e-5 or np.any(np.linalg.det(R) < 0):
        raise PoseError(f"{what} is not a rotation matrix (orthonormal, det +1)")


def _rigid(T, what: str) -> np.ndarray:
    """(..., 4, 4) or (..., 3, 4) float64 of a rigid transform; a 4x4 whose last row is not [0, 0, 0, 1]
    (a projective matrix, a transposed one) is refused, as the pose readers refuse it."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape[-2:] not in ((4, 4), (3, 4)):
        raise ShapeError(f"{what} matrix must be (..., 4, 4) or (..., 3, 4), got {T.shape}")
    if T.shape[-2:] == (4, 4) and T.size and np.abs(T[..., 3, :] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-9:
        raise PoseError(f"the last row of a 4x4 {what} rigid transform must be [0, 0, 0, 1]")
    return T


class Pose:
    """cam_from_world rigid transform(s), float64."""

    __slots__ = ("R", "t")

    def __init__(
        self, R_cam_from_world: np.ndarray, t_cam_from_world: np.ndarray, _rotation_checked: bool = False
    ):
        # C-contiguous copies, not views: numpy's matrix products round by the operands' memory layout, and a
        # pose pickled to a worker process arrives C-contiguous; a transposed view here gave ``--workers 1``
        # poses up to 0.1 m apart from ``--workers 2`` ones (``tests/test_run_photos.py``).
        R = np.ascontiguousarray(R_cam_from_world, dtype=np.float64)
        t = np.ascontiguousarray(float64_coordinates(t_cam_from_world, "pose translation"))
        if R.shape[-2:] != (3, 3) or t.shape[-1:] != (3,) or R.shape[:-2] != t.shape[:-1]:
            raise ShapeError(f"pose needs R (..., 3, 3) and t (..., 3), got {R.shape} and {t.shape}")
        if not np.all(np.isfinite(t)):
            raise PoseError("pose translation has non-finite entries")
        if not _rotation_checked:  # ``from_xyz_rpy``'s rotations are made from finite angles: rotations
            _check_rotation(R, "pose rotation")
        self.R = R
        self.t = t

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_cam_from_world(cls, T_cam_from_world: np.ndarray) -> Pose:
        """From world-to-camera matrices (4x4 or 3x4, batches too), checked to be rigid: ``x_cam = R x_world +
        t``, the form ``Pose`` stores.
        """
        T = _rigid(T_cam_from_world, "cam_from_world")
        return cls(T[..., :3, :3], T[..., :3, 3])

    @classmethod
    def from_world_from_cam(cls, T_world_from_cam: np.ndarray) -> Pose:
        """From camera-to-world matrices (LoD-Loc's ``*_pose.txt``, OpenCV camera axes)."""
        T = _rigid(T_world_from_cam, "world_from_cam")
        return cls.from_rotation_center(T[..., :3, :3], T[..., :3, 3])

    @classmethod
    def from_rotation_center(
        cls, R_world_from_cam: np.ndarray, center: np.ndarray, _rotation_checked: bool = False
    ) -> Pose:
        """From the camera's orientation in the world and its centre (world coordinates)."""
        Rwc = np.asarray(R_world_from_cam, dtype=np.float64)
        C = float64_coordinates(center, "camera centre")
        if Rwc.shape[-2:] != (3, 3) or C.shape[-1:] != (3,):
            raise ShapeError(
                f"a pose needs a rotation (..., 3, 3) and a centre (..., 3), got {Rwc.shape} and {C.shape}"
            )
        if not np.all(np.isfinite(C)):
            raise PoseError("camera centre has non-finite entries")
        R = np.swapaxes(Rwc, -1, -2)
        return cls(R, -np.einsum("...ij,...j->...i", R, C), _rotation_checked)

    @classmethod
    def from_xyz_rpy(cls, xyz: np.ndarray, roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> Pose:
        """From camera centre(s) and roll/pitch/yaw in degrees (module docstring convention)."""
        xyz = float64_coordinates(xyz, "camera centre")
        if xyz.shape[-1:] != (3,):
            raise ShapeError(f"camera centre(s) must have shape (..., 3), got {xyz.shape}")
        angles = np.stack(np.broadcast_arrays(pitch, roll, yaw), axis=-1).astype(np.float64)
        if not np.all(np.isfinite(angles)):
            raise PoseError("roll/pitch/yaw have non-finite entries")
        R_body = euler_xyz_matrices(angles.reshape(-1, 3)).reshape(angles.shape[:-1] + (3, 3))
        return cls.from_rotation_center(R_body @ CAM_FROM_BODY_FLIP, xyz, _rotation_checked=True)

    @classmethod
    def from_state(cls, state: np.ndarray) -> Pose:
        """From (..., 6) state vectors (x, y, z, roll, pitch, yaw; metres and degrees), as ``to_xyz_rpy``
        returns them and the search and the refinement move them."""
        s = np.asarray(state, dtype=np.float64)
        if s.shape[-1:] != (6,):
            raise ShapeError(f"pose states must have shape (..., 6), got {s.shape}")
        return cls.from_xyz_rpy(s[..., :3], s[..., 3], s[..., 4], s[..., 5])

    @classmethod
    def stack(cls, poses: list[Pose]) -> Pose:
        """One batched ``Pose`` of single poses, in order: the renderer and the scores take batches."""
        return cls(np.stack([p.R for p in poses]), np.stack([p.t for p in poses]))

    # ------------------------------------------------------------------ views
    @property
    def batch_shape(self) -> tuple[int, ...]:
        """The leading dimensions of a batch of poses (``()`` for a single pose)."""
        return self.R.shape[:-2]

    def __len__(self) -> int:
        if not self.batch_shape:
            raise TypeError("a single Pose has no len()")
        return self.batch_shape[0]

    def __getitem__(self, index) -> Pose:
        if not self.batch_shape:
            raise ArgumentTypeError(
                "a single Pose cannot be indexed or iterated (one camera; a batch is Pose.stack([...]))"
            )
        return Pose(self.R[index], self.t[index])

    def __repr__(self) -> str:
        if self.batch_shape:
            return f"Pose(batch={self.batch_shape})"
        x, y, z, r, p, yw = self.to_xyz_rpy()
        return f"Pose(center=({x:.3f}, {y:.3f}, {z:.3f}), roll={r:.3f}, pitch={p:.3f}, yaw={yw:.3f})"

    @property
    def R_world_from_cam(self) -> np.ndarray:
        """The camera-to-world rotation ``R^T``: the camera's axes as world directions (column 2 is the
        viewing direction).
        """
        return np.swapaxes(self.R, -1, -2)

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates: ``-R^T t``."""
        return -np.einsum("...ji,...j->...i", self.R, self.t)

    @property
    def cam_from_world(self) -> np.ndarray:
        """The 4x4 world-to-camera matrix(es) [R | t; 0 0 0 1]."""
        T = np.zeros(self.batch_shape + (4, 4))
        T[..., :3, :3] = self.R
        T[..., :3, 3] = self.t
        T[..., 3, 3] = 1.0
        return T

    @property
    def world_from_cam(self) -> np.ndarray:
        """The 4x4 camera-to-world matrix(es) [R^T | centre; 0 0 0 1] (LoD-Loc's ``*_pose.txt`` form)."""
        T = np.zeros(self.batch_shape + (4, 4))
        T[..., :3, :3] = self.R_world_from_cam
        T[..., :3, 3] = self.center
        T[..., 3, 3] = 1.0
        return T

    @property
    def viewing_direction(self) -> np.ndarray:
        """Unit optical axis (camera +z) in world coordinates."""
        return self.R_world_from_cam[..., :, 2]

    def to_xyz_rpy(self) -> np.ndarray:
        """(..., 6) array (x, y, z, roll, pitch, yaw) in degrees; inverse of ``from_xyz_rpy``."""
        R_body = self.R_world_from_cam @ CAM_FROM_BODY_FLIP
        flat = Rotation.from_matrix(R_body.reshape(-1, 3, 3)).as_euler("xyz", degrees=True)
        pitch, roll, yaw = flat[:, 0], flat[:, 1], flat[:, 2]
        out = np.concatenate([self.center.reshape(-1, 3), np.stack([roll, pitch, yaw], 1)], axis=1)
        return out.reshape(self.batch_shape + (6,))

    # ------------------------------------------------------------------ operations
    def transform(self, points_world: np.ndarray) -> np.ndarray:
        """World points (M, 3) -> camera-frame points (..., M, 3)."""
        p = np.asarray(points_world, dtype=np.float64)
        return np.einsum("...ij,mj->...mi", self.R, p) + self.t[..., None, :]

    def directions_to_world(self, vectors_cam: np.ndarray) -> np.ndarray:
        """Camera-frame vectors (..., 3) -> world frame (``R^T v``; no translation) for a single pose.

        Elementwise, no BLAS: the same bits on every machine, and not slowed by a busy multi-threaded BLAS.
        A pixel's ray in the world: ``directions_to_world(camera.ray_directions())``."""
        v = np.asarray(vectors_cam, dtype=np.float64)
        R = self.R
        return v[..., :1] * R[0] + v[..., 1:2] * R[1] + v[..., 2:3] * R[2]

    def points_to_world(self, points_cam: np.ndarray) -> np.ndarray:
        """Camera-frame points (..., 3) -> world points (``R^T p + C``) for a single pose; the inverse of
        ``transform``. A pixel and its z-depth: ``points_to_world(camera.unproject(uv, depth))``."""
        return self.directions_to_world(points_cam) + self.center

    def shift_world(self, offset: np.ndarray) -> Pose:
        """The same camera in a world frame whose origin moved by ``offset`` (new = old - offset).

        ``CityModel.pose_to_local`` / ``pose_to_world`` wrap this with the model's origin (CRS <-> local).
        """
        offset = np.asarray(offset, dtype=np.float64)
        return Pose.from_rotation_center(self.R_world_from_cam, self.center - offset)

    def rotate_world_z(self, angle_deg: np.ndarray) -> Pose:
        """Turn the camera about the world z axis through its own centre (adds ``angle_deg`` to yaw)."""
        a = np.asarray(angle_deg, dtype=np.float64)
        batch = np.broadcast_shapes(a.shape, self.batch_shape)
        Rz = rotation_about_world_z(np.broadcast_to(a, batch))
        return Pose.from_rotation_center(
            Rz @ self.R_world_from_cam, np.broadcast_to(self.center, batch + (3,))
        )


def yaw_fan_rotations(roll: float, pitch: float, yaws: np.ndarray) -> np.ndarray:
    """(Y, 3, 3) cam_from_world rotations at ``(roll, pitch, yaws[k])`` (degrees): the rotations a search
    tries about one camera centre (the cascade's sweeps, the wireframe baseline's grid)."""
    n = len(yaws)
    return Pose.from_xyz_rpy(np.zeros((n, 3)), np.full(n, roll), np.full(n, pitch), yaws).R

"""Small shared helpers of the localizer tests (not a test module): the test camera and views of the
generated city (``conftest.generated_lod2``)."""

from __future__ import annotations

import numpy as np

from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose

CAMERA = Camera.from_fov(512, 384, 70.0)


def view(city, dx, dy, height, roll, pitch, yaw) -> Pose:
    """A camera ``(dx, dy)`` from the city's centre, ``height`` above its lowest point."""
    lo, hi = city.bounds_local
    centre = 0.5 * (lo + hi)
    return Pose.from_xyz_rpy([centre[0] + dx, centre[1] + dy, lo[2] + height], roll, pitch, yaw)


def perturbed(pose: Pose, dxyz, droll=0.0, dpitch=0.0, dyaw=0.0) -> Pose:
    """``pose`` moved by ``dxyz`` (m) and turned by the angle offsets (deg)."""
    x, y, z, roll, pitch, yaw = pose.to_xyz_rpy()
    return Pose.from_xyz_rpy(np.array([x, y, z]) + dxyz, roll + droll, pitch + dpitch, yaw + dyaw)

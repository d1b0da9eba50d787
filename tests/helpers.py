"""Small shared helpers of the tests (not a test module): the test camera and views of the generated city
(``conftest.generated_lod2``), and the scripts of ``benchmarks/`` loaded as modules."""

from __future__ import annotations

import errno
import importlib.util
import os
from pathlib import Path
from types import ModuleType

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


def deny_reading(monkeypatch, path: Path) -> None:
    """Make reading ``path`` (``Path.read_bytes`` / ``read_text``) fail with "Permission denied", as a file of
    mode 000 does for a user other than root (the tests may run as root, who reads it anyway)."""
    read_bytes = Path.read_bytes

    def denied(self):
        if self == path:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(self))
        return read_bytes(self)

    monkeypatch.setattr(Path, "read_bytes", denied)
    monkeypatch.setattr(Path, "read_text", lambda self, *args, **kwargs: denied(self).decode())


def benchmark_script(name: str) -> ModuleType:
    """``benchmarks/<name>.py`` loaded as a module (the scripts are not a package)."""
    path = Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module

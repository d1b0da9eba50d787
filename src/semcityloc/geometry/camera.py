"""Pinhole camera intrinsics.

Pixel convention (COLMAP / OpenCV calibration): pixel (row i, column j) covers [j, j+1) x [i, i+1) and
its centre is at image coordinates (u, v) = (j + 0.5, i + 0.5); the top-left pixel's centre is (0.5, 0.5).
A camera point (x, y, z) (x right, y down, z forward) projects to u = fx x/z + cx, v = fy y/z + cy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from semcityloc.errors import ArgumentTypeError, CameraError, ShapeError

MAX_SIDE_PX = 100_000  # wider or taller than any camera's sensor: a calibration file's typo or garbage
# How far a principal point may lie from the image centre, as a share of the image's width / height, before
# the intrinsics are taken for another image's: a resized or cropped copy (DJI's calibration tags are then
# not used, ``datasets.dji_camera``), or another camera's (a calibration file is then refused for the
# photo, ``geometry.io.check_fits_photo``). Calibrated drone lenses are centred within a few %.
PRINCIPAL_POINT_TOLERANCE = 0.1


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: focal lengths and principal point in pixels, image size; no distortion.

    The one camera model of the pipeline: renderers, masks, the search and the pose files all assume it,
    and a photo with lens distortion is resampled to it first (``geometry.distortion``). Pixel centres sit
    at half-integers: pixel (row i, column j) covers [j, j+1) x [i, i+1) and its centre is
    (u, v) = (j + 0.5, i + 0.5), so the top-left pixel's centre is (0.5, 0.5) and ``cx = width / 2`` is the
    image's middle (COLMAP / OpenCV calibration; docs/conventions.md). Camera axes are OpenCV's (x right,
    y down, z forward): (x, y, z) projects to (fx x / z + cx, fy y / z + cy). Values are checked when made
    (finite numbers, not bools; positive focal lengths; whole positive sizes up to ``MAX_SIDE_PX``), so a
    typo in a calibration file is a ``CameraError`` here rather than an empty render later.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            number = isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool)
            if not number or not math.isfinite(value):  # a bool is an int to Python: True is no focal length
                raise CameraError(f"camera {name} must be a finite number, got {value!r}")
            object.__setattr__(self, name, float(value))
        if self.fx <= 0 or self.fy <= 0:
            raise CameraError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value <= 0:
                raise CameraError(f"camera {name} must be a positive integer, got {value!r}")
            if value > MAX_SIDE_PX:
                raise CameraError(f"camera {name} must be at most {MAX_SIDE_PX} pixels, got {value!r}")
            object.__setattr__(self, name, int(value))

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_K(cls, K: np.ndarray, width: int, height: int) -> Camera:
        """From a 3x3 (or 3x4 ``[K|0]``) intrinsic matrix."""
        K = np.asarray(K, dtype=np.float64)
        if K.shape not in ((3, 3), (3, 4)):
            raise ShapeError(f"intrinsic matrix must be 3x3 or 3x4, got shape {K.shape}")
        if abs(K[0, 1]) > 1e-9 * max(abs(K[0, 0]), 1.0):
            raise CameraError("skewed intrinsics (K[0,1] != 0) are not supported")
        return cls(K[0, 0], K[1, 1], K[0, 2], K[1, 2], width, height)

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float) -> Camera:
        """Square pixels, principal point at the image centre, horizontal field of view in degrees.

        A field of view up to pi "degrees" is refused as radians (``math.radians(70)`` is 1.22: a 1.2 degree
        camera would be built silently, whose views of a city hold one window); the narrowest drone zoom
        lenses are a little below that, and no localizer of this package can use such a view."""
        if isinstance(hfov_deg, bool) or not isinstance(hfov_deg, (int, float, np.integer, np.floating)):
            raise ArgumentTypeError(f"horizontal field of view must be a number of degrees, got {hfov_deg!r}")
        if not 0 < hfov_deg < 180:
            raise CameraError(f"horizontal field of view must be in (0, 180) degrees, got {hfov_deg}")
        if hfov_deg <= math.pi:
            meant = math.degrees(hfov_deg)
            raise CameraError(
                f"horizontal field of view {hfov_deg} looks like radians (at most pi): give degrees"
                + (f", e.g. math.degrees({hfov_deg}) = {meant:.1f}" if meant < 180 else " in (0, 180)")
            )
        f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2)
        return cls(f, f, width / 2, height / 2, width, height)

    # ------------------------------------------------------------------ properties
    @property
    def K(self) -> np.ndarray:
        """The 3x3 intrinsic matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (float64), in the pixel-centre
        convention of the class.
        """
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], dtype=np.float64)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height)."""
        return self.width, self.height

    @property
    def hfov_deg(self) -> float:
        """The horizontal field of view in degrees, from the width and fx (edge to edge of the image)."""
        return math.degrees(2 * math.atan(0.5 * self.width / self.fx))

    @property
    def vfov_deg(self) -> float:
        """The vertical field of view in degrees, from the height and fy (edge to edge of the image)."""
        return math.degrees(2 * math.atan(0.5 * self.height / self.fy))

    def principal_point_offset(self) -> float:
        """How far the principal point lies from the image centre: the larger of its offsets as shares of
        the width and of the height (0: centred; compared with ``PRINCIPAL_POINT_TOLERANCE``)."""
        return max(abs(self.cx - self.width / 2) / self.width, abs(self.cy - self.height / 2) / self.height)

    def scaled(self, width: int, height: int) -> Camera:
        """The same camera sampled at another resolution (the image edges stay where they are)."""
        sx, sy = width / self.width, height / self.height
        return Camera(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, width, height)

    def scale(self, factor: float) -> Camera:
        """Resolution times ``factor``, rounded to whole pixels."""
        return self.scaled(max(1, round(self.width * factor)), max(1, round(self.height * factor)))

    # ------------------------------------------------------------------ geometry
    def pixel_centers(self) -> np.ndarray:
        """(H, W, 2) image coordinates (u, v) of every pixel centre."""
        u = np.arange(self.width) + 0.5
        v = np.arange(self.height) + 0.5
        uu, vv = np.meshgrid(u, v)
        return np.stack([uu, vv], axis=-1)

    def ray_directions(self, normalize: bool = False) -> np.ndarray:
        """(H, W, 3) camera-frame rays through the pixel centres; z = 1 unless ``normalize``."""
        uv = self.pixel_centers()
        rays = np.stack(
            [(uv[..., 0] - self.cx) / self.fx, (uv[..., 1] - self.cy) / self.fy, np.ones(uv.shape[:2])],
            axis=-1,
        )
        if normalize:
            rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
        return rays

    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Camera-frame points (..., 3) -> image coordinates (..., 2) and a mask of points in front."""
        p = np.asarray(points_cam, dtype=np.float64)
        if p.shape[-1] != 3:
            raise ShapeError(f"points must have shape (..., 3), got {p.shape}")
        z = p[..., 2]
        in_front = z > 1e-9
        zs = np.where(in_front, z, 1.0)
        uv = np.stack([self.fx * p[..., 0] / zs + self.cx, self.fy * p[..., 1] / zs + self.cy], axis=-1)
        return uv, in_front

    def unproject(self, uv: np.ndarray, depth: np.ndarray | float = 1.0) -> np.ndarray:
        """Image coordinates (..., 2) and z-depth -> camera-frame points (..., 3)."""
        uv = np.asarray(uv, dtype=np.float64)
        d = np.asarray(depth, dtype=np.float64)
        x = (uv[..., 0] - self.cx) / self.fx
        y = (uv[..., 1] - self.cy) / self.fy
        return np.stack([x * d, y * d, np.ones_like(x) * d], axis=-1)

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """Whether image coordinates (..., 2) lie in the image, u in [0, width) and v in [0, height): pixel
        edges, not centres, bound it.
        """
        uv = np.asarray(uv)
        return (uv[..., 0] >= 0) & (uv[..., 0] < self.width) & (uv[..., 1] >= 0) & (uv[..., 1] < self.height)

    def as_dict(self) -> dict:
        """The camera as a JSON-ready dict in COLMAP's ``PINHOLE`` terms (model, size, fx, fy, cx, cy): how
        pose files and run records state the intrinsics used.
        """
        return {
            "model": "PINHOLE",
            "width": self.width,
            "height": self.height,
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
        }

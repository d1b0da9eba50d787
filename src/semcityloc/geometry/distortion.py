"""Lens distortion: the OpenCV (Brown–Conrady) radial-tangential model, and images resampled between a
distorted photo and the pinhole camera the rest of the pipeline assumes.

Why: the renderer, the localizer and every mask are pinhole (``geometry/camera.py``); photos are not. A
drone camera's distortion moves the image corners by pixels even at the localizer's working resolution,
and a pinhole fit to a distorted image lands the camera off by as much. Users have the coefficients from
COLMAP / OpenDroneMap (``OPENCV``, ``RADIAL``, ``SIMPLE_RADIAL``) or from the photo (DJI's
``DewarpData``); rather than asking them to undistort first, the photo run and ``semcityloc localize``
resample the photo, its mask and its depth onto the pinhole camera with the same ``K``
(``undistort_image``), and ``semcityloc label`` resamples its rendered labels the other way
(``distort_image``) so that they lie on the photo they label.

Model, in normalised camera coordinates ``x = X / Z``, ``y = Y / Z``, ``r² = x² + y²``::

    x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2 x²)
    y_d = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2 y²) + 2 p2 x y

and the pixel ``u = fx x_d + cx``, ``v = fy y_d + cy`` (pixel centres at +0.5, ``geometry/camera.py``).
This is OpenCV's five-coefficient model and COLMAP's ``OPENCV``; ``RADIAL`` has ``p1 = p2 = k3 = 0``,
``SIMPLE_RADIAL`` only ``k1``. The inverse (``undistort``) is the fixed-point iteration OpenCV's
``undistortPoints`` uses; ``UNDISTORT_TOL_PX`` bounds its error over the image
(``max_inverse_error_px``, checked in ``tests/test_distortion.py``).

The pinhole image keeps the photo's ``K``. Under barrel distortion (``k1 < 0``, the usual) the photo sees
more than that pinhole view and its corners are cut; under pincushion the pinhole view's corners lie
outside the photo and get the fill value (IGNORE for labels, NaN for depth, black for the photo), as the
photo's corners do in ``distort_image`` under barrel distortion.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.ndimage import map_coordinates

from semcityloc.errors import CameraError, ShapeError
from semcityloc.geometry.camera import Camera

COEFFICIENTS = ("k1", "k2", "p1", "p2", "k3")  # OpenCV's order
UNDISTORT_ITERATIONS = 20
# The inverse's error a camera is refused above (pixels, anywhere in the image): a distortion so strong
# that the model folds over inside the image has no inverse there.
UNDISTORT_TOL_PX = 0.05
# Below this largest displacement (pixels at the image's own resolution) resampling changes nothing.
NEGLIGIBLE_SHIFT_PX = 0.05


@dataclass(frozen=True)
class LensDistortion:
    """Radial (k1, k2, k3) and tangential (p1, p2) coefficients, normalised coordinates (module docstring).
    All zero: a pinhole camera."""

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0

    def __post_init__(self) -> None:
        for name in COEFFICIENTS:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise CameraError(f"distortion {name} must be a number, got {value!r}")
            if not math.isfinite(value):
                raise CameraError(f"distortion {name} must be finite, got {value!r}")
            object.__setattr__(self, name, float(value))

    @classmethod
    def from_params(cls, params: dict[str, float]) -> LensDistortion:
        """From COLMAP's parameter names (``k`` of SIMPLE_RADIAL is ``k1``); others are ignored."""
        return cls(
            k1=params.get("k1", params.get("k", 0.0)),
            k2=params.get("k2", 0.0),
            p1=params.get("p1", 0.0),
            p2=params.get("p2", 0.0),
            k3=params.get("k3", 0.0),
        )

    @property
    def is_zero(self) -> bool:
        """Whether every coefficient is 0, so images need no undistortion."""
        return not any(getattr(self, name) for name in COEFFICIENTS)

    def as_dict(self) -> dict[str, float]:
        """The coefficients under COLMAP's model name ``OPENCV``, for records and exports."""
        return {"model": "OPENCV", **asdict(self)}

    # ------------------------------------------------------------------ points
    def distort(self, xy: np.ndarray) -> np.ndarray:
        """Normalised pinhole coordinates (..., 2) -> distorted normalised coordinates (..., 2)."""
        xy = _points(xy)
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
        yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y
        return np.stack([xd, yd], axis=-1)

    def undistort(self, xy_distorted: np.ndarray) -> np.ndarray:
        """Distorted normalised coordinates (..., 2) -> pinhole ones: ``distort``'s inverse by fixed-point
        iteration (``UNDISTORT_ITERATIONS``)."""
        xd = _points(xy_distorted)
        xy = xd.copy()
        for _ in range(UNDISTORT_ITERATIONS):
            x, y = xy[..., 0], xy[..., 1]
            r2 = x * x + y * y
            radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
            dx = 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
            dy = self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y
            xy = np.stack([(xd[..., 0] - dx) / radial, (xd[..., 1] - dy) / radial], axis=-1)
        return xy

    # ------------------------------------------------------------------ pixels
    def distorted_pixels(self, camera: Camera, uv: np.ndarray) -> np.ndarray:
        """Pixel coordinates (..., 2) of the pinhole ``camera`` -> where the photo shows them."""
        return _to_pixels(camera, self.distort(_to_normalised(camera, uv)))

    def pinhole_pixels(self, camera: Camera, uv_distorted: np.ndarray) -> np.ndarray:
        """Pixel coordinates (..., 2) of the photo -> where the pinhole ``camera`` shows them."""
        return _to_pixels(camera, self.undistort(_to_normalised(camera, uv_distorted)))

    def max_shift_px(self, camera: Camera) -> float:
        """The largest displacement distortion causes over ``camera``'s image (its border and centre
        lines; pixels at its resolution)."""
        uv = _border_samples(camera)
        return float(np.max(np.linalg.norm(self.distorted_pixels(camera, uv) - uv, axis=-1)))

    def max_inverse_error_px(self, camera: Camera) -> float:
        """How far ``undistort`` misses over ``camera``'s image (pixels): large where the model folds."""
        uv = _border_samples(camera)
        with np.errstate(over="ignore", invalid="ignore"):  # a hostile coefficient: inf, then refused
            back = self.distorted_pixels(camera, self.pinhole_pixels(camera, uv))
            error = np.linalg.norm(back - uv, axis=-1)
        return float(np.max(np.where(np.isfinite(error), error, np.inf)))

    def check(self, camera: Camera) -> None:
        """``CameraError`` when the model cannot be inverted over ``camera``'s image."""
        error = self.max_inverse_error_px(camera)
        if not error <= UNDISTORT_TOL_PX:
            raise CameraError(
                f"lens distortion {self.as_dict()} cannot be inverted over the {camera.width} x "
                f"{camera.height} image (off by {error:.3g} px): the coefficients do not describe this "
                "image (another resolution's, or another model's)"
            )


# ---------------------------------------------------------------------------------------------- images
def undistort_image(
    image: np.ndarray, camera: Camera, distortion: LensDistortion, fill: float, nearest: bool
) -> np.ndarray:
    """A photo-shaped array (H, W) or (H, W, C) resampled onto the pinhole camera with the same ``K``.

    ``camera``: the photo's intrinsics at any resolution (rescaled to the array's). ``nearest`` for
    labels and depth (no label or depth is invented between two surfaces), bilinear for a photo.
    Pixels the photo does not show get ``fill``. Returned unchanged when distortion moves nothing by
    ``NEGLIGIBLE_SHIFT_PX``."""
    cam = _camera_for(image, camera)
    if distortion.max_shift_px(cam) < NEGLIGIBLE_SHIFT_PX:
        return image
    return _resample(image, distortion.distorted_pixels(cam, cam.pixel_centers()), fill, nearest)


def distort_image(
    image: np.ndarray,
    camera: Camera,
    distortion: LensDistortion,
    fill: float,
    nearest: bool,
    source: Camera | None = None,
) -> np.ndarray:
    """``undistort_image``'s inverse: a pinhole array (e.g. labels rendered from the model) resampled
    onto the distorted photo's pixels. ``source``: the array's own camera when it is a wider canvas
    around ``camera``'s pinhole image (``pinhole_canvas``: the same focal length and principal ray), so
    that the rays a barrel lens pulls into the photo's corners are there; the photo is then ``camera``'s
    size. Without it, the array is ``camera``'s pinhole image at any resolution, and the photo's pixels
    whose rays fall outside it get ``fill``."""
    if source is None:
        cam = _camera_for(image, camera)
        if distortion.max_shift_px(cam) < NEGLIGIBLE_SHIFT_PX:
            return image
        distortion.check(cam)
        return _resample(image, distortion.pinhole_pixels(cam, cam.pixel_centers()), fill, nearest)
    if np.asarray(image).shape[:2] != (source.height, source.width):
        raise ShapeError(
            f"the array {np.asarray(image).shape} is not the {source.width} x {source.height} canvas"
        )
    distortion.check(camera)
    uv = distortion.pinhole_pixels(camera, camera.pixel_centers())
    scale = np.array([source.fx / camera.fx, source.fy / camera.fy])
    uv = (uv - [camera.cx, camera.cy]) * scale + [source.cx, source.cy]
    return _resample(image, uv, fill, nearest)


def pinhole_canvas(camera: Camera, distortion: LensDistortion) -> Camera:
    """The pinhole camera with ``camera``'s focal length and principal ray whose image holds every ray of
    the distorted photo: ``camera`` widened by whole pixels on each side where the lens pulls rays from
    outside its pinhole image (barrel distortion's corners); ``camera`` itself when none are."""
    if distortion.is_zero:
        return camera
    border = distortion.pinhole_pixels(camera, _border_samples(camera))
    over_x = max(0.0, float(-border[:, 0].min()), float(border[:, 0].max() - camera.width))
    over_y = max(0.0, float(-border[:, 1].min()), float(border[:, 1].max() - camera.height))
    mx, my = (math.ceil(v - NEGLIGIBLE_SHIFT_PX) if v > NEGLIGIBLE_SHIFT_PX else 0 for v in (over_x, over_y))
    if mx == 0 and my == 0:
        return camera
    return Camera(
        camera.fx, camera.fy, camera.cx + mx, camera.cy + my, camera.width + 2 * mx, camera.height + 2 * my
    )


def unseen_by_photo(shape: tuple[int, int], camera: Camera, distortion: LensDistortion) -> np.ndarray:
    """(H, W) bool: the pixels of the undistorted (pinhole) image of that size that the photo does not
    show (a border, widest at the corners, under pincushion distortion: where ``undistort_image``
    fills). A network run on the undistorted photo sees the fill there; its output there says nothing."""
    blank = np.zeros(tuple(shape), dtype=bool)
    return undistort_image(blank, camera, distortion, fill=True, nearest=True)


def _resample(image: np.ndarray, uv: np.ndarray, fill: float, nearest: bool) -> np.ndarray:
    """``image`` sampled at pixel coordinates ``uv`` (H', W', 2); outside the image: ``fill``."""
    rows, cols = uv[..., 1] - 0.5, uv[..., 0] - 0.5  # pixel (i, j)'s centre is (j + 0.5, i + 0.5)
    h, w = image.shape[:2]
    inside = (rows >= -0.5) & (rows <= h - 0.5) & (cols >= -0.5) & (cols <= w - 0.5)
    coords = np.stack([np.clip(rows, 0, h - 1), np.clip(cols, 0, w - 1)])
    if nearest:
        out = image[np.rint(coords[0]).astype(np.intp), np.rint(coords[1]).astype(np.intp)]
        out = np.array(out, copy=True)
    else:
        planes = image[..., None] if image.ndim == 2 else image
        sampled = [
            map_coordinates(planes[..., c].astype(np.float32), coords, order=1, mode="nearest")
            for c in range(planes.shape[-1])
        ]
        out = np.stack(sampled, axis=-1).reshape(uv.shape[:2] + image.shape[2:])
        if np.issubdtype(image.dtype, np.integer):
            info = np.iinfo(image.dtype)
            out = np.clip(np.rint(out), info.min, info.max)
        out = out.astype(image.dtype)
    out[~inside] = fill
    return out


def _camera_for(image: np.ndarray, camera: Camera) -> Camera:
    image = np.asarray(image)
    if image.ndim not in (2, 3) or min(image.shape[:2]) < 1:
        raise ShapeError(f"expected an (H, W) or (H, W, C) image, got shape {image.shape}")
    h, w = image.shape[:2]
    return camera if camera.size == (w, h) else camera.scaled(w, h)


def _points(xy: np.ndarray) -> np.ndarray:
    xy = np.asarray(xy, dtype=np.float64)
    if xy.shape[-1:] != (2,):
        raise ShapeError(f"points must have shape (..., 2), got {xy.shape}")
    return xy


def _to_normalised(camera: Camera, uv: np.ndarray) -> np.ndarray:
    uv = _points(uv)
    return np.stack([(uv[..., 0] - camera.cx) / camera.fx, (uv[..., 1] - camera.cy) / camera.fy], axis=-1)


def _to_pixels(camera: Camera, xy: np.ndarray) -> np.ndarray:
    return np.stack([camera.fx * xy[..., 0] + camera.cx, camera.fy * xy[..., 1] + camera.cy], axis=-1)


def _border_samples(camera: Camera, n: int = 64) -> np.ndarray:
    """Points along the image border and its two centre lines, where distortion is largest / checked."""
    u = np.linspace(0.0, camera.width, n)
    v = np.linspace(0.0, camera.height, n)
    w, h = float(camera.width), float(camera.height)
    lines = [
        np.stack([u, np.zeros(n)], -1),
        np.stack([u, np.full(n, h)], -1),
        np.stack([np.zeros(n), v], -1),
        np.stack([np.full(n, w), v], -1),
        np.stack([u, np.full(n, h / 2)], -1),
        np.stack([np.full(n, w / 2), v], -1),
    ]
    return np.concatenate(lines)

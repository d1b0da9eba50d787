"""A DJI photo's pinhole camera and lens distortion, from its own metadata (``DjiMetadata``).

Why: a user's photos need intrinsics, and DJI writes them. ``calibrated_intrinsics`` makes the pinhole
camera from DJI's per-unit calibration tags (``CalibratedFocalLength``, ``CalibratedOpticalCenterX`` /
``Y``); ``dewarp_lens`` the camera with its lens distortion from ``DewarpData`` when the camera did not
undistort the photo itself (``DewarpFlag`` 0); ``camera_from_exif`` the calibration when the photo has
one, else approximately from the 35 mm-equivalent focal length. The tags are in pixels of the image the
camera wrote: on a resized or cropped copy they describe another image and are not used.
"""

from __future__ import annotations

import math

from semcityloc.datasets.dji_metadata import DjiMetadata
from semcityloc.errors import CameraError
from semcityloc.geometry.camera import PRINCIPAL_POINT_TOLERANCE, Camera
from semcityloc.geometry.distortion import LensDistortion

FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)  # the "35 mm equivalent" is defined on the diagonal
# How far ``DewarpData``'s focal length may lie from the 35 mm-equivalent one (a share of the latter,
# ``|fx / f35_px - 1|``) before the tag is taken to describe another image than the photo (a resized copy:
# its focal length in pixels scales with the size, so half the size is 50 % off). Not a measured bound: the
# 35 mm value is approximate (a whole number of millimetres in EXIF, ±2 % for a 24 mm lens; 2.4 % short of
# the calibration on the real H20T image, ``camera_from_exif``), so it must allow a few %, while a copy
# shrunk by 10 % or more (or enlarged by more than about 11 %) is caught. Its value, 0.1, is the one this
# check shared with ``geometry.camera.PRINCIPAL_POINT_TOLERANCE`` (a principal point's offset as a share of
# the image size, another quantity) until it got its own name.
FOCAL_35MM_TOLERANCE = 0.1


def camera_from_exif(meta: DjiMetadata) -> Camera:
    """The photo's pinhole camera from its own metadata (principal point at the centre unless calibrated).

    DJI's calibration when the photo carries one (``calibrated_intrinsics``). Otherwise the 35 mm-equivalent
    focal length: ``f_px = f35 / 43.27 mm x image diagonal in pixels`` (the equivalent focal length is
    defined on the diagonal of a 36 x 24 mm frame). Measured on the real DJI H20T thermal demo image (no
    calibration tags): 1098.6 px against LoD-Loc's calibrated 1125 px (2.4 % short), which lowers the
    camera by as much (``docs/your-data.md``, section 4). Use a calibration when there is one.
    """
    calibrated = calibrated_intrinsics(meta)
    if calibrated is not None:
        return calibrated
    if meta.focal_length_35mm is None or meta.width is None or meta.height is None:
        raise CameraError(
            "the image has no 35 mm-equivalent focal length (EXIF FocalLengthIn35mmFilm) or size"
        )
    f = meta.focal_length_35mm / FULL_FRAME_DIAGONAL_MM * math.hypot(meta.width, meta.height)
    return Camera(f, f, meta.width / 2.0, meta.height / 2.0, meta.width, meta.height)


def dewarp_lens(meta: DjiMetadata) -> tuple[Camera, LensDistortion] | None:
    """The camera and lens distortion of DJI's ``DewarpData``, or None: no tag, a photo the camera already
    undistorted (``DewarpFlag`` 1), a tag that does not fit the photo's size, or coefficients that cannot be
    inverted over it.

    The tag is in pixels of the image the camera wrote; its principal point is an offset from that image's
    centre. A resized or cropped copy is recognised as in ``calibrated_intrinsics`` when the photo also
    has the calibration tags; without them, by a focal length more than ``FOCAL_35MM_TOLERANCE`` off the
    35 mm-equivalent one."""
    if meta.dewarp is None or meta.dewarp_flag == 1 or meta.width is None or meta.height is None:
        return None
    fx, fy, dx, dy, k1, k2, p1, p2, k3 = meta.dewarp
    if fx <= 0 or fy <= 0:
        return None
    if meta.calibrated_focal_px is not None and calibrated_intrinsics(meta) is None:
        return None  # the calibration tags say the photo is not the image the camera wrote
    if meta.focal_length_35mm is not None:
        approximate = meta.focal_length_35mm / FULL_FRAME_DIAGONAL_MM * math.hypot(meta.width, meta.height)
        if abs(fx / approximate - 1.0) > FOCAL_35MM_TOLERANCE:
            return None
    camera = Camera(fx, fy, meta.width / 2.0 + dx, meta.height / 2.0 + dy, meta.width, meta.height)
    distortion = LensDistortion(k1=k1, k2=k2, p1=p1, p2=p2, k3=k3)
    try:
        distortion.check(camera)
    except CameraError:
        return None
    return camera, distortion


def calibrated_intrinsics(meta: DjiMetadata) -> Camera | None:
    """The camera of DJI's calibration tags, or None when the photo has none or they do not fit its size.

    The tags are in pixels of the image the camera wrote. A photo resized or cropped since has its optical
    centre far from where the tags put it; then the tags describe another image and are not used (more
    than ``geometry.camera.PRINCIPAL_POINT_TOLERANCE`` of the image size off its centre, the bound a
    calibration file is held to as well)."""
    f, cx, cy = meta.calibrated_focal_px, meta.calibrated_cx_px, meta.calibrated_cy_px
    if f is None or cx is None or cy is None or meta.width is None or meta.height is None or f <= 0:
        return None
    camera = Camera(f, f, cx, cy, meta.width, meta.height)
    return camera if camera.principal_point_offset() <= PRINCIPAL_POINT_TOLERANCE else None

"""A camera given on the command line, checked against the photo it is used with.

Why: intrinsics given with ``--image`` (``read_lens_for_photo``) that belong to another camera would draw
or localize on that photo's pixels wrongly, silently. (A pose given on the command line is checked
against the model's CRS by ``citymodel.pose_crs.read_pose_world``.)
"""

from __future__ import annotations

import argparse
from pathlib import Path

from semcityloc.errors import UnknownImageSizeError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.distortion import LensDistortion
from semcityloc.geometry.intrinsics_files import check_fits_photo, read_lens
from semcityloc.io.images import check_aspect, image_size


def read_lens_for_photo(
    intrinsics: str, width: int | None, height: int | None, image: str | None
) -> tuple[Camera, LensDistortion]:
    """``read_lens`` of ``--intrinsics`` (at ``--width`` x ``--height`` when given; a LoD-Loc K states no
    size, and one whose principal point is not at the centre of a whole-pixel image gives none: then at
    ``--image``'s size, without one the message names ``--width`` / ``--height``); with ``--image`` the
    intrinsics must describe that photo (``geometry.io.check_fits_photo``: its size or resized, a principal
    point near the centre) and, resampled, keep its aspect; without ``--width`` / ``--height`` the camera is
    then at the photo's own size (a photo resized from the size the intrinsics state: the K rescaled,
    ``Camera.scaled``), so that whatever is drawn or found with it is on the photo's pixels (``render``'s
    outputs, ``localize``'s overlay and pose file); without one, their principal point must lie near the
    centre of the size they state (a K of another image size, given at a ``--width`` it never had, was
    taken as it is)."""
    photo = (Path(image).name, *image_size(image, "photo")) if image else None
    try:
        camera, distortion = read_lens(intrinsics, width=width, height=height, photo=photo)
    except UnknownImageSizeError as exc:  # a K off the centre of any whole-pixel image: it is the photo's
        if photo is None or width is not None or height is not None:
            raise UnknownImageSizeError(f"{exc}: --width W --height H, or --image PHOTO (its size)") from None
        camera, distortion = read_lens(intrinsics, width=photo[1], height=photo[2], photo=photo)
    if photo is not None:  # resampled to a --width x --height of another aspect than the photo
        check_aspect((photo[2], photo[1]), camera.width, camera.height, "photo", image)
        if width is None and height is None and camera.size != photo[1:]:  # the photo's own size wins
            camera = camera.scaled(*photo[1:])
    else:  # no photo to hold it against: its principal point must still be near its own image's centre
        check_fits_photo(camera, str(intrinsics), ("(no --image: the size they are used at)", *camera.size))
    return camera, distortion


def add_pose_name_argument(p: argparse.ArgumentParser, pose_option: str) -> None:
    """``--pose-name NAME``: which pose of a multi-image ``pose_option`` file (a COLMAP ``images.txt``) to
    take; without it, ``--image``'s file name chooses (``photo_name``)."""
    p.add_argument(
        "--pose-name",
        default=None,
        metavar="NAME",
        help=f"the image name of the pose to take from a {pose_option} file of several (a COLMAP images.txt; "
        "default: --image's file name)",
    )


def photo_name(image: str | None) -> str | None:
    """The file name of ``--image``, which chooses a pose among several when no ``--pose-name`` is given."""
    return Path(image).name if image else None

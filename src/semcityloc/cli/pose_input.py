"""A pose or a camera given on the command line, checked against what it is used with.

Why: ``read_pose`` reads a pose's numbers; a JSON pose (``pose_to_dict``'s layout, what ``localize`` and
``run`` write) also says which CRS they are in. A pose of another CRS used as one in the model's is a
camera hundreds of kilometres (or a hemisphere) away, or worse, near enough to look plausible: refused
here, naming both CRSs, before anything is searched. Likewise intrinsics given with ``--image``
(``read_lens_for_photo``): another camera's would draw or localize on that photo's pixels wrongly, silently.
"""

from __future__ import annotations

import os
from pathlib import Path

from semcityloc.citymodel.crs import parse_crs_name, same_horizontal_crs
from semcityloc.citymodel.model import CityModel, crs_label
from semcityloc.errors import CRSError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.distortion import LensDistortion
from semcityloc.geometry.io import declared_pose_frame, read_lens, read_pose
from semcityloc.geometry.pose import Pose
from semcityloc.io.images import check_aspect, image_size


def read_pose_in_model_crs(spec: str | os.PathLike, model: CityModel, what: str = "pose") -> Pose:
    """The pose of ``spec`` (``read_pose``'s forms), in ``model``'s CRS: refused (``CRSError``) when it
    declares another CRS than the model's."""
    pose = read_pose(spec)
    _, declared = declared_pose_frame(spec)
    if declared is not None and model.crs is not None:
        declared_crs = parse_crs_name(declared)
        if not same_horizontal_crs(declared_crs, model.crs):
            raise CRSError(
                f"the {what} is in {declared} but the model in {crs_label(model.crs)}: convert the {what} "
                "to the model's CRS (pyproj), or give the model the CRS its coordinates are in (--crs)"
            )
    return pose


def read_lens_for_photo(
    intrinsics: str, width: int | None, height: int | None, image: str | None
) -> tuple[Camera, LensDistortion]:
    """``read_lens`` of ``--intrinsics`` (at ``--width`` x ``--height`` when given); with ``--image`` the
    intrinsics must describe that photo (``geometry.io.check_fits_photo``: its size or resized, a principal
    point near the centre) and, resampled, keep its aspect."""
    photo = (Path(image).name, *image_size(image, "photo")) if image else None
    camera, distortion = read_lens(intrinsics, width=width, height=height, photo=photo)
    if photo is not None:  # resampled to a --width x --height of another aspect than the photo
        check_aspect((photo[2], photo[1]), camera.width, camera.height, "photo", image)
    return camera, distortion

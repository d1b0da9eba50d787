"""Read poses and intrinsics from the small text formats users pass on the CLI; write a pose as JSON: the
public names, in one place to import them from (``from semcityloc.geometry.io import read_pose``).

Every reader takes a ``spec``: a path to a file, or the text itself (inline JSON, a COLMAP line, comma
separated numbers). The accepted forms are listed in ``read_pose`` and ``read_intrinsics``. Whatever is
wrong with an input, the error is one of ``PoseError`` / ``CameraError`` / ``ShapeError`` /
``InputFileError`` with a one-line message that starts with the file name or the inline text.

Frames: a pose is read exactly as written (in whatever world frame the file uses, usually the model's
CRS); bring it to a model's local frame with ``model.pose_to_local(pose)``. A JSON pose also declares its
world frame (``frame``: ``POSE_FRAMES``), which ``declared_pose_frame`` reads for the caller to check
(``citymodel.pose_crs.read_pose_world``). ``write_pose_json(path, pose_local=..., origin_world=...)``
writes a local pose in the world frame again (local + origin, float64), so its output reads back.

Where each job is done:

- ``geometry.spec_text``: a spec's text (file or inline), its lines, the entry for an image name;
- ``geometry.pose_files``: ``read_pose``, ``read_poses``, ``read_colmap_camera_ids`` (every pose form);
- ``geometry.pose_json``: the JSON pose, read (``pose_from_json``) and written (``pose_to_dict``,
  ``write_pose_json``);
- ``geometry.pose_frame``: the world frame a JSON pose declares (``POSE_FRAMES``, ``PoseFrame``,
  ``declared_pose_frame``);
- ``geometry.intrinsics_files``: ``read_intrinsics``, ``read_lens``, ``check_fits_photo``.
"""

from __future__ import annotations

from semcityloc.geometry.intrinsics_files import (
    COLMAP_MODELS,
    INTRINSICS_FORMS,
    check_fits_photo,
    read_intrinsics,
    read_lens,
)
from semcityloc.geometry.pose_files import POSE_FORMS, read_colmap_camera_ids, read_pose, read_poses
from semcityloc.geometry.pose_frame import (
    POSE_FRAME_CRS,
    POSE_FRAME_CRS_OFFSET,
    POSE_FRAME_MODEL,
    POSE_FRAMES,
    PoseFrame,
    declared_pose_frame,
    format_offset,
)
from semcityloc.geometry.pose_json import pose_to_dict, write_pose_json
from semcityloc.geometry.spec_text import MAX_SPEC_FILE_BYTES

__all__ = [
    "COLMAP_MODELS",
    "INTRINSICS_FORMS",
    "MAX_SPEC_FILE_BYTES",
    "POSE_FORMS",
    "POSE_FRAMES",
    "POSE_FRAME_CRS",
    "POSE_FRAME_CRS_OFFSET",
    "POSE_FRAME_MODEL",
    "PoseFrame",
    "check_fits_photo",
    "declared_pose_frame",
    "format_offset",
    "pose_to_dict",
    "read_colmap_camera_ids",
    "read_intrinsics",
    "read_lens",
    "read_pose",
    "read_poses",
    "write_pose_json",
]

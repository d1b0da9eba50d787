"""A pose read from a file or inline text in any of the forms the CLI accepts (``read_pose``: LoD-Loc
matrices, COLMAP lines and ``images.txt``, JSON through ``geometry.pose_json``, ``x,y,z,roll,pitch,yaw``).

Frames: a pose is read exactly as written (in whatever world frame the file uses, usually the model's
CRS); bring it to a model's local frame with ``model.pose_to_local(pose)``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from semcityloc.errors import PoseError, parameter
from semcityloc.geometry.colmap_text import (
    IMAGE_CAMERA_ID,
    IMAGE_NAME,
    IMAGE_POSE,
    is_image_line,
    is_number,
    numbers,
)
from semcityloc.geometry.conventions import pose_from_colmap, pose_from_lodloc_c2w
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.pose_frame import PoseFrame, frame_of_pose_json
from semcityloc.geometry.pose_json import pose_from_json
from semcityloc.geometry.spec_text import labelled, load_spec, parse_json, pick_entry, spec_lines

POSE_FORMS = (
    "a 4x4 (or 3x4) camera-to-world matrix (LoD-Loc *_pose.txt), 'name qw qx qy qz tx ty tz' (COLMAP), "
    "COLMAP images.txt, JSON, or 'x,y,z,roll,pitch,yaw'"
)


def _colmap_images(rows: list[list[str]]) -> dict[str, Pose]:
    """COLMAP images.txt: 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME' lines (2D-point lines ignored)."""
    return {r[IMAGE_NAME]: pose_from_colmap(*map(float, r[IMAGE_POSE])) for r in rows if is_image_line(r)}


def _pose_entries(text: str) -> dict[str, Pose]:
    """All poses in a text (not JSON); unnamed single poses are keyed ''."""
    rows = spec_lines(text)
    if not rows:
        raise PoseError(f"no pose values; expected {POSE_FORMS}")
    images = _colmap_images(rows)
    if images:
        return images
    named = [r for r in rows if not is_number(r[0])]
    if named:
        if len(named) != len(rows):
            raise PoseError(
                "mixes named and unnamed lines; expected one 'name qw qx qy qz tx ty tz' per line"
            )
        out = {}
        for r in rows:
            v = numbers(r[1:], PoseError)
            if len(v) != 7:
                raise PoseError(
                    f"line for {r[0]!r} has {len(v)} numbers; expected 'name qw qx qy qz tx ty tz'"
                )
            out[r[0]] = pose_from_colmap(*v)
        return out
    values = [numbers(r, PoseError) for r in rows]
    counts = [len(v) for v in values]
    if len(rows) in (3, 4) and all(c == 4 for c in counts):
        return {"": pose_from_lodloc_c2w(np.array(values))}
    if len(rows) == 1 and counts[0] in (12, 16):
        return {"": pose_from_lodloc_c2w(np.array(values[0]).reshape(-1, 4))}
    if len(rows) == 1 and counts[0] == 7:
        return {"": pose_from_colmap(*values[0])}
    if len(rows) == 1 and counts[0] == 6:
        x, y, z, roll, pitch, yaw = values[0]
        return {"": Pose.from_xyz_rpy([x, y, z], roll, pitch, yaw)}
    shape = " / ".join(str(c) for c in counts[:5]) + (" / ..." if len(counts) > 5 else "")
    raise PoseError(f"{len(rows)} line(s) with {shape} numbers is not a pose; expected {POSE_FORMS}")


def _is_json(text: str) -> bool:
    return text.lstrip().startswith(("{", "["))


def read_pose_entries(spec: str | os.PathLike) -> tuple[dict[str, Pose], str]:
    text, label = load_spec(spec, PoseError, "pose")

    def parse() -> dict[str, Pose]:
        if _is_json(text):
            return {"": pose_from_json(parse_json(text))}
        return _pose_entries(text)

    return labelled(label, parse), label


def _named(entries: dict[str, Pose], label: str, name: str | None, photo: str | None = None) -> Pose:
    """The pose of ``entries`` for image ``name`` (``read_pose``'s rule: an unnamed single pose is it);
    without a ``name``, one of several is the pose of ``photo`` (the file name of the image it is used
    with: ``render --image``, ``localize --image``) when given."""
    if list(entries) == [""]:
        return entries[""]
    if name is None and photo is not None and len(entries) > 1:
        name = photo
    choose = f"choose one by its image name ({parameter('pose_name', 'NAME')})"
    return labelled(label, pick_entry, entries, name, PoseError, "pose", choose)


@dataclass(frozen=True)
class PoseText:
    """A pose spec read once (``read_pose_text``): the file's label, the frame it declares
    (``declared_pose_frame``'s) and, parsed when asked, its poses (``read_poses``'s) and COLMAP camera ids
    (``read_colmap_camera_ids``'s). For a caller that checks the frame before it takes the poses
    (``citymodel.pose_crs.read_pose_world``, ``datasets.photos.PoseFiles``): one read of the file."""

    label: str
    frame: PoseFrame
    text: str
    json_value: Any  # the text parsed as JSON when it is JSON, else None

    def poses(self) -> dict[str, Pose]:
        """Every pose by image name, as ``read_poses``."""
        if self.json_value is not None:
            return {"": labelled(self.label, pose_from_json, self.json_value)}
        return labelled(self.label, _pose_entries, self.text)

    def pose(self, name: str | None = None, photo: str | None = None) -> Pose:
        """The pose for image ``name`` (else, of several, ``photo``'s: ``_named``), as ``read_pose``."""
        return _named(self.poses(), self.label, name, photo)

    def camera_ids(self) -> dict[str, str]:
        """Image name -> ``CAMERA_ID``, as ``read_colmap_camera_ids``."""
        return {r[IMAGE_NAME]: r[IMAGE_CAMERA_ID] for r in spec_lines(self.text) if is_image_line(r)}


def read_pose_text(spec: str | os.PathLike) -> PoseText:
    """A pose spec read once, its declared frame read (errors: ``declared_pose_frame``'s) and its poses
    left to ``PoseText.poses`` / ``pose``."""
    text, label = load_spec(spec, PoseError, "pose")
    value = labelled(label, parse_json, text) if _is_json(text) else None
    frame = labelled(label, frame_of_pose_json, value) if isinstance(value, dict) else PoseFrame(None)
    return PoseText(label, frame, text, value)


def read_poses(spec: str | os.PathLike) -> dict[str, Pose]:
    """Every pose in a spec, by image name (``''`` for an unnamed single pose). Forms: ``read_pose``."""
    return read_pose_entries(spec)[0]


def read_colmap_camera_ids(spec: str | os.PathLike) -> dict[str, str]:
    """Image name -> ``CAMERA_ID`` (as written) of every COLMAP ``images.txt`` image line in a spec, the
    lines ``read_poses`` takes poses from; ``{}`` for the other pose forms."""
    text, _ = load_spec(spec, PoseError, "pose")
    return {r[IMAGE_NAME]: r[IMAGE_CAMERA_ID] for r in spec_lines(text) if is_image_line(r)}


def read_pose(spec: str | os.PathLike, name: str | None = None) -> Pose:
    """One camera pose from a file or inline text. Accepted forms:

    - LoD-Loc ``*_pose.txt``: a 4x4 (or 3x4) camera-to-world matrix, OpenCV camera axes, rows on lines
      (whitespace or commas), or its 16 (12) numbers row-major on one line;
    - a COLMAP pose line ``name qw qx qy qz tx ty tz`` or ``qw qx qy qz tx ty tz`` (world-to-camera,
      Hamilton quaternion scalar first); a file of such lines (LoD-Loc ``GT_pose.txt``) or a COLMAP
      ``images.txt`` needs ``name`` (matched exactly, then by file name, then by stem) unless it has one;
    - JSON (file or inline): ``{"world_from_cam": 4x4}``, ``{"cam_from_world": 4x4}``,
      ``{"qvec": [qw, qx, qy, qz], "tvec": [...]}`` or ``{"xyz": [...], "roll": .., "pitch": .., "yaw": ..}``
      (also what ``write_pose_json`` writes);
    - inline ``x,y,z,roll,pitch,yaw`` (our Euler convention, degrees; see ``geometry/pose.py``).
    """
    entries, label = read_pose_entries(spec)
    return _named(entries, label, name)

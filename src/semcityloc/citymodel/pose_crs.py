"""A pose file read as a pose in a city model's CRS, the CRS it declares checked against the model's.

Why: ``geometry.io.read_pose`` reads a pose's numbers; a JSON pose (``pose_to_dict``'s layout, what
``localize`` and ``run`` write) also says which CRS they are in. A pose of another CRS used as one in the
model's is a camera hundreds of kilometres (or a hemisphere) away, or worse, near enough to look plausible:
``read_pose_world`` refuses it, naming both CRSs, before anything is rendered or searched. The CLI and the
photo folders (``datasets.photos.PoseFiles``) read poses through it; so should a library user.
"""

from __future__ import annotations

import os

import pyproj

from semcityloc.citymodel.crs import parse_crs_name, same_horizontal_crs
from semcityloc.citymodel.model import crs_label
from semcityloc.errors import CRSError, parameter
from semcityloc.geometry.io import declared_pose_frame, read_pose
from semcityloc.geometry.pose import Pose


def check_pose_crs(spec: str | os.PathLike, model_crs: pyproj.CRS | None, what: str = "pose") -> None:
    """``CRSError`` when the JSON pose of ``spec`` declares a CRS whose horizontal part is not
    ``model_crs``'s (``what`` names the pose in the message: "pose", "prior", ...). Poses that declare
    none (every non-JSON form), and models without a CRS, pass."""
    _, declared = declared_pose_frame(spec)
    if declared is None or model_crs is None:
        return
    try:
        declared_crs = parse_crs_name(declared)
    except CRSError as exc:
        raise CRSError(
            f"{spec}: the {what}'s crs: {exc}; write the CRS its numbers are in, or leave it out"
        ) from None
    if not same_horizontal_crs(declared_crs, model_crs):
        raise CRSError(
            f"the {what} is in {declared} but the model in {crs_label(model_crs)}: convert the {what} "
            f"to the model's CRS (pyproj), or give the model the CRS its coordinates are in "
            f"({parameter('crs')})"
        )


def read_pose_world(
    spec: str | os.PathLike, model_crs: pyproj.CRS | None, what: str = "pose", name: str | None = None
) -> Pose:
    """``read_pose(spec, name)``, a pose in the model's CRS (``model.pose_to_local`` takes it into the
    model's local frame), after ``check_pose_crs``."""
    check_pose_crs(spec, model_crs, what)
    return read_pose(spec, name)

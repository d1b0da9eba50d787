"""A pose given on the command line, checked against the model it is used with.

Why: ``read_pose`` reads a pose's numbers; a JSON pose (``pose_to_dict``'s layout, what ``localize`` and
``run`` write) also says which CRS they are in. A pose of another CRS used as one in the model's is a
camera hundreds of kilometres (or a hemisphere) away, or worse, near enough to look plausible: refused
here, naming both CRSs, before anything is searched.
"""

from __future__ import annotations

import os

from semcityloc.citymodel.crs import parse_crs_name, same_horizontal_crs
from semcityloc.citymodel.model import CityModel, crs_label
from semcityloc.errors import CRSError
from semcityloc.geometry.io import declared_pose_frame, read_pose
from semcityloc.geometry.pose import Pose


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

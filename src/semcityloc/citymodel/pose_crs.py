"""A pose file read as a pose in a city model's world frame, the frame it declares checked against it.

Why: ``geometry.io.read_pose`` reads a pose's numbers; a JSON pose (``pose_to_dict``'s layout, what
``localize`` and ``run`` write) also says which frame they are in (``geometry.io.declared_pose_frame``): a
CRS, or a CRS minus an offset (``run --offset``). A pose of another CRS used as one in the model's is a
camera hundreds of kilometres (or a hemisphere) away, or worse, near enough to look plausible; one of the
CRS minus an offset used as CRS coordinates (or the other way round) is the offset away, thousands of
kilometres. ``read_pose_world`` refuses both, naming the two frames, before anything is rendered or
searched. The CLI and the photo folders (``datasets.photos.PoseFiles``) read poses through it; so should a
library user.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pyproj

from semcityloc.citymodel.crs import parse_crs_name, same_horizontal_crs
from semcityloc.citymodel.model import CityModel, crs_label
from semcityloc.errors import CRSError, PoseError, parameter
from semcityloc.geometry.pose import LOCAL_FRAME_REACH_M, Pose
from semcityloc.geometry.pose_files import read_pose_text
from semcityloc.geometry.pose_frame import (
    POSE_FRAME_CRS,
    POSE_FRAME_CRS_OFFSET,
    PoseFrame,
    declared_pose_frame,
)

# Two offsets are one when they differ by less than this (m): both are written and read as float64.
SAME_OFFSET_M = 1e-6


def _model_offset(crs_offset) -> np.ndarray:
    return np.zeros(3) if crs_offset is None else np.asarray(crs_offset, dtype=np.float64).reshape(3)


def check_pose_crs(
    spec: str | os.PathLike, model_crs: pyproj.CRS | None, what: str = "pose", crs_offset=None
) -> None:
    """``CRSError`` when the JSON pose of ``spec`` declares a frame that is not the model's world frame:
    a CRS whose horizontal part is not ``model_crs``'s, or its numbers the CRS minus an offset other than
    ``crs_offset`` (the model's frame is ``model_crs`` minus this, ``run --offset``; None: the CRS itself).
    ``what`` names the pose in the message: "pose", "prior", ... Poses that declare no CRS (every non-JSON
    form, a ``model`` frame), and models without a CRS, pass: there is nothing to check them by."""
    check_declared_frame(declared_pose_frame(spec), spec, model_crs, what, crs_offset)


def check_declared_frame(
    declared: PoseFrame, spec: str | os.PathLike, model_crs: pyproj.CRS | None, what: str, crs_offset
) -> None:
    """``check_pose_crs`` of the frame ``declared`` that the pose of ``spec`` declares (read already)."""
    if declared.crs is None or model_crs is None:
        return
    try:
        declared_crs = parse_crs_name(declared.crs)
    except CRSError as exc:
        raise CRSError(
            f"{spec}: the {what}'s crs: {exc}; write the CRS its numbers are in, or leave it out"
        ) from None
    if not same_horizontal_crs(declared_crs, model_crs):
        raise CRSError(
            f"the {what} is in {declared.describe()} but the model in {crs_label(model_crs)}: convert the "
            f"{what} to the model's CRS (pyproj), or give the model the CRS its coordinates are in "
            f"({parameter('crs')})"
        )
    model_offset = _model_offset(crs_offset)
    pose_offset = np.zeros(3) if declared.crs_offset is None else np.array(declared.crs_offset)
    if np.abs(pose_offset - model_offset).max() < SAME_OFFSET_M:
        return
    label = crs_label(model_crs)
    model_frame = (
        PoseFrame(POSE_FRAME_CRS_OFFSET, label, tuple(model_offset.tolist()))
        if model_offset.any()
        else PoseFrame(POSE_FRAME_CRS, label)
    )
    if not pose_offset.any():
        remedy = (
            f"subtract the model's offset from its numbers, or leave out the model's offset "
            f"({parameter('offset')})"
        )
    else:
        given = ",".join(np.format_float_positional(float(v), trim="-") for v in pose_offset)
        remedy = f"give the model the offset its numbers are by ({parameter('offset', given)})"
        if not model_offset.any():
            remedy += f", or add its crs_offset to them (a pose in {declared.crs})"
    raise CRSError(
        f"the {what} is in {declared.describe()} but the model's frame is {model_frame.describe()}: taken as "
        f"the model's, its numbers would be {_distance(pose_offset - model_offset)} off; {remedy}"
    )


def _distance(shift: np.ndarray) -> str:
    metres = float(np.linalg.norm(shift))
    return f"{metres / 1000:,.0f} km" if metres >= 10_000 else f"{metres:,.1f} m"


def read_pose_world(
    spec: str | os.PathLike,
    model_crs: pyproj.CRS | None,
    what: str = "pose",
    name: str | None = None,
    crs_offset=None,
    photo: str | None = None,
) -> Pose:
    """``read_pose(spec, name)``, a pose in the model's world frame (``model.pose_to_local`` takes it into
    the model's local frame), after ``check_pose_crs`` (``crs_offset``: the model's frame is ``model_crs``
    minus this). ``photo``: the file name of the image the pose is for, which chooses among several when
    ``name`` is None. The file is read once (``geometry.pose_files.read_pose_text``)."""
    text = read_pose_text(spec)
    check_declared_frame(text.frame, spec, model_crs, what, crs_offset)
    return text.pose(name, photo)


def camera_far_from_model(pose_local: Pose, model: CityModel) -> str | None:
    """Why the camera of ``pose_local`` (in ``model``'s local frame) cannot be a view of the model, or None:
    it lies farther from the model than a local frame reaches (``LOCAL_FRAME_REACH_M``), a pose in another
    CRS, another unit or with a garbage coordinate (1e300). Said in the words of the pose file's frame: the
    one check ``render``, ``label`` and the data-set commands make of each pose before it is rendered."""
    distance = float(np.abs(pose_local.center).max())
    if math.isfinite(distance) and distance <= LOCAL_FRAME_REACH_M:
        return None
    if not math.isfinite(distance):
        far = "infinitely far"
    else:
        far = f"{distance / 1000:,.0f} km" if distance < 1e9 else f"{distance / 1000:.3g} km"
    return (
        f"the camera lies {far} from the model (more than {LOCAL_FRAME_REACH_M / 1000:g} km from its "
        f"origin, {model.origin[0]:.1f} {model.origin[1]:.1f} {model.origin[2]:.1f}): is the pose in the "
        f"model's CRS ({crs_label(model.crs) or 'none declared'}) and in metres?"
    )


def check_camera_near_model(pose_local: Pose, model: CityModel, source: object) -> None:
    """``PoseError`` led by ``source`` (the pose file) when ``camera_far_from_model`` says why the camera
    cannot be a view of ``model``: before the renderer refuses it in a library's words (a pose in world
    coordinates given as local)."""
    problem = camera_far_from_model(pose_local, model)
    if problem is not None:
        raise PoseError(f"{source}: {problem}")

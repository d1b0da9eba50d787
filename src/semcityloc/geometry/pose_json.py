"""The JSON pose: read in any of its forms (``pose_from_json``: ``world_from_cam``, ``cam_from_world``,
``qvec`` + ``tvec``, ``xyz`` + roll / pitch / yaw) and written in one layout (``pose_to_dict``,
``write_pose_json``: a local pose in the world frame again, local + origin in float64, so that it reads
back; its ``frame`` from ``geometry.pose_frame``).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from semcityloc.errors import ArgumentTypeError, InputFileError, PoseError, ShapeError
from semcityloc.geometry.conventions import colmap_qvec_tvec, pose_from_colmap
from semcityloc.geometry.pose import Pose, local_frame_problem
from semcityloc.geometry.pose_frame import POSE_FRAME_CRS, POSE_FRAME_CRS_OFFSET, POSE_FRAME_MODEL
from semcityloc.geometry.spec_text import RIGID, json_matrix, json_number, json_vector
from semcityloc.io.files import json_default, write_json_atomic

# A pose JSON holding both matrices must agree to this (metres / rotation-matrix entries).
CONSISTENCY_TOL_M = 1e-4
CONSISTENCY_TOL_R = 1e-6


def focal_scale_of(obj: Any) -> float:
    """A pose file's ``focal_scale`` (``write_pose_json``: its pose holds with the camera's stated focal
    lengths times it), 1 where it has none."""
    scale = obj.get("focal_scale") if isinstance(obj, dict) else None
    return float(scale) if isinstance(scale, (int, float)) and not isinstance(scale, bool) else 1.0


def pose_from_json(obj: Any) -> Pose:
    if not isinstance(obj, dict):
        raise PoseError(f"pose JSON must be an object, got {type(obj).__name__}")
    if "world_from_cam" in obj:
        pose = Pose.from_world_from_cam(json_matrix(obj["world_from_cam"], RIGID, "world_from_cam"))
        if "cam_from_world" in obj:
            other = Pose.from_cam_from_world(json_matrix(obj["cam_from_world"], RIGID, "cam_from_world"))
            if (
                np.abs(other.center - pose.center).max() > CONSISTENCY_TOL_M
                or np.abs(other.R - pose.R).max() > CONSISTENCY_TOL_R
            ):
                raise PoseError("'world_from_cam' and 'cam_from_world' are not inverses of each other")
        return pose
    if "cam_from_world" in obj:
        return Pose.from_cam_from_world(json_matrix(obj["cam_from_world"], RIGID, "cam_from_world"))
    qkey = "qvec" if "qvec" in obj else "qvec_wxyz" if "qvec_wxyz" in obj else None
    if qkey is not None:
        if "tvec" not in obj:
            raise PoseError(f"{qkey!r} needs 'tvec' (COLMAP world-to-camera translation)")
        return pose_from_colmap(
            *json_vector(obj, qkey, 4, PoseError), *json_vector(obj, "tvec", 3, PoseError)
        )
    xyz_key = "xyz" if "xyz" in obj else "position" if "position" in obj else None
    if xyz_key is not None:
        missing = [k for k in ("roll", "pitch", "yaw") if k not in obj]
        if missing:
            raise PoseError(f"{xyz_key!r} needs 'roll', 'pitch' and 'yaw' (missing {', '.join(missing)})")
        angles = [json_number(obj, k, PoseError) for k in ("roll", "pitch", "yaw")]
        return Pose.from_xyz_rpy(json_vector(obj, xyz_key, 3, PoseError), *angles)
    raise PoseError(
        "pose JSON needs 'world_from_cam', 'cam_from_world', 'qvec'+'tvec' or 'xyz'+'roll'/'pitch'/'yaw'; "
        f"got keys {sorted(obj)}"
    )


def _crs_name(crs: Any) -> str | None:
    if crs is None:
        return None
    if isinstance(crs, str):
        return crs
    to_string = getattr(crs, "to_string", None)
    return to_string() if callable(to_string) else str(crs)


def _finite_xyz(value: Any, name: str) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,):
        raise ShapeError(f"{name} must have shape (3,), got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise PoseError(f"{name} has non-finite entries")
    return v


def pose_to_dict(
    *,
    pose_local: Pose | None = None,
    origin_world: np.ndarray | None = None,
    pose_world: Pose | None = None,
    crs: Any = None,
    crs_offset: np.ndarray | None = None,
    extra: dict | None = None,
    focal_scale: float | None = None,
) -> dict[str, Any]:
    """The JSON-ready description of one pose written by ``write_pose_json`` (see there)."""
    if (pose_local is None) == (pose_world is None):
        raise ArgumentTypeError(
            "give one pose: pose_local (a model's local frame, with origin_world: model.origin) or "
            "pose_world (the world frame it is written in)"
        )
    if pose_local is not None and origin_world is None:
        raise ArgumentTypeError(
            "a pose_local needs origin_world (model.origin) to be written in the world frame"
        )
    if pose_world is not None and origin_world is not None:
        raise ArgumentTypeError("origin_world goes with pose_local; a pose_world is written as it is")
    pose = pose_local if pose_local is not None else pose_world
    if not isinstance(pose, Pose):
        raise PoseError(f"expected a Pose, got {type(pose).__name__}")
    if pose.batch_shape:
        raise ShapeError(f"write one pose at a time, got a batch of shape {pose.batch_shape}")
    out: dict[str, Any] = {}
    offset = None if crs_offset is None else _finite_xyz(crs_offset, "crs_offset")
    if offset is not None and crs is None:
        raise PoseError("crs_offset needs crs: the CRS the world frame is that CRS minus the offset of")
    if offset is not None and any(offset):
        out.update(frame=POSE_FRAME_CRS_OFFSET, offset_crs=_crs_name(crs), crs_offset=offset.tolist())
    elif crs is not None:
        out.update(frame=POSE_FRAME_CRS, crs=_crs_name(crs))
    else:
        out["frame"] = POSE_FRAME_MODEL
    if pose_local is not None:
        local_center = pose_local.center
        if (problem := local_frame_problem(local_center)) is not None:
            raise PoseError(
                f"with an origin the pose must be in the local frame (pose_local; world = local + "
                f"origin_world): {problem}"
            )
        o = _finite_xyz(origin_world, "origin_world")
        pose = pose_local.shift_world(-o)  # local -> world: world = local + origin, in float64
        out["origin"] = o.tolist()
        out["position_local"] = local_center.tolist()
    x, y, z, roll, pitch, yaw = pose.to_xyz_rpy().tolist()
    qvec, tvec = colmap_qvec_tvec(pose)
    out.update(
        {
            "position": [x, y, z],
            "roll": roll,
            "pitch": pitch,
            "yaw": yaw,
            "world_from_cam": pose.world_from_cam.tolist(),
            "cam_from_world": pose.cam_from_world.tolist(),
            "qvec_wxyz": qvec.tolist(),
            "tvec": tvec.tolist(),
            "convention": (
                "OpenCV camera axes (x right, y down, z forward); world x east, y north, z up; "
                "R_world_from_cam = Rz(yaw) Ry(roll) Rx(pitch) diag(1,-1,-1), degrees; "
                "qvec_wxyz/tvec = COLMAP cam_from_world"
            ),
        }
    )
    if focal_scale is not None:  # the pose holds with the stated focal lengths times this
        out["focal_scale"] = float(focal_scale)
    if extra is not None:
        if not isinstance(extra, dict):
            raise ShapeError(f"extra must be a dict, got {type(extra).__name__}")
        try:
            out["extra"] = json.loads(json.dumps(extra, default=json_default))
        except (TypeError, ValueError) as exc:
            raise ShapeError(f"extra is not JSON-serialisable: {exc}") from exc
    return out


def write_pose_json(path: str | os.PathLike, **pose_keywords: Any) -> dict[str, Any]:
    """Write one pose as JSON and return what was written.

    ``pose_keywords``: those of ``pose_to_dict``. The pose: ``pose_local`` (a model's local frame) with
    ``origin_world`` (the model's float64 origin), written in the world frame, ``position = local centre +
    origin`` in float64, with ``origin`` and ``position_local``; or ``pose_world``, written as it is.
    ``crs``: the CRS the world frame is in (a name or a ``pyproj.CRS``); ``crs_offset``: with ``crs``, the
    world frame is that CRS minus this (``run --offset``); ``extra``: any JSON-serialisable dict.

    Keys: ``frame`` (``POSE_FRAMES``: "crs", the numbers are coordinates of ``crs``; "crs_offset", of
    ``offset_crs`` minus ``crs_offset``, and no ``crs`` key, so that no reader takes them for CRS
    coordinates; "model", a model's own coordinates without a CRS), ``position`` (camera centre),
    ``roll`` / ``pitch`` / ``yaw`` (degrees, our convention), ``world_from_cam`` and ``cam_from_world``
    (4x4), ``qvec_wxyz`` / ``tvec`` (COLMAP), ``convention`` (a reminder string), ``focal_scale`` when
    given (the pose holds with the camera's stated focal lengths times it: a pose the focal check's
    correction re-found, ``localization.focal_check.found_camera``), and ``extra`` (any JSON-serialisable
    dict) when given. ``read_pose`` reads the file back (in the frame it was written in;
    ``citymodel.read_pose_world`` checks that frame against a model's). The file is strict JSON (a NaN or
    infinity in ``extra``, e.g. the depth cost of a run without depth, is written ``null``; the returned
    dict keeps it) and written whole or not at all (``io.files.write_json_atomic``).
    """
    data = pose_to_dict(**pose_keywords)
    target = Path(path)
    try:
        write_json_atomic(target, data)
    except OSError as exc:
        raise InputFileError(f"{target}: cannot write pose JSON: {exc.strerror or exc}") from exc
    return data

"""The world frame a JSON pose declares its numbers in (``frame``: ``POSE_FRAMES``; ``PoseFrame``), as
``pose_json.pose_to_dict`` writes it and ``declared_pose_frame`` reads it, files written before stop 52
too; ``citymodel.pose_crs`` checks it against a model's.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from semcityloc.errors import PoseError
from semcityloc.geometry.spec_text import json_vector, labelled, load_spec, parse_json

# The ``frame`` a pose JSON declares its numbers in (``pose_to_dict`` writes it, ``declared_pose_frame``
# reads it). Never "local": a pose file is never in a model's local frame (its ``position_local`` is).
POSE_FRAME_CRS = "crs"  # coordinates of the CRS named by ``crs``
POSE_FRAME_CRS_OFFSET = "crs_offset"  # coordinates of the CRS named by ``offset_crs`` minus ``crs_offset``
POSE_FRAME_MODEL = "model"  # a city model's own coordinates, which name no CRS: nothing to check them by
POSE_FRAMES = (POSE_FRAME_CRS, POSE_FRAME_CRS_OFFSET, POSE_FRAME_MODEL)
# Written before stop 52: "world" (no origin given) and "crs" without a ``crs`` (offset or unnamed frame).
LEGACY_POSE_FRAME_WORLD = "world"
# Where such a file kept its offset: frame -> (offset key, CRS key) of its ``extra``.
_LEGACY_OFFSET_KEYS = {
    POSE_FRAME_CRS: ("crs_offset", "offset_crs"),
    LEGACY_POSE_FRAME_WORLD: ("offset", "crs"),
}


@dataclass(frozen=True)
class PoseFrame:
    """The world frame a JSON pose declares its numbers in (``declared_pose_frame``)."""

    frame: str | None  # one of ``POSE_FRAMES``; None: the pose declares none (every non-JSON form)
    crs: str | None = None  # the CRS named: the numbers' (crs), the one they are offset in (crs_offset)
    crs_offset: tuple[float, float, float] | None = None  # crs_offset: CRS coordinates = numbers + this

    def describe(self) -> str:
        """The frame in words: "EPSG:32649", "EPSG:32649 minus (695672, 3131199, 0)", "no CRS"."""
        if self.crs is None:
            return "no CRS"
        return self.crs if self.crs_offset is None else f"{self.crs} minus {format_offset(self.crs_offset)}"


def format_offset(offset) -> str:
    """``(695672, 3131199, 0.5)``: an offset as its numbers read back (no rounding, no trailing zeros)."""
    return "(" + ", ".join(np.format_float_positional(float(v), trim="-") for v in offset) + ")"


def _crs_string(obj: dict, key: str) -> str | None:
    value = obj.get(key)
    if value is not None and not isinstance(value, str):  # {"epsg": 4326}, 4326: a CRS, just not a name
        raise PoseError(f'its {key} {value!r} is no CRS name; write it as a string, e.g. "EPSG:25832"')
    return value


def _offset_frame(obj: dict, offset_key: str, crs_key: str) -> PoseFrame:
    """A crs_offset frame from ``obj[offset_key]`` (3 numbers) and ``obj[crs_key]`` (the CRS's name)."""
    if offset_key not in obj:
        raise PoseError(
            f"its frame is crs_offset but it has no {offset_key!r}: the offset its numbers are by"
        )
    offset = json_vector(obj, offset_key, 3, PoseError)
    crs = _crs_string(obj, crs_key)
    if crs is None:
        raise PoseError(f"{offset_key!r} needs {crs_key!r}: the CRS the numbers plus the offset are in")
    return PoseFrame(POSE_FRAME_CRS_OFFSET, crs, (offset[0], offset[1], offset[2]))


def _legacy_offset_frame(obj: dict, frame: str | None) -> PoseFrame | None:
    """The crs_offset frame of a file written before stop 52, or None: ``run --offset`` wrote "frame":
    "crs", no ``crs``, and ``extra.crs_offset`` + ``extra.offset_crs`` (None without a CRS: frame model);
    ``dataset dji-prior --offset`` wrote "frame": "world", no ``crs``, and ``extra.offset`` (not all zero)
    + ``extra.crs``."""
    extra = obj.get("extra")
    if not isinstance(extra, dict):
        return None
    keys = _LEGACY_OFFSET_KEYS.get(frame)
    if keys is None or extra.get(keys[0]) is None or extra.get(keys[1]) is None:
        return None
    found = _offset_frame(extra, *keys)
    return found if any(found.crs_offset) else PoseFrame(POSE_FRAME_CRS, found.crs)


def frame_of_pose_json(obj: dict) -> PoseFrame:
    """The frame a pose JSON object declares (``declared_pose_frame``), old files' too."""
    frame, crs = obj.get("frame"), _crs_string(obj, "crs")
    if frame is not None and frame not in (*POSE_FRAMES, LEGACY_POSE_FRAME_WORLD):
        raise PoseError(
            f"its frame {frame!r} is none of {', '.join(POSE_FRAMES)} (docs/data-formats.md): write the "
            "frame its numbers are in, or leave it out"
        )
    if frame == POSE_FRAME_CRS_OFFSET:
        if crs is not None:
            raise PoseError(
                f"its frame is crs_offset but it also names a crs ({crs}): say one frame its numbers are in"
            )
        return _offset_frame(obj, "crs_offset", "offset_crs")
    if frame == POSE_FRAME_MODEL:
        if crs is not None:
            raise PoseError(
                f"its frame is model (no CRS) but it names a crs ({crs}): say one frame its numbers are in"
            )
        return PoseFrame(POSE_FRAME_MODEL)
    if crs is not None:  # "crs", and an old "world" or a file without a frame that names its CRS
        return PoseFrame(POSE_FRAME_CRS, crs)
    legacy = _legacy_offset_frame(obj, frame)
    if legacy is not None:
        return legacy
    # An old "crs" / "world" without a crs: a model's frame without a CRS; no frame at all: none declared.
    return PoseFrame(POSE_FRAME_MODEL if frame is not None else None)


def declared_pose_frame(spec: str | os.PathLike) -> PoseFrame:
    """The frame a JSON pose (file or inline) declares its numbers in, ``PoseFrame(None)`` when it declares
    none (every non-JSON form, a JSON pose without ``frame`` or ``crs``): what ``pose_to_dict`` writes
    beside the pose, for the caller to check against the model it is used with (a pose file of another CRS,
    or of the CRS minus another offset, is not a pose in this one; ``citymodel.pose_crs``).

    Files written before stop 52 are read as what they were: "frame": "crs" with a ``crs`` and "world" with
    one are ``crs``; "crs" without one but with ``extra.crs_offset`` / ``extra.offset_crs`` (``run
    --offset``), and "world" with ``extra.offset`` / ``extra.crs`` (``dataset dji-prior --offset``), are
    ``crs_offset``; any other "crs" / "world" without a ``crs`` is ``model``."""
    text, label = load_spec(spec, PoseError, "pose")
    if not text.lstrip().startswith("{"):
        return PoseFrame(None)
    obj = labelled(label, parse_json, text)
    if not isinstance(obj, dict):
        return PoseFrame(None)
    return labelled(label, frame_of_pose_json, obj)

"""Read poses and intrinsics from the small text formats users pass on the CLI; write a pose as JSON.

Every reader takes a ``spec``: a path to a file, or the text itself (inline JSON, a COLMAP line, comma
separated numbers). The accepted forms are listed in ``read_pose`` and ``read_intrinsics``. Whatever is
wrong with an input, the error is one of ``PoseError`` / ``CameraError`` / ``ShapeError`` /
``InputFileError`` with a one-line message that starts with the file name or the inline text.

Frames: a pose is read exactly as written (in whatever world frame the file uses, usually the model's
CRS); bring it to a model's local frame with ``model.pose_to_local(pose)``. A JSON pose also declares its
world frame (``frame``: ``POSE_FRAMES``), which ``declared_pose_frame`` reads for the caller to check
(``citymodel.pose_crs.read_pose_world``). ``write_pose_json(path, pose_local=..., origin_world=...)``
writes a local pose in the world frame again (local + origin, float64), so its output reads back.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from semcityloc.errors import (
    ArgumentTypeError,
    CameraError,
    InputFileError,
    IntrinsicsMismatchError,
    PoseError,
    SemCityLocError,
    ShapeError,
    UnknownImageSizeError,
)
from semcityloc.geometry.camera import PRINCIPAL_POINT_TOLERANCE, Camera
from semcityloc.geometry.colmap_text import (
    CAMERA_MODELS,
    IMAGE_CAMERA_ID,
    IMAGE_NAME,
    IMAGE_POSE,
    camera_values,
    is_image_line,
    is_number,
    numbers,
)
from semcityloc.geometry.conventions import colmap_qvec_tvec, pose_from_colmap, pose_from_lodloc_c2w
from semcityloc.geometry.distortion import COEFFICIENTS, LensDistortion
from semcityloc.geometry.pose import Pose, local_frame_problem
from semcityloc.io.files import json_default, write_json_atomic

# Pose and intrinsics files are a few lines long; refuse to slurp e.g. an image passed by mistake.
MAX_SPEC_FILE_BYTES = 10_000_000
# COLMAP camera models we read: name -> parameter names. Their distortion is ``LensDistortion``'s model
# (``read_lens``); FULL_OPENCV only without its rational terms k4..k6.
COLMAP_MODELS: dict[str, tuple[str, ...]] = {
    name: CAMERA_MODELS[name][1]
    for name in ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV")
}
_RATIONAL_TERMS = ("k4", "k5", "k6")
# A pose JSON holding both matrices must agree to this (metres / rotation-matrix entries).
CONSISTENCY_TOL_M = 1e-4
CONSISTENCY_TOL_R = 1e-6

_SPLIT = re.compile(r"[,\s]+")


# ---------------------------------------------------------------------------------------------- input
def _label(spec: str | os.PathLike, is_file: bool) -> str:
    if is_file:
        return str(spec)
    text = " ".join(str(spec).split())
    return repr(text if len(text) <= 80 else text[:77] + "...")


def _is_file(path: Path) -> bool:
    try:
        return path.is_file()
    except (OSError, ValueError):  # name too long, embedded NUL: not a file name
        return False


def _load(spec: str | os.PathLike, error: type[SemCityLocError], what: str) -> tuple[str, str]:
    """``(text, label)`` of a spec: the file's content if it names a file, else the spec itself."""
    if isinstance(spec, os.PathLike):
        path: Path | None = Path(spec)
    elif isinstance(spec, str):
        stripped = spec.strip()
        if not stripped:
            raise error(f"empty {what}")
        if stripped.startswith(("{", "[")) or "\n" in stripped:
            path = None  # inline JSON / several lines: text, never a file name
        else:
            path = Path(stripped)
            if not _is_file(path):
                # Inline forms end with a number ("x,y,z,roll,pitch,yaw", "name qw ... tz", "fx,...,h")
                # or are comma separated; anything else is taken for a file name that does not exist.
                if "," not in stripped and not is_number(_SPLIT.split(stripped)[-1]):
                    raise InputFileError(f"{stripped}: no such {what} file")
                path = None
    else:
        raise error(f"{what} must be a path or a string, got {type(spec).__name__}")
    if path is None:
        return str(spec), _label(spec, False)
    label = str(path)
    try:
        if path.stat().st_size > MAX_SPEC_FILE_BYTES:
            raise InputFileError(f"{label}: {path.stat().st_size} bytes is too large for a {what} file")
        return path.read_text(encoding="utf-8-sig"), label  # a BOM (Windows editors) is no content
    except FileNotFoundError as exc:
        raise InputFileError(f"{label}: no such {what} file") from exc
    except UnicodeDecodeError as exc:
        raise InputFileError(f"{label}: not a UTF-8 text file (expected a {what} file)") from exc
    except OSError as exc:
        raise InputFileError(f"{label}: cannot read {what} file: {exc.strerror or exc}") from exc


def _json(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputFileError(f"invalid JSON ({exc.msg} at line {exc.lineno} column {exc.colno})") from exc


def _lines(text: str) -> list[list[str]]:
    """Token lists of the non-empty, non-comment lines; tokens split on whitespace and commas."""
    out = []
    for line in text.splitlines():
        line = line.strip()
        tokens = [t for t in _SPLIT.split(line) if t] if not line.startswith("#") else []
        if tokens:  # a line of separators alone (",") holds nothing
            out.append(tokens)
    return out


def _pick(entries: dict[str, Any], name: str | None, error: type[SemCityLocError], what: str) -> Any:
    """The entry called ``name`` (exact, then file name, then stem); the only one when name is None."""
    if name is None:
        if len(entries) == 1:
            return next(iter(entries.values()))
        some = ", ".join(list(entries)[:3])
        raise error(f"{len(entries)} {what}s ({some}, ...): pass the image name to choose one")
    for key in (lambda n: n, lambda n: Path(n).name, lambda n: Path(n).stem):
        hits = [k for k in entries if key(k) == key(name)]
        if len(hits) == 1:
            return entries[hits[0]]
        if len(hits) > 1:
            raise error(f"image name {name!r} is ambiguous: it matches {', '.join(hits[:3])}")
    raise error(f"no {what} for image {name!r} (have {len(entries)}: {', '.join(list(entries)[:3])}, ...)")


def _matrix(value: Any, shapes: tuple[tuple[int, int], ...], key: str) -> np.ndarray:
    """A JSON matrix of one of ``shapes``; a 4x4 one must end in the row [0, 0, 0, 1] (rigid transform)."""
    wanted = " or ".join(f"{r}x{c}" for r, c in shapes)
    try:
        M = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{key!r} must be a {wanted} matrix of numbers") from exc
    if M.shape not in shapes:
        raise ShapeError(f"{key!r} must be {wanted}, got shape {M.shape}")
    if M.shape == (4, 4) and not np.array_equal(M[3], [0.0, 0.0, 0.0, 1.0]):
        raise PoseError(f"{key!r}: the last row of a 4x4 rigid transform must be [0, 0, 0, 1]")
    return M


_RIGID = ((4, 4), (3, 4))


def _number(obj: dict, key: str, error: type[SemCityLocError]) -> float:
    value = obj[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise error(f"{key!r} must be a number, got {value!r}")
    try:
        return float(value)
    except OverflowError:  # an integer beyond float64 (JSON integers are unbounded)
        raise error(f"{key!r} is too large: {str(value)[:40]}...") from None


def _vector(obj: dict, key: str, n: int, error: type[SemCityLocError]) -> list[float]:
    value = obj[key]
    if (
        not isinstance(value, list)
        or len(value) != n
        or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value)
    ):
        raise error(f"{key!r} must be a list of {n} numbers, got {value!r}")
    try:
        return [float(v) for v in value]
    except OverflowError:  # an integer beyond float64
        raise error(f"{key!r} holds a number too large for float64") from None


def _labelled(label: str, fn, *args):
    """Run a parser; prefix its typed error with the input's label."""
    try:
        return fn(*args)
    except InputFileError as exc:
        if str(exc).startswith(label):
            raise
        raise InputFileError(f"{label}: {exc}") from exc
    except (PoseError, CameraError, ShapeError) as exc:
        raise type(exc)(f"{label}: {exc}") from exc


# ---------------------------------------------------------------------------------------------- poses
POSE_FORMS = (
    "a 4x4 (or 3x4) camera-to-world matrix (LoD-Loc *_pose.txt), 'name qw qx qy qz tx ty tz' (COLMAP), "
    "COLMAP images.txt, JSON, or 'x,y,z,roll,pitch,yaw'"
)


def _pose_from_json(obj: Any) -> Pose:
    if not isinstance(obj, dict):
        raise PoseError(f"pose JSON must be an object, got {type(obj).__name__}")
    if "world_from_cam" in obj:
        pose = Pose.from_world_from_cam(_matrix(obj["world_from_cam"], _RIGID, "world_from_cam"))
        if "cam_from_world" in obj:
            other = Pose.from_cam_from_world(_matrix(obj["cam_from_world"], _RIGID, "cam_from_world"))
            if (
                np.abs(other.center - pose.center).max() > CONSISTENCY_TOL_M
                or np.abs(other.R - pose.R).max() > CONSISTENCY_TOL_R
            ):
                raise PoseError("'world_from_cam' and 'cam_from_world' are not inverses of each other")
        return pose
    if "cam_from_world" in obj:
        return Pose.from_cam_from_world(_matrix(obj["cam_from_world"], _RIGID, "cam_from_world"))
    qkey = "qvec" if "qvec" in obj else "qvec_wxyz" if "qvec_wxyz" in obj else None
    if qkey is not None:
        if "tvec" not in obj:
            raise PoseError(f"{qkey!r} needs 'tvec' (COLMAP world-to-camera translation)")
        return pose_from_colmap(*_vector(obj, qkey, 4, PoseError), *_vector(obj, "tvec", 3, PoseError))
    xyz_key = "xyz" if "xyz" in obj else "position" if "position" in obj else None
    if xyz_key is not None:
        missing = [k for k in ("roll", "pitch", "yaw") if k not in obj]
        if missing:
            raise PoseError(f"{xyz_key!r} needs 'roll', 'pitch' and 'yaw' (missing {', '.join(missing)})")
        angles = [_number(obj, k, PoseError) for k in ("roll", "pitch", "yaw")]
        return Pose.from_xyz_rpy(_vector(obj, xyz_key, 3, PoseError), *angles)
    raise PoseError(
        "pose JSON needs 'world_from_cam', 'cam_from_world', 'qvec'+'tvec' or 'xyz'+'roll'/'pitch'/'yaw'; "
        f"got keys {sorted(obj)}"
    )


def _colmap_images(rows: list[list[str]]) -> dict[str, Pose]:
    """COLMAP images.txt: 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME' lines (2D-point lines ignored)."""
    return {r[IMAGE_NAME]: pose_from_colmap(*map(float, r[IMAGE_POSE])) for r in rows if is_image_line(r)}


def _pose_entries(text: str) -> dict[str, Pose]:
    """All poses in a text (not JSON); unnamed single poses are keyed ''."""
    rows = _lines(text)
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


def _read_pose_entries(spec: str | os.PathLike) -> tuple[dict[str, Pose], str]:
    text, label = _load(spec, PoseError, "pose")

    def parse() -> dict[str, Pose]:
        if text.lstrip().startswith(("{", "[")):
            return {"": _pose_from_json(_json(text))}
        return _pose_entries(text)

    return _labelled(label, parse), label


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
    offset = _vector(obj, offset_key, 3, PoseError)
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


def _pose_frame(obj: dict) -> PoseFrame:
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
    text, label = _load(spec, PoseError, "pose")
    if not text.lstrip().startswith("{"):
        return PoseFrame(None)
    obj = _labelled(label, _json, text)
    if not isinstance(obj, dict):
        return PoseFrame(None)
    return _labelled(label, _pose_frame, obj)


def read_poses(spec: str | os.PathLike) -> dict[str, Pose]:
    """Every pose in a spec, by image name (``''`` for an unnamed single pose). Forms: ``read_pose``."""
    return _read_pose_entries(spec)[0]


def read_colmap_camera_ids(spec: str | os.PathLike) -> dict[str, str]:
    """Image name -> ``CAMERA_ID`` (as written) of every COLMAP ``images.txt`` image line in a spec, the
    lines ``read_poses`` takes poses from; ``{}`` for the other pose forms."""
    text, _ = _load(spec, PoseError, "pose")
    return {r[IMAGE_NAME]: r[IMAGE_CAMERA_ID] for r in _lines(text) if is_image_line(r)}


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
    entries, label = _read_pose_entries(spec)
    if list(entries) == [""]:
        return entries[""]
    return _labelled(label, _pick, entries, name, PoseError, "pose")


# ---------------------------------------------------------------------------------------------- intrinsics
INTRINSICS_FORMS = (
    "a 3x4 [K|0] or 3x3 K matrix (LoD-Loc *_intrinsic.txt), 'name PINHOLE w h fx fy cx cy' "
    "(COLMAP; also SIMPLE_PINHOLE w h f cx cy), JSON, or 'fx,fy,cx,cy,w,h'"
)


def _size_from_principal_point(c: float, axis: str) -> int:
    """Image size 2c for a principal point c at the image centre (LoD-Loc files do not store the size)."""
    size = 2.0 * c
    if not math.isfinite(size) or size < 1 or abs(size - round(size)) > 1e-6:
        raise UnknownImageSizeError(
            f"cannot infer the image {axis} from c{'x' if axis == 'width' else 'y'}={c:g} "
            f"(not at the centre of a whole-pixel image): pass the image {axis}"
        )
    return int(round(size))


def _camera(
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    own_w: int | None,
    own_h: int | None,
    width: int | None,
    height: int | None,
) -> Camera:
    """The camera at its own size if it has one (``read_lens`` resamples it to the requested size, after
    checking it against the photo it is for), else at the given size, else ``2 cx`` x ``2 cy``."""
    if own_w is not None and own_h is not None:
        if (width is None) != (height is None):
            raise CameraError(
                f"intrinsics are for {own_w}x{own_h}; give both width and height to resample them, or neither"
            )
        return Camera(fx, fy, cx, cy, own_w, own_h)
    w = width if width is not None else _size_from_principal_point(cx, "width")
    h = height if height is not None else _size_from_principal_point(cy, "height")
    return Camera(fx, fy, cx, cy, w, h)


def _resampled(camera: Camera, width: int | None, height: int | None) -> Camera:
    """``camera`` at ``width`` x ``height`` when both are given and differ from its size (``Camera.scaled``:
    the same field of view, e.g. a downscaled image)."""
    if width is None or height is None or (width, height) == camera.size:
        return camera
    return camera.scaled(width, height)


def _is_resized(size: tuple[int, int], other: tuple[int, int]) -> bool:
    """Whether an image of size ``other`` is one of ``size`` resized by one factor, each side rounded to
    whole pixels: what ``Camera.scaled`` resamples intrinsics for. Another aspect is another image."""
    (w, h), (w2, h2) = size, other
    return abs(h * w2 / w - h2) <= 1.0 or abs(w * h2 / h - w2) <= 1.0


def check_fits_photo(camera: Camera, source: str, photo: tuple[str, int, int]) -> None:
    """``IntrinsicsMismatchError`` naming ``source`` (the intrinsics' file), the photo and both sizes unless
    ``camera`` (at the size the file states, or was placed at) can describe ``photo`` (name, width, height):
    its size is the photo's or the photo is it resized (``_is_resized``), and its principal point is
    within ``PRINCIPAL_POINT_TOLERANCE`` of the image centre (the bound DJI's calibration tags are held to).
    Why: the intrinsics of another image (a thermal camera's 640x512 on a 2325x1742 photo) localize
    nothing, and the run then blames the map and the prior."""
    name, width, height = photo
    if camera.size != (width, height) and not _is_resized(camera.size, (width, height)):
        raise IntrinsicsMismatchError(
            f"{source}: intrinsics of a {camera.width}x{camera.height} image do not fit photo {name} "
            f"({width}x{height}), which is no resized copy of it: the calibration of another camera or "
            "image size"
        )
    offset = camera.principal_point_offset()
    if offset > PRINCIPAL_POINT_TOLERANCE:
        raise IntrinsicsMismatchError(
            f"{source}: principal point ({camera.cx:g}, {camera.cy:g}) lies {100 * offset:.0f} % of the "
            f"image size off the centre of photo {name} ({width}x{height}; at most "
            f"{100 * PRINCIPAL_POINT_TOLERANCE:.0f} %): it is the centre of a {2 * camera.cx:.0f}x"
            f"{2 * camera.cy:.0f} image, the calibration of another camera or image size"
        )


def _check_K(K: np.ndarray) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) of a 3x3 K or 3x4 [K|0]; anything else that is not a pinhole K -> CameraError."""
    if K.shape[1] == 4 and np.abs(K[:, 3]).max() > 0:
        raise CameraError("a 3x4 intrinsic matrix must be [K|0] (its last column is not zero)")
    if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise CameraError("not an intrinsic matrix: expected [[fx 0 cx] [0 fy cy] [0 0 1]]")
    if abs(K[0, 1]) > 1e-9 * max(abs(K[0, 0]), 1.0):
        raise CameraError("skewed intrinsics (K[0][1] != 0) are not supported")
    return float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])


def _lens_from_json(obj: Any, width: int | None, height: int | None) -> tuple[Camera, LensDistortion]:
    camera = _camera_from_json(obj, width, height)
    terms = {k: _number(obj, k, CameraError) for k in COEFFICIENTS if k in obj}
    return camera, LensDistortion(**terms)


def _camera_from_json(obj: Any, width: int | None, height: int | None) -> Camera:
    if not isinstance(obj, dict):
        raise CameraError(f"intrinsics JSON must be an object, got {type(obj).__name__}")
    size = [None, None]
    for i, key in enumerate(("width", "height")):
        if key in obj:
            v = _number(obj, key, CameraError)
            if not v.is_integer():
                raise CameraError(f"{key!r} must be a whole number of pixels, got {v:g}")
            size[i] = int(v)
    if (size[0] is None) != (size[1] is None):
        raise CameraError("intrinsics JSON has only one of 'width' and 'height'")
    if "K" in obj:
        fx, fy, cx, cy = _check_K(_matrix(obj["K"], ((3, 3), (3, 4)), "K"))
    else:
        missing = [k for k in ("fx", "fy", "cx", "cy") if k not in obj]
        if missing:
            raise CameraError(
                f"intrinsics JSON needs 'fx', 'fy', 'cx', 'cy' (or 'K'); missing {', '.join(missing)}"
            )
        fx, fy, cx, cy = (_number(obj, k, CameraError) for k in ("fx", "fy", "cx", "cy"))
    return _camera(fx, fy, cx, cy, size[0], size[1], width, height)


def _colmap_lens(
    tokens: list[str], at: int, width: int | None, height: int | None
) -> tuple[Camera, LensDistortion]:
    model, w, h, params = camera_values(tokens, at, COLMAP_MODELS)
    rational = {k: params[k] for k in _RATIONAL_TERMS if params.get(k, 0.0) != 0}
    if rational:
        terms = ", ".join(f"{k}={v:g}" for k, v in rational.items())
        raise CameraError(
            f"{model} has rational distortion terms ({terms}), which are not supported: calibrate with "
            "OPENCV (k1 k2 p1 p2) or undistort the images first"
        )
    fx = params.get("fx", params.get("f"))
    fy = params.get("fy", params.get("f"))
    camera = _camera(fx, fy, params["cx"], params["cy"], w, h, width, height)
    return camera, LensDistortion.from_params(params)


def _camera_entries(
    text: str, width: int | None, height: int | None
) -> dict[str, tuple[Camera, LensDistortion]]:
    rows = _lines(text)
    if not rows:
        raise CameraError(f"no intrinsic values; expected {INTRINSICS_FORMS}")
    model_at = [next((i for i in (0, 1) if i < len(r) and r[i].upper() in COLMAP_MODELS), None) for r in rows]
    if any(m is not None for m in model_at):
        out = {}
        for r, at in zip(rows, model_at, strict=True):
            if at is None:
                raise CameraError(
                    f"line {' '.join(r)[:60]!r} names no camera model; expected {INTRINSICS_FORMS}"
                )
            out[r[0] if at == 1 else ""] = _colmap_lens(r, at, width, height)
        return out
    for r in rows:
        if len(r) > 2 and not is_number(r[1]) and is_number(r[2]):
            raise CameraError(f"unsupported camera model {r[1]!r} (supported: {', '.join(COLMAP_MODELS)})")
    values = [numbers(r, CameraError) for r in rows]
    counts = [len(v) for v in values]
    if len(rows) == 3 and (all(c == 4 for c in counts) or all(c == 3 for c in counts)):
        return {"": (_camera(*_check_K(np.array(values)), None, None, width, height), LensDistortion())}
    if len(rows) == 1 and counts[0] in (4, 6):
        v = values[0]
        own = (None, None)
        if counts[0] == 6:
            if not (v[4].is_integer() and v[5].is_integer()):
                raise CameraError(f"image size must be whole pixels, got {v[4]:g} x {v[5]:g}")
            own = (int(v[4]), int(v[5]))
        return {"": (_camera(v[0], v[1], v[2], v[3], *own, width, height), LensDistortion())}
    shape = " / ".join(str(c) for c in counts[:5]) + (" / ..." if len(counts) > 5 else "")
    raise CameraError(
        f"{len(rows)} line(s) with {shape} numbers are not intrinsics; expected {INTRINSICS_FORMS}"
    )


def read_intrinsics(
    spec: str | os.PathLike,
    width: int | None = None,
    height: int | None = None,
    name: str | None = None,
    photo: tuple[str, int, int] | None = None,
) -> Camera:
    """Pinhole intrinsics from a file or inline text (``read_lens``'s forms and ``photo`` check);
    ``CameraError`` when they carry a non-zero lens distortion, since a caller of this function uses the
    image as it is."""
    camera, distortion = read_lens(spec, width, height, name, photo)
    if not distortion.is_zero:
        terms = ", ".join(f"{k}={v:g}" for k, v in distortion.as_dict().items() if k != "model" and v)
        raise CameraError(
            f"{_load(spec, CameraError, 'intrinsics')[1]}: non-zero lens distortion "
            f"({terms}); this command takes pinhole images: undistort them first (colmap image_undistorter), "
            "or give them to 'semcityloc run' / 'semcityloc localize', which undistort photo, mask and depth"
        )
    return camera


def read_lens(
    spec: str | os.PathLike,
    width: int | None = None,
    height: int | None = None,
    name: str | None = None,
    photo: tuple[str, int, int] | None = None,
) -> tuple[Camera, LensDistortion]:
    """Intrinsics and lens distortion (``geometry.distortion``; zero for the pinhole forms) from a file or
    inline text. Accepted forms:

    - LoD-Loc ``*_intrinsic.txt``: a 3x4 ``[K|0]`` (or 3x3 ``K``) matrix. It stores no image size: unless
      ``width`` / ``height`` are given they are taken as ``2 cx`` / ``2 cy`` (principal point at the image
      centre; the real file has cx = 320, cy = 256 for a 640x512 image). A principal point that is not at
      the centre of a whole-pixel image raises ``CameraError`` asking for the size;
    - a COLMAP ``cameras.txt`` / LoD-Loc ``intrinsic.txt`` line ``name MODEL w h params`` (or without the
      name/id), MODEL one of PINHOLE ``fx fy cx cy``, SIMPLE_PINHOLE ``f cx cy``, SIMPLE_RADIAL ``f cx cy
      k``, RADIAL ``f cx cy k1 k2``, OPENCV ``fx fy cx cy k1 k2 p1 p2`` and FULL_OPENCV with its rational
      terms k4..k6 zero; several lines need ``name``;
    - JSON ``{"fx", "fy", "cx", "cy", "width", "height"}`` or ``{"K": 3x3, "width", "height"}``
      (``Camera.as_dict`` output reads back), optionally with ``"k1", "k2", "p1", "p2", "k3"``;
    - inline ``fx,fy,cx,cy,w,h`` (or ``fx,fy,cx,cy`` with the size rule above).

    When the intrinsics carry their own size and both ``width`` and ``height`` are given and differ, the
    camera is resampled to that size (``Camera.scaled``: same field of view, e.g. a downscaled image; the
    distortion, in normalised coordinates, is the same at any size).

    ``photo``: (name, width, height) of the photo the intrinsics are used with; before any resampling they
    must fit it (``check_fits_photo``: the same size or the photo resized, a principal point near the
    centre), else ``IntrinsicsMismatchError`` naming the file, the photo and both sizes.
    """
    for key, value in (("width", width), ("height", height)):
        if value is not None and (
            isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0
        ):
            raise CameraError(f"image {key} must be a positive integer, got {value!r}")
    text, label = _load(spec, CameraError, "intrinsics")

    def parse() -> dict[str, tuple[Camera, LensDistortion]]:
        if text.lstrip().startswith(("{", "[")):
            return {"": _lens_from_json(_json(text), width, height)}
        return _camera_entries(text, width, height)

    entries = _labelled(label, parse)
    if list(entries) == [""]:
        camera, distortion = entries[""]
    else:
        camera, distortion = _labelled(label, _pick, entries, name, CameraError, "camera")
    if photo is not None:
        check_fits_photo(camera, label, photo)
    camera = _labelled(label, _resampled, camera, width, height)
    _labelled(label, distortion.check, camera)
    return camera, distortion


# ---------------------------------------------------------------------------------------------- output
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
    (4x4), ``qvec_wxyz`` / ``tvec`` (COLMAP), ``convention`` (a reminder string), and ``extra`` (any
    JSON-serialisable dict) when given. ``read_pose`` reads the file back (in the frame it was written in;
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

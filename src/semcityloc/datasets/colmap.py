"""COLMAP sparse models (``cameras``, ``images``, ``points3D``) in text and binary form: read and write.

Why our own reader: users bring priors and want results as COLMAP models, and ``pycolmap`` is a heavy
optional package whose Python API changes between releases. The two file formats are small and stable
(COLMAP's ``src/colmap/scene/reconstruction_io.cc``); this module implements them with ``struct`` and
numpy. ``colmap_pycolmap.py`` converts to and from ``pycolmap.Reconstruction`` when that is installed.

Text format (``*.txt``; ``#`` lines are comments, tokens are separated by spaces; the camera-model table
and the line parsing and writing are ``geometry.colmap_text``, shared with ``geometry.io``):

- ``cameras.txt``: ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`` per line;
- ``images.txt``: two lines per image, ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` and then
  ``X Y POINT3D_ID`` triples of its 2D points (an empty line when it has none; POINT3D_ID -1 = none);
- ``points3D.txt``: ``POINT3D_ID X Y Z R G B ERROR TRACK[]`` with TRACK as ``IMAGE_ID POINT2D_IDX`` pairs.

Binary format (``*.bin``; little-endian, no padding):

- ``cameras.bin``: ``uint64`` count, then per camera ``int32 camera_id, int32 model_id, uint64 width,
  uint64 height, float64 params[n]`` (n fixed by the model, ``CAMERA_MODELS``);
- ``images.bin``: ``uint64`` count, then per image ``uint32 image_id, float64 qw qx qy qz, float64 tx ty
  tz, uint32 camera_id``, the name as UTF-8 bytes ending in a NUL byte, ``uint64`` number of 2D points
  and per point ``float64 x, float64 y, int64 point3D_id`` (-1 = none);
- ``points3D.bin``: ``uint64`` count, then per point ``uint64 point3D_id, float64 x y z, uint8 r g b,
  float64 error, uint64 track_length`` and per track element ``uint32 image_id, uint32 point2D_idx``.

Poses: ``(qvec, tvec)`` is ``cam_from_world`` with a Hamilton quaternion ``(qw, qx, qy, qz)``; COLMAP's
camera axes are OpenCV's, so ``ColmapImage.pose`` is directly our ``Pose`` (``geometry.conventions``).
Values are kept exactly: the text writer prints floats with ``repr`` (shortest round-trip form), so a
model written and read back in either format equals the input bit for bit.
"""

from __future__ import annotations

import io
import os
import struct
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from semcityloc.errors import (
    CameraError,
    InputFileError,
    OutputPathError,
    UnsupportedFormatError,
    unknown_choice,
)
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.colmap_text import (
    CAMERA_MODELS,
    MODEL_BY_ID,
    camera_line,
    format_float,
    image_lines,
    parse_tokens,
    read_camera_lines,
    read_image_lines,
    text_rows,
)
from semcityloc.geometry.conventions import colmap_qvec_tvec, pose_from_colmap
from semcityloc.geometry.distortion import LensDistortion
from semcityloc.geometry.pose import Pose
from semcityloc.io.files import write_atomic

# Models that are a pinhole once their distortion terms are zero: (fx, fy, cx, cy) from params.
_PINHOLE_PARTS: dict[str, tuple[int, int, int, int]] = {
    "SIMPLE_PINHOLE": (0, 0, 1, 2),
    "PINHOLE": (0, 1, 2, 3),
    "SIMPLE_RADIAL": (0, 0, 1, 2),
    "RADIAL": (0, 0, 1, 2),
    "OPENCV": (0, 1, 2, 3),
    "FULL_OPENCV": (0, 1, 2, 3),
}
# A count read from a binary file above this is corruption, not a model (refuse before allocating).
MAX_BINARY_COUNT = 1 << 32


def text_unreadable_names(names) -> list[str]:
    """The ``names`` COLMAP's text reader cannot read back from ``images.txt``: empty, or holding white
    space (``ReadImagesText`` takes a name up to its first space, so ``my photo.JPG`` reads back as ``my``).
    The binary format holds any name."""
    return [n for n in names if not n or any(c.isspace() for c in n)]


# ---------------------------------------------------------------------------------------------- records
@dataclass
class ColmapCamera:
    """One COLMAP camera: ``params`` in the order of ``CAMERA_MODELS[model]``."""

    camera_id: int
    model: str
    width: int
    height: int
    params: np.ndarray

    def __post_init__(self) -> None:
        if self.model not in CAMERA_MODELS:
            raise unknown_choice("COLMAP camera model", self.model, CAMERA_MODELS, UnsupportedFormatError)
        self.params = np.asarray(self.params, dtype=np.float64).reshape(-1)
        n = len(CAMERA_MODELS[self.model][1])
        if self.params.size != n:
            raise CameraError(
                f"COLMAP camera {self.camera_id}: {self.model} needs {n} params, got {self.params.size}"
            )

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, ColmapCamera)
            and (self.camera_id, self.model, self.width, self.height)
            == (other.camera_id, other.model, other.width, other.height)
            and np.array_equal(self.params, other.params)
        )

    def to_lens_camera(self) -> tuple[Camera, LensDistortion]:
        """The ``Camera`` and its lens (``geometry.distortion``: k1 k2 p1 p2 k3; zero for the pinhole
        models), what ``from_camera`` wrote; ``CameraError`` for fisheye models, FULL_OPENCV's rational
        terms k4..k6, or a lens that folds over inside the image."""
        parts = _PINHOLE_PARTS.get(self.model)
        if parts is None:
            raise CameraError(f"COLMAP camera {self.camera_id}: model {self.model} is not a pinhole camera")
        params = dict(zip(CAMERA_MODELS[self.model][1], self.params.tolist(), strict=True))
        rational = {k: v for k, v in params.items() if k in ("k4", "k5", "k6") and v != 0}
        if rational:
            raise CameraError(
                f"COLMAP camera {self.camera_id}: {self.model} has rational distortion terms {rational}, "
                "which are not supported (calibrate with OPENCV, or undistort the images first)"
            )
        fx, fy, cx, cy = (float(self.params[i]) for i in parts)
        camera, lens = Camera(fx, fy, cx, cy, self.width, self.height), LensDistortion.from_params(params)
        lens.check(camera)
        return camera, lens

    def to_camera(self) -> Camera:
        """The pinhole ``Camera``; ``CameraError`` for fisheye models or non-zero distortion terms
        (``to_lens_camera`` reads those)."""
        parts = _PINHOLE_PARTS.get(self.model)
        if parts is None:
            raise CameraError(f"COLMAP camera {self.camera_id}: model {self.model} is not a pinhole camera")
        n_pinhole = 3 if self.model.startswith(("SIMPLE", "RADIAL")) else 4
        distortion = self.params[n_pinhole:]
        if np.any(distortion != 0):
            raise CameraError(
                f"COLMAP camera {self.camera_id}: {self.model} has distortion {distortion.tolist()}; "
                "undistort the images first (colmap image_undistorter) and use the PINHOLE model, or read "
                "it with its lens (ColmapCamera.to_lens_camera)"
            )
        fx, fy, cx, cy = (float(self.params[i]) for i in parts)
        return Camera(fx, fy, cx, cy, self.width, self.height)

    @classmethod
    def from_camera(
        cls, camera: Camera, camera_id: int = 1, distortion: LensDistortion | None = None
    ) -> ColmapCamera:
        """The COLMAP camera of a ``Camera`` and its lens: ``PINHOLE`` without distortion, ``OPENCV``
        (fx fy cx cy k1 k2 p1 p2), or ``FULL_OPENCV`` when k3 is not zero (its k4..k6 zero)."""
        pinhole = [camera.fx, camera.fy, camera.cx, camera.cy]
        if distortion is None or distortion.is_zero:
            return cls(camera_id, "PINHOLE", camera.width, camera.height, pinhole)
        d = distortion
        opencv = [*pinhole, d.k1, d.k2, d.p1, d.p2]
        if d.k3 == 0.0:
            return cls(camera_id, "OPENCV", camera.width, camera.height, opencv)
        return cls(camera_id, "FULL_OPENCV", camera.width, camera.height, [*opencv, d.k3, 0.0, 0.0, 0.0])


@dataclass
class ColmapImage:
    """One registered image: its ``cam_from_world`` pose, camera and 2D points (``xys`` (N, 2),
    ``point3D_ids`` (N,), -1 where a 2D point has no 3D point)."""

    image_id: int
    qvec: np.ndarray  # (4,) qw qx qy qz, cam_from_world
    tvec: np.ndarray  # (3,)
    camera_id: int
    name: str
    xys: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    point3D_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __post_init__(self) -> None:
        self.qvec = np.asarray(self.qvec, dtype=np.float64).reshape(4)
        self.tvec = np.asarray(self.tvec, dtype=np.float64).reshape(3)
        self.xys = np.asarray(self.xys, dtype=np.float64).reshape(-1, 2)
        self.point3D_ids = np.asarray(self.point3D_ids, dtype=np.int64).reshape(-1)
        if len(self.xys) != len(self.point3D_ids):
            raise InputFileError(
                f"COLMAP image {self.image_id}: {len(self.xys)} 2D points but {len(self.point3D_ids)} ids"
            )

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, ColmapImage)
            and (self.image_id, self.camera_id, self.name) == (other.image_id, other.camera_id, other.name)
            and np.array_equal(self.qvec, other.qvec)
            and np.array_equal(self.tvec, other.tvec)
            and np.array_equal(self.xys, other.xys)
            and np.array_equal(self.point3D_ids, other.point3D_ids)
        )

    @property
    def pose(self) -> Pose:
        """``cam_from_world`` as a ``Pose`` (``PoseError`` for a quaternion far from unit norm)."""
        return pose_from_colmap(*self.qvec, *self.tvec)

    @classmethod
    def from_pose(cls, image_id: int, name: str, camera_id: int, pose_world: Pose) -> ColmapImage:
        """The image record of ``pose`` (cam_from_world) as COLMAP's qvec (qw >= 0) and tvec."""
        qvec, tvec = colmap_qvec_tvec(pose_world)
        return cls(image_id, qvec, tvec, camera_id, name)


@dataclass
class ColmapPoint3D:
    """One 3D point with colour, reprojection error and track ``(image_id, point2D_idx)`` pairs."""

    point3D_id: int
    xyz: np.ndarray
    rgb: np.ndarray
    error: float
    image_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    point2D_idxs: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __post_init__(self) -> None:
        self.xyz = np.asarray(self.xyz, dtype=np.float64).reshape(3)
        self.rgb = np.asarray(self.rgb, dtype=np.uint8).reshape(3)
        self.error = float(self.error)
        self.image_ids = np.asarray(self.image_ids, dtype=np.int64).reshape(-1)
        self.point2D_idxs = np.asarray(self.point2D_idxs, dtype=np.int64).reshape(-1)
        if len(self.image_ids) != len(self.point2D_idxs):
            raise InputFileError(f"COLMAP point {self.point3D_id}: track lengths differ")

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, ColmapPoint3D)
            and self.point3D_id == other.point3D_id
            and np.array_equal(self.xyz, other.xyz)
            and np.array_equal(self.rgb, other.rgb)
            and (self.error == other.error or (np.isnan(self.error) and np.isnan(other.error)))
            and np.array_equal(self.image_ids, other.image_ids)
            and np.array_equal(self.point2D_idxs, other.point2D_idxs)
        )


@dataclass
class ColmapModel:
    """A COLMAP sparse model: dicts keyed by id, in file order."""

    cameras: dict[int, ColmapCamera] = field(default_factory=dict)
    images: dict[int, ColmapImage] = field(default_factory=dict)
    points3D: dict[int, ColmapPoint3D] = field(default_factory=dict)

    def poses(self) -> dict[str, tuple[Camera, Pose]]:
        """``{image name: (pinhole Camera, cam_from_world Pose)}`` of every image."""
        return {name: (camera.to_camera(), pose) for name, (camera, pose) in self._image_cameras().items()}

    def lens_poses(self) -> dict[str, tuple[Camera, LensDistortion, Pose]]:
        """``{image name: (Camera, its lens, cam_from_world Pose)}`` of every image: ``poses`` for cameras
        with distortion (``ColmapCamera.to_lens_camera``; ``poses`` refuses them). Public API for reading
        any COLMAP model with its lenses (``docs/data-formats.md``); nothing in the library calls it."""
        return {
            name: (*camera.to_lens_camera(), pose) for name, (camera, pose) in self._image_cameras().items()
        }

    def _image_cameras(self) -> dict[str, tuple[ColmapCamera, Pose]]:
        """``{image name: (its COLMAP camera, cam_from_world Pose)}``; an image naming a camera the model
        does not hold is an ``InputFileError``."""
        out = {}
        for image in self.images.values():
            if image.camera_id not in self.cameras:
                raise InputFileError(
                    f"COLMAP image {image.name!r} refers to missing camera {image.camera_id}"
                )
            out[image.name] = (self.cameras[image.camera_id], image.pose)
        return out

    @classmethod
    def from_poses(
        cls,
        entries: Mapping[str, tuple[Camera, Pose]],
        distortions: Mapping[str, LensDistortion] | None = None,
    ) -> ColmapModel:
        """A model of named (camera, pose) pairs, with each image's lens where ``distortions`` names one
        (``ColmapCamera.from_camera``); identical cameras share one COLMAP camera id."""
        model = cls()
        camera_ids: dict[tuple, int] = {}
        for image_id, (name, (camera, pose)) in enumerate(entries.items(), start=1):
            lens = (distortions or {}).get(name)
            lens_key = None if lens is None or lens.is_zero else lens
            key = (camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height, lens_key)
            if key not in camera_ids:
                camera_ids[key] = len(camera_ids) + 1
                model.cameras[camera_ids[key]] = ColmapCamera.from_camera(camera, camera_ids[key], lens)
            model.images[image_id] = ColmapImage.from_pose(image_id, name, camera_ids[key], pose)
        return model


# ---------------------------------------------------------------------------------------------- text
# Line layouts, the camera-model table and the line parsing live in ``geometry.colmap_text``.
def read_cameras_text(path: str | os.PathLike) -> dict[int, ColmapCamera]:
    """``cameras.txt`` -> {camera id: ``ColmapCamera``}; a bad line is an error naming the file and line."""
    path = Path(path)
    cameras: dict[int, ColmapCamera] = {}
    for lineno, cam_id, model, width, height, params in read_camera_lines(path):
        try:
            cameras[cam_id] = ColmapCamera(cam_id, model, width, height, params)
        except (CameraError, UnsupportedFormatError) as exc:
            raise type(exc)(f"{path}: line {lineno}: {exc}") from exc
    return cameras


def read_images_text(path: str | os.PathLike) -> dict[int, ColmapImage]:
    """``images.txt`` -> {image id: ``ColmapImage``} (pose, camera id, name, 2D points); its line layout
    and checks: ``geometry.colmap_text.read_image_lines``.
    """
    images: dict[int, ColmapImage] = {}
    for _, image_id, qvec, tvec, camera_id, name, xys, ids in read_image_lines(path):
        images[image_id] = ColmapImage(image_id, qvec, tvec, camera_id, name, xys, ids)
    return images


def read_points3D_text(path: str | os.PathLike) -> dict[int, ColmapPoint3D]:
    """``points3D.txt`` -> {point id: ``ColmapPoint3D``}; every number checked (colours 0..255, whole tracks),
    a bad line named by file and line.
    """
    path = Path(path)
    points: dict[int, ColmapPoint3D] = {}
    for lineno, line in text_rows(path):
        if not line:
            continue
        tok = line.split()
        if len(tok) < 8 or (len(tok) - 8) % 2:
            raise InputFileError(f"{path}: line {lineno}: expected 'POINT3D_ID X Y Z R G B ERROR TRACK[]'")
        pid = parse_tokens(path, lineno, "point id", int, tok[:1])[0]
        xyz = parse_tokens(path, lineno, "coordinates", float, tok[1:4])
        rgb = parse_tokens(path, lineno, "colour", int, tok[4:7])
        if not all(0 <= c <= 255 for c in rgb):
            raise InputFileError(f"{path}: line {lineno}: colour values must be 0..255, got {rgb}")
        error = parse_tokens(path, lineno, "error", float, tok[7:8])[0]
        track = parse_tokens(path, lineno, "track", int, tok[8:])
        points[pid] = ColmapPoint3D(pid, xyz, rgb, error, track[0::2], track[1::2])
    return points


def write_cameras_text(cameras: Mapping[int, ColmapCamera], path: str | os.PathLike) -> None:
    """Write ``cameras.txt`` with COLMAP's header comments, atomically (a failed write leaves no partial
    file).
    """
    lines = [
        "# Camera list with one line of data per camera:",
        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
        f"# Number of cameras: {len(cameras)}",
    ]
    for c in cameras.values():
        lines.append(camera_line(c.camera_id, c.model, c.width, c.height, c.params))
    _write_text(path, lines)


def write_images_text(images: Mapping[int, ColmapImage], path: str | os.PathLike) -> None:
    """Write ``images.txt`` (two lines per image, COLMAP's header comments), atomically; floats in round-trip
    form, so reading it back gives the same model.
    """
    mean_obs = np.mean([len(im.xys) for im in images.values()]) if images else 0.0
    lines = [
        "# Image list with two lines of data per image:",
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
        "#   POINTS2D[] as (X, Y, POINT3D_ID)",
        f"# Number of images: {len(images)}, mean observations per image: {mean_obs:g}",
    ]
    for im in images.values():
        lines.extend(
            image_lines(im.image_id, im.qvec, im.tvec, im.camera_id, im.name, im.xys, im.point3D_ids)
        )
    _write_text(path, lines)


def write_points3D_text(points: Mapping[int, ColmapPoint3D], path: str | os.PathLike) -> None:
    """Write ``points3D.txt`` (one line per point with its track), atomically."""
    lines = [
        "# 3D point list with one line of data per point:",
        "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
        f"# Number of points: {len(points)}",
    ]
    for p in points.values():
        track = " ".join(f"{int(i)} {int(j)}" for i, j in zip(p.image_ids, p.point2D_idxs, strict=True))
        values = [*map(format_float, p.xyz), *map(str, p.rgb.tolist()), format_float(p.error)]
        lines.append(" ".join([str(p.point3D_id), *values]) + (" " + track if track else ""))
    _write_text(path, lines)


def _write_text(path: str | os.PathLike, lines: list[str]) -> None:
    try:
        write_atomic(Path(path), "\n".join(lines) + "\n")
    except OSError as exc:
        raise InputFileError(f"{path}: cannot write COLMAP file: {exc.strerror or exc}") from exc


# ---------------------------------------------------------------------------------------------- binary
class _Reader:
    """Little-endian reads from bytes with a clear error at the end of the data."""

    def __init__(self, data: bytes, path: Path):
        self.buf = memoryview(data)
        self.pos = 0
        self.path = path

    def take(self, fmt: str):
        """Unpack ``fmt`` at the cursor and advance; a file ending too soon is an InputFileError."""
        size = struct.calcsize(fmt)
        if self.pos + size > len(self.buf):
            raise InputFileError(f"{self.path}: truncated COLMAP binary file (ends at byte {len(self.buf)})")
        values = struct.unpack_from(fmt, self.buf, self.pos)
        self.pos += size
        return values

    def array(self, dtype: np.dtype, count: int) -> np.ndarray:
        """``count`` values of ``dtype`` at the cursor (a copy), refused if the file ends first."""
        size = np.dtype(dtype).itemsize * count
        if self.pos + size > len(self.buf):
            raise InputFileError(f"{self.path}: truncated COLMAP binary file (ends at byte {len(self.buf)})")
        out = np.frombuffer(self.buf, dtype=dtype, count=count, offset=self.pos).copy()
        self.pos += size
        return out

    def count(self, what: str) -> int:
        """A uint64 record count, refused when implausibly large (a corrupt file, not an allocation)."""
        (n,) = self.take("<Q")
        if n > MAX_BINARY_COUNT:
            raise InputFileError(f"{self.path}: implausible number of {what} ({n}): corrupt COLMAP file")
        return n

    def cstring(self) -> str:
        """A NUL-terminated UTF-8 string (an image name) at the cursor."""
        end = bytes(self.buf[self.pos :]).find(b"\x00")
        if end < 0:
            raise InputFileError(f"{self.path}: truncated COLMAP binary file (image name without its NUL)")
        raw = bytes(self.buf[self.pos : self.pos + end])
        self.pos += end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise InputFileError(f"{self.path}: image name is not UTF-8: {raw[:40]!r}") from exc

    def finish(self) -> None:
        """Refuse bytes left after the last record (a file of another layout or version)."""
        if self.pos != len(self.buf):
            raise InputFileError(f"{self.path}: {len(self.buf) - self.pos} bytes after the last record")


def _read_bytes(path: Path) -> bytes:
    """A binary COLMAP file's bytes; one that starts as COLMAP's text files do (``# Camera list``, ``# Image
    list``, ``# 3D point list``) is named as text under a binary name, not read as a count of billions."""
    try:
        data = path.read_bytes()
        if data.startswith((b"# Camera list", b"# Image list", b"# 3D point list")):  # a count never is
            raise InputFileError(
                f"{path}: COLMAP text under a binary file's name (it starts with {data[:14].decode()!r}); "
                f"name it {path.stem}.txt"
            )
        return data
    except FileNotFoundError as exc:
        raise InputFileError(f"{path}: no such COLMAP file") from exc
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read COLMAP file ({exc.strerror or exc})") from exc


_POINT2D = np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")])
_TRACK = np.dtype([("image", "<u4"), ("idx", "<u4")])


def read_cameras_binary(path: str | os.PathLike) -> dict[int, ColmapCamera]:
    """``cameras.bin`` -> {camera id: ``ColmapCamera``}; an unknown model id, a truncated file or bytes after
    the last record are ``InputFileError`` / ``UnsupportedFormatError``, never a silently short model.
    """
    path = Path(path)
    r = _Reader(_read_bytes(path), path)
    cameras = {}
    for _ in range(r.count("cameras")):
        cam_id, model_id, width, height = r.take("<iiQQ")
        if model_id not in MODEL_BY_ID:
            raise UnsupportedFormatError(f"{path}: camera {cam_id} has unknown COLMAP model id {model_id}")
        model = MODEL_BY_ID[model_id]
        params = r.array(np.dtype("<f8"), len(CAMERA_MODELS[model][1]))
        cameras[cam_id] = ColmapCamera(cam_id, model, width, height, params.astype(np.float64))
    r.finish()
    return cameras


def read_images_binary(path: str | os.PathLike) -> dict[int, ColmapImage]:
    """``images.bin`` -> {image id: ``ColmapImage``}; truncation, implausible counts and non-UTF-8 names are
    typed errors naming the file.
    """
    path = Path(path)
    r = _Reader(_read_bytes(path), path)
    images = {}
    for _ in range(r.count("images")):
        image_id, qw, qx, qy, qz, tx, ty, tz, camera_id = r.take("<I7dI")
        name = r.cstring()
        pts = r.array(_POINT2D, r.count("2D points"))
        xys = np.column_stack([pts["x"], pts["y"]]).astype(np.float64)
        images[image_id] = ColmapImage(
            image_id, [qw, qx, qy, qz], [tx, ty, tz], camera_id, name, xys, pts["id"].astype(np.int64)
        )
    r.finish()
    return images


def read_points3D_binary(path: str | os.PathLike) -> dict[int, ColmapPoint3D]:
    """``points3D.bin`` -> {point id: ``ColmapPoint3D``}; truncation and implausible counts are typed
    errors.
    """
    path = Path(path)
    r = _Reader(_read_bytes(path), path)
    points = {}
    for _ in range(r.count("3D points")):
        pid, x, y, z, red, green, blue, error = r.take("<Q3d3Bd")
        track = r.array(_TRACK, r.count("track elements"))
        points[pid] = ColmapPoint3D(
            pid,
            [x, y, z],
            [red, green, blue],
            error,
            track["image"].astype(np.int64),
            track["idx"].astype(np.int64),
        )
    r.finish()
    return points


def write_cameras_binary(cameras: Mapping[int, ColmapCamera], path: str | os.PathLike) -> None:
    """Write ``cameras.bin`` in COLMAP's little-endian layout, atomically."""
    out = io.BytesIO()
    out.write(struct.pack("<Q", len(cameras)))
    for c in cameras.values():
        out.write(struct.pack("<iiQQ", c.camera_id, CAMERA_MODELS[c.model][0], c.width, c.height))
        out.write(np.asarray(c.params, dtype="<f8").tobytes())
    _write_bytes(path, out.getvalue())


def write_images_binary(images: Mapping[int, ColmapImage], path: str | os.PathLike) -> None:
    """Write ``images.bin`` in COLMAP's little-endian layout, atomically; a name with a NUL (which would end
    the name in the file) is refused.
    """
    out = io.BytesIO()
    out.write(struct.pack("<Q", len(images)))
    for im in images.values():
        name = im.name.encode("utf-8")
        if b"\x00" in name:
            raise InputFileError(f"image name {im.name!r} contains a NUL character")
        out.write(struct.pack("<I7dI", im.image_id, *im.qvec, *im.tvec, im.camera_id))
        out.write(name + b"\x00")
        pts = np.zeros(len(im.xys), dtype=_POINT2D)
        pts["x"], pts["y"], pts["id"] = im.xys[:, 0], im.xys[:, 1], im.point3D_ids
        out.write(struct.pack("<Q", len(pts)))
        out.write(pts.tobytes())
    _write_bytes(path, out.getvalue())


def write_points3D_binary(points: Mapping[int, ColmapPoint3D], path: str | os.PathLike) -> None:
    """Write ``points3D.bin`` in COLMAP's little-endian layout, atomically."""
    out = io.BytesIO()
    out.write(struct.pack("<Q", len(points)))
    for p in points.values():
        out.write(struct.pack("<Q3d3Bd", p.point3D_id, *p.xyz, *p.rgb.tolist(), p.error))
        track = np.zeros(len(p.image_ids), dtype=_TRACK)
        track["image"], track["idx"] = p.image_ids, p.point2D_idxs
        out.write(struct.pack("<Q", len(track)))
        out.write(track.tobytes())
    _write_bytes(path, out.getvalue())


def _write_bytes(path: str | os.PathLike, data: bytes) -> None:
    try:
        write_atomic(Path(path), data)
    except OSError as exc:
        raise InputFileError(f"{path}: cannot write COLMAP file: {exc.strerror or exc}") from exc


# ---------------------------------------------------------------------------------------------- models
_READERS = {
    ".txt": (read_cameras_text, read_images_text, read_points3D_text),
    ".bin": (read_cameras_binary, read_images_binary, read_points3D_binary),
}
_WRITERS = {
    ".txt": (write_cameras_text, write_images_text, write_points3D_text),
    ".bin": (write_cameras_binary, write_images_binary, write_points3D_binary),
}


MODEL_KINDS = ("cameras", "images", "points3D")


def model_file(folder: Path, kind: str) -> Path | None:
    """``folder/<kind>.bin`` or ``.txt`` (``kind``: one of ``MODEL_KINDS``), None when neither is there.
    Both there is an ``InputFileError`` naming both (stop 55): they are two models that may differ (a text
    export written into a folder that held a binary one), and COLMAP's choice, binary first, read the one
    the user had not just written, silently."""
    found = [folder / f"{kind}{ext}" for ext in (".bin", ".txt") if (folder / f"{kind}{ext}").is_file()]
    if len(found) > 1:
        raise InputFileError(
            f"{folder}: holds both {found[0].name} and {found[1].name}, a binary and a text COLMAP model "
            "that may differ: remove the one not meant (or give the file itself)"
        )
    return found[0] if found else None


def detect_model_format(path: str | os.PathLike) -> str:
    """``".bin"`` or ``".txt"``: the format whose ``cameras`` and ``images`` files are in ``path``; a folder
    holding either in both formats is refused (``model_file``)."""
    folder = Path(path)
    if not folder.is_dir():
        raise InputFileError(f"{folder}: no such COLMAP model folder")
    cameras, images = model_file(folder, "cameras"), model_file(folder, "images")
    if cameras is not None and images is not None and cameras.suffix == images.suffix:
        return cameras.suffix
    raise InputFileError(f"{folder}: no COLMAP model (cameras.bin + images.bin or cameras.txt + images.txt)")


def read_model(path: str | os.PathLike, ext: str | None = None) -> ColmapModel:
    """Read ``cameras``, ``images`` and (when present) ``points3D`` from a model folder.

    ``ext``: ``".bin"`` / ``".txt"``, default detected (``detect_model_format``).
    """
    folder = Path(path)
    ext = ext or detect_model_format(folder)
    if ext not in _READERS:
        raise UnsupportedFormatError(f"COLMAP model format must be '.bin' or '.txt', got {ext!r}")
    read_cams, read_imgs, read_pts = _READERS[ext]
    points_file = folder / f"points3D{ext}"
    return ColmapModel(
        cameras=read_cams(folder / f"cameras{ext}"),
        images=read_imgs(folder / f"images{ext}"),
        points3D=read_pts(points_file) if points_file.is_file() else {},
    )


def write_model(model: ColmapModel, path: str | os.PathLike, ext: str = ".bin") -> Path:
    """Write the three files of ``model`` into folder ``path`` (created); returns the folder."""
    if ext not in _WRITERS:
        raise UnsupportedFormatError(f"COLMAP model format must be '.bin' or '.txt', got {ext!r}")
    folder = Path(path)
    other = ".txt" if ext == ".bin" else ".bin"
    theirs = [f"{kind}{other}" for kind in MODEL_KINDS if (folder / f"{kind}{other}").is_file()]
    if theirs:  # two models in one folder: a reader would choose one of them (``model_file``)
        raise OutputPathError(
            f"{folder}: holds a {'binary' if other == '.bin' else 'text'} COLMAP model already "
            f"({', '.join(theirs)}); writing {ext} files beside it would leave two models that may differ: "
            "remove those files or choose another folder"
        )
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputFileError(
            f"{folder}: cannot create the COLMAP model folder: {exc.strerror or exc}"
        ) from exc
    write_cams, write_imgs, write_pts = _WRITERS[ext]
    write_cams(model.cameras, folder / f"cameras{ext}")
    write_imgs(model.images, folder / f"images{ext}")
    write_pts(model.points3D, folder / f"points3D{ext}")
    return folder

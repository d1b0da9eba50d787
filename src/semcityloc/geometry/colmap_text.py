"""COLMAP's text model format in one place: the camera-model table and the ``cameras.txt`` /
``images.txt`` line layouts, read and written.

- ``cameras.txt``: ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`` per line;
- ``images.txt``: two lines per image, ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` and then
  ``X Y POINT3D_ID`` triples of its 2D points (an empty line when it has none);
- ``#`` lines are comments, tokens are separated by spaces; floats are written with ``repr`` (shortest
  round-trip form), so a model written and read back equals the input bit for bit.

Two kinds of readers sit on it. ``datasets.colmap`` reads whole sparse models strictly
(``read_camera_lines`` / ``read_image_lines``: every line must be one, errors name the file and line).
``geometry.io`` finds poses and intrinsics in files of unknown form leniently (``is_image_line``,
``camera_values``: a line that is not one is some other form). Lives in ``geometry`` (the bottom layer) so
that both ``geometry.io`` and ``datasets.colmap`` can use it.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from semcityloc.errors import CameraError, InputFileError, SemCityLocError

# COLMAP camera models: name -> (model id, parameter names). Ids and orders as in colmap/sensor/models.h.
CAMERA_MODELS: dict[str, tuple[int, tuple[str, ...]]] = {
    "SIMPLE_PINHOLE": (0, ("f", "cx", "cy")),
    "PINHOLE": (1, ("fx", "fy", "cx", "cy")),
    "SIMPLE_RADIAL": (2, ("f", "cx", "cy", "k")),
    "RADIAL": (3, ("f", "cx", "cy", "k1", "k2")),
    "OPENCV": (4, ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")),
    "OPENCV_FISHEYE": (5, ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")),
    "FULL_OPENCV": (6, ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")),
    "FOV": (7, ("fx", "fy", "cx", "cy", "omega")),
    "SIMPLE_RADIAL_FISHEYE": (8, ("f", "cx", "cy", "k")),
    "RADIAL_FISHEYE": (9, ("f", "cx", "cy", "k1", "k2")),
    "THIN_PRISM_FISHEYE": (
        10,
        ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "sx1", "sy1"),
    ),
    "RAD_TAN_THIN_PRISM_FISHEYE": (
        11,
        ("fx", "fy", "cx", "cy", "k0", "k1", "k2", "k3", "k4", "k5", "p0", "p1", "s0", "s1", "s2", "s3"),
    ),
}
MODEL_BY_ID: dict[int, str] = {mid: name for name, (mid, _) in CAMERA_MODELS.items()}

CAMERA_LINE = "CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]"
IMAGE_LINE = "IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME"
# Token positions of an images.txt image line.
IMAGE_POSE = slice(1, 8)  # QW QX QY QZ TX TY TZ
IMAGE_CAMERA_ID = 8
IMAGE_NAME = 9


# ---------------------------------------------------------------------------------------------- tokens
def is_number(token: str) -> bool:
    """Whether a token parses as a float; how the readers tell an image line from a 2D-point line or a name
    from a number.
    """
    try:
        float(token)
    except ValueError:
        return False
    return True


def numbers(tokens: list[str], error: type[SemCityLocError]) -> list[float]:
    """The tokens as floats; ``error`` naming the first one that is not a number."""
    bad = [t for t in tokens if not is_number(t)]
    if bad:
        raise error(f"non-numeric value {bad[0]!r}")
    return [float(t) for t in tokens]


# ---------------------------------------------------------------------------------------------- lenient
def is_image_line(tokens: list[str]) -> bool:
    """Whether the tokens of a line of unknown form are an images.txt image line: ten tokens, the first
    nine numbers and the name not (2D-point lines and other pose forms are not)."""
    return len(tokens) == 10 and not is_number(tokens[IMAGE_NAME]) and all(is_number(t) for t in tokens[:9])


def camera_values(
    tokens: list[str], at: int, models: dict[str, tuple[str, ...]]
) -> tuple[str, int, int, dict[str, float]]:
    """``(MODEL, width, height, {param name: value})`` of a cameras.txt-like line whose model token is at
    ``at`` (0: no camera id, 1: ``CAMERA_ID MODEL ...``); ``models``: the accepted models (upper case)
    and their parameter names. Case-insensitive model names; ``CameraError`` for a wrong count."""
    model = tokens[at].upper()
    names = models[model]
    values = numbers(tokens[at + 1 :], CameraError)
    if len(values) != 2 + len(names):
        raise CameraError(
            f"{model} needs 'w h {' '.join(names)}' ({2 + len(names)} numbers), got {len(values)}"
        )
    w, h = values[0], values[1]
    if not (w.is_integer() and h.is_integer()):
        raise CameraError(f"{model} image size must be whole pixels, got {w:g} x {h:g}")
    return model, int(w), int(h), dict(zip(names, values[2:], strict=True))


# ---------------------------------------------------------------------------------------------- strict
def text_rows(path: Path) -> list[tuple[int, str]]:
    """(line number, line) of a text file, comments dropped, blank lines kept (images.txt needs them)."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise InputFileError(f"{path}: no such COLMAP file") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(f"{path}: cannot read COLMAP text file ({exc})") from exc
    return [
        (n, line.strip()) for n, line in enumerate(text.splitlines(), 1) if not line.lstrip().startswith("#")
    ]


def parse_tokens(path: Path, lineno: int, what: str, convert, tokens: list[str]) -> list:
    """``[convert(t) for t in tokens]``; ``InputFileError`` naming the file and line when one fails (for
    ``int``: also a value beyond int64, which ids are stored as)."""
    try:
        values = [convert(t) for t in tokens]
    except ValueError:
        raise InputFileError(
            f"{path}: line {lineno}: {what} are not numbers: {' '.join(tokens)[:80]!r}"
        ) from None
    if convert is int and any(not -(2**63) <= v < 2**63 for v in values):
        raise InputFileError(f"{path}: line {lineno}: {what} out of range: {' '.join(tokens)[:80]!r}")
    return values


def read_camera_lines(path: str | os.PathLike) -> Iterator[tuple[int, int, str, int, int, list[float]]]:
    """``(line number, camera id, model, width, height, params)`` of every camera line of a cameras.txt
    (one at a time: a caller's check of line n runs before line n + 1 is parsed)."""
    path = Path(path)
    for lineno, line in text_rows(path):
        if not line:
            continue
        tok = line.split()
        if len(tok) < 4:
            raise InputFileError(f"{path}: line {lineno}: expected '{CAMERA_LINE}'")
        cam_id, width, height = parse_tokens(
            path, lineno, "camera id and size", int, [tok[0], tok[2], tok[3]]
        )
        params = parse_tokens(path, lineno, "camera params", float, tok[4:])
        yield lineno, cam_id, tok[1], width, height, params


def read_image_lines(
    path: str | os.PathLike,
) -> Iterator[tuple[int, int, list[float], list[float], int, str, np.ndarray, list[int]]]:
    """``(line number, image id, qvec, tvec, camera id, name, xys (N, 2), point3D ids (N,))`` of every
    image of an images.txt (its image line and the 2D-point line after it; names may hold spaces)."""
    path = Path(path)
    rows = text_rows(path)
    i = 0
    while i < len(rows):
        lineno, line = rows[i]
        if not line:
            i += 1
            continue
        tok = line.split(maxsplit=9)
        if len(tok) < 10:
            raise InputFileError(f"{path}: line {lineno}: expected '{IMAGE_LINE}'")
        image_id, camera_id = parse_tokens(
            path, lineno, "image / camera ids", int, [tok[0], tok[IMAGE_CAMERA_ID]]
        )
        values = parse_tokens(path, lineno, "pose values", float, tok[IMAGE_POSE])
        points = rows[i + 1][1].split() if i + 1 < len(rows) else []
        if len(points) % 3:
            raise InputFileError(f"{path}: line {rows[i + 1][0]}: 2D points must be 'X Y POINT3D_ID' triples")
        points_line = rows[i + 1][0] if i + 1 < len(rows) else lineno + 1
        xy = parse_tokens(path, points_line, "2D points", float, points[0::3] + points[1::3])
        ids = parse_tokens(path, points_line, "point3D ids", int, points[2::3])
        n = len(ids)
        xys = np.column_stack([xy[:n], xy[n:]]) if n else np.zeros((0, 2))
        yield lineno, image_id, values[:4], values[4:], camera_id, tok[IMAGE_NAME], xys, ids
        i += 2


# ---------------------------------------------------------------------------------------------- writing
def format_float(value: float) -> str:
    """A float as COLMAP text: ``repr`` (shortest form that reads back to the same double)."""
    return repr(float(value))


def camera_line(camera_id: int, model: str, width: int, height: int, params) -> str:
    """One ``cameras.txt`` line (``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]``), parameters in round-trip float
    form so that a model written and read back is unchanged.
    """
    return " ".join([str(camera_id), model, str(width), str(height), *map(format_float, params)])


def image_lines(
    image_id: int, qvec, tvec, camera_id: int, name: str, xys: np.ndarray, point3D_ids: np.ndarray
) -> tuple[str, str]:
    """The image line and the 2D-point line of one image; ``InputFileError`` for a name the text format
    cannot hold (empty, a line break, white space at its ends)."""
    if not name or name != name.strip() or "\n" in name or "\r" in name:
        raise InputFileError(
            f"image name {name!r} cannot be written to COLMAP text (empty, line "
            "break, or white space at its ends)"
        )
    head = " ".join([str(image_id), *map(format_float, qvec), *map(format_float, tvec), str(camera_id), name])
    points = " ".join(
        f"{format_float(x)} {format_float(y)} {int(p)}" for (x, y), p in zip(xys, point3D_ids, strict=True)
    )
    return head, points

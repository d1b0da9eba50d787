"""What every reader of a pose or intrinsics spec shares: a ``spec`` is a path to a file or the text
itself (inline JSON, a COLMAP line, comma separated numbers); ``load_spec`` tells which and reads it (a
size limit, a BOM, a typed error naming the file or the inline text), ``spec_lines`` splits its lines into
tokens, ``pick_entry`` chooses the entry for an image name, ``labelled`` prefixes a parser's typed error
with the input's label, and ``json_matrix`` / ``json_number`` / ``json_vector`` check a JSON value.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from semcityloc.errors import CameraError, InputFileError, PoseError, SemCityLocError, ShapeError
from semcityloc.geometry.colmap_text import is_number

# Pose and intrinsics files are a few lines long; refuse to slurp e.g. an image passed by mistake.
MAX_SPEC_FILE_BYTES = 10_000_000


_SPLIT = re.compile(r"[,\s]+")


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


def load_spec(spec: str | os.PathLike, error: type[SemCityLocError], what: str) -> tuple[str, str]:
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


def parse_json(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputFileError(f"invalid JSON ({exc.msg} at line {exc.lineno} column {exc.colno})") from exc


def spec_lines(text: str) -> list[list[str]]:
    """Token lists of the non-empty, non-comment lines; tokens split on whitespace and commas."""
    out = []
    for line in text.splitlines():
        line = line.strip()
        tokens = [t for t in _SPLIT.split(line) if t] if not line.startswith("#") else []
        if tokens:  # a line of separators alone (",") holds nothing
            out.append(tokens)
    return out


def pick_entry(
    entries: dict[str, Any],
    name: str | None,
    error: type[SemCityLocError],
    what: str,
    choose: str = "pass the image name to choose one",
) -> Any:
    """The entry called ``name`` (exact, then file name, then stem); the only one when name is None.
    ``choose``: how the message tells the caller to name one (``parameter``'s words: a flag on the CLI)."""
    if name is None:
        if len(entries) == 1:
            return next(iter(entries.values()))
        some = ", ".join(list(entries)[:3])
        raise error(f"{len(entries)} {what}s ({some}, ...): {choose}")
    for key in (lambda n: n, lambda n: Path(n).name, lambda n: Path(n).stem):
        hits = [k for k in entries if key(k) == key(name)]
        if len(hits) == 1:
            return entries[hits[0]]
        if len(hits) > 1:
            raise error(f"image name {name!r} is ambiguous: it matches {', '.join(hits[:3])}")
    raise error(f"no {what} for image {name!r} (have {len(entries)}: {', '.join(list(entries)[:3])}, ...)")


def json_matrix(value: Any, shapes: tuple[tuple[int, int], ...], key: str) -> np.ndarray:
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


RIGID = ((4, 4), (3, 4))


def json_number(obj: dict, key: str, error: type[SemCityLocError]) -> float:
    value = obj[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise error(f"{key!r} must be a number, got {value!r}")
    try:
        return float(value)
    except OverflowError:  # an integer beyond float64 (JSON integers are unbounded)
        raise error(f"{key!r} is too large: {str(value)[:40]}...") from None


def json_vector(obj: dict, key: str, n: int, error: type[SemCityLocError]) -> list[float]:
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


def labelled(label: str, fn, *args):
    """Run a parser; prefix its typed error with the input's label."""
    try:
        return fn(*args)
    except InputFileError as exc:
        if str(exc).startswith(label):
            raise
        raise InputFileError(f"{label}: {exc}") from exc
    except (PoseError, CameraError, ShapeError) as exc:
        raise type(exc)(f"{label}: {exc}") from exc

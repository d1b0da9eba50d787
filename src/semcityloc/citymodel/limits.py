"""Size limits of city model files: what the readers refuse before reading, and how to raise them.

Why: a hostile or mistaken file (a 1 GB tile, a CityJSON with 10^7 vertices, a gzip bomb) must get a clear
answer, not exhaust the machine's memory minutes later. CityGML is streamed (memory grows with the mesh
kept, not with the file), so its limit is generous; CityJSON is one JSON document parsed whole (Python
objects take about 10x the file) and OBJ is read as one text, so theirs are lower. Each limit is in MB of
the file (a gzip CityJSON: decompressed, stopped at the limit; a gzip CityGML is streamed, its file size
counts) and set by an environment variable (docs/reliability.md has the measured peak memory per size):

- ``SEMCITYLOC_MAX_CITYGML_MB`` (default 4096)
- ``SEMCITYLOC_MAX_CITYJSON_MB`` (default 128)
- ``SEMCITYLOC_MAX_OBJ_MB`` (default 1024)
"""

from __future__ import annotations

import math
import os
import zlib
from pathlib import Path

from semcityloc.errors import InputFileError, ParameterError

DEFAULT_LIMITS_MB = {"CityGML": 4096, "CityJSON": 128, "OBJ": 1024}
MB = 1024 * 1024


def env_name(kind: str) -> str:
    """The environment variable that raises the size limit of ``kind`` (``SEMCITYLOC_MAX_CITYGML_MB``), named
    in every refusal.
    """
    return f"SEMCITYLOC_MAX_{kind.upper()}_MB"


def env_mb(name: str, default: float) -> float:
    """A size in MB from the environment variable ``name`` (unset or empty: ``default``);
    ``ParameterError`` naming the variable when it is not a positive number."""
    text = os.environ.get(name, "").strip()
    if not text:
        return float(default)
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not (math.isfinite(value) and value > 0):
        raise ParameterError(f"{name}={text!r}: must be a positive number of MB")
    return value


def limit_bytes(kind: str) -> int:
    """The size limit of ``kind`` files in bytes (its environment variable, else the default)."""
    return int(env_mb(env_name(kind), DEFAULT_LIMITS_MB[kind]) * MB)


def too_large(path: Path, kind: str, size: int) -> InputFileError:
    """The error for a file over its size limit, naming the size, the limit and the variable with a value that
    would admit the file, so the user can raise it if the machine has the memory.
    """
    limit = limit_bytes(kind)
    return InputFileError(
        f"{path}: {size / MB:.0f} MB of {kind} is over the size limit of {limit / MB:.0f} MB; "
        f"if this machine has the memory for it, raise the limit: {env_name(kind)}={2 * size // MB + 1}"
    )


def check_file_size(path: Path, kind: str) -> None:
    """``InputFileError`` naming the limit and its variable when ``path`` is larger than ``kind``'s limit
    (a missing file is left to the reader to report)."""
    try:
        size = path.stat().st_size
    except OSError:
        return
    if size > limit_bytes(kind):
        raise too_large(path, kind, size)


def gunzip_bounded(path: Path, data: bytes, kind: str) -> bytes:
    """``data`` (a gzip stream) decompressed, refused once it grows past ``kind``'s limit (a gzip bomb
    stops there, never allocated in full). Raises ``zlib.error`` / ``EOFError`` on a broken stream."""
    limit = limit_bytes(kind)
    inflater = zlib.decompressobj(wbits=31)
    out = inflater.decompress(data, limit + 1)
    if len(out) > limit:
        raise too_large(path, kind, len(out) + len(inflater.unconsumed_tail) * 2)
    if not inflater.eof:
        raise EOFError("compressed file ended before the end-of-stream marker was reached")
    return out

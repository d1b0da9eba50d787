"""Writing files so that a crash, a kill or a full disk never leaves one half-written, and JSON that every
reader takes.

Why here, below everything that writes: a run's rows and records (``benchmark.runfiles``), the data sets'
exports (``datasets.geojson``, COLMAP, LoD-Loc), pose files and anything else a user keeps must either be
whole or absent, and a failed write must not leave its temporary file behind to fill the disk further.
JSON is written strict (``json_safe``: NaN and infinities as ``null``): Python reads ``NaN`` tokens, jq,
JavaScript and most other readers refuse the whole file.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np


def write_atomic(path: Path, data: bytes | str) -> None:
    """Write ``path`` through a temporary file in the same folder and ``os.replace`` (never half-written).
    An ``OSError`` (a full disk) names ``path`` and leaves no temporary file."""
    if isinstance(data, str):
        data = data.encode("utf-8")
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with removed_on_error(tmp):  # a failed write leaves no temporary file (it would keep a disk full)
            with open(tmp, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
    except OSError as exc:  # the same kind of error, naming the file meant, not the temporary one
        if exc.filename == str(path):
            raise
        raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from exc


@contextlib.contextmanager
def removed_on_error(tmp: Path) -> Iterator[None]:
    """Remove the temporary file ``tmp`` when the block fails (a full disk stays no fuller), then re-raise."""
    try:
        yield
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise


def json_default(value: Any) -> Any:
    """``json.dumps(..., default=json_default)``: numpy arrays and scalars, paths -> plain JSON values."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")


def json_safe(value: Any) -> Any:
    """Non-finite floats -> None (strict JSON), recursively."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_json_atomic(path: Path, value: Any) -> None:
    """``value`` as strict, indented JSON (numpy values as plain ones, non-finite floats -> null),
    atomically (``write_atomic``)."""
    plain = json.loads(json.dumps(value, default=json_default))
    write_atomic(path, json.dumps(json_safe(plain), indent=2, allow_nan=False) + "\n")

"""Writing files so that a crash, a kill or a full disk never leaves one half-written.

Why here, below everything that writes: a run's rows and records (``benchmark.runfiles``), the data sets'
exports (``datasets.geojson``) and anything else a user keeps must either be whole or absent, and a failed
write must not leave its temporary file behind to fill the disk further.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path


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

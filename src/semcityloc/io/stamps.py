"""Has a file changed? A file's stamp (which file, and when and how it last changed) for caches in one
process, its SHA-256 read once while that stamp holds, and its fingerprint (size and SHA-256) for what
outlives the process.

Why its own module, below everything: the parsed city's cache key, a photo run's resolved inputs (cached
per process, ``benchmark.photo_focal.calibrated_inputs``) and a run's record of what each photo was made
from (``benchmark.photo_source``) must all notice a file that changed, without reading every file again.

- ``file_stamp``: device and inode (which file), size, modification and status-change times in ns. The
  status-change time (ctime) is set by the kernel on every write, rename or chmod and cannot be set back by
  a program, so ``cp -p`` (which keeps the source's modification time), ``touch -d`` or an editor that
  restores the modification time all change the stamp, where size and modification time alone would not.
  File times are kept to the kernel's clock tick (milliseconds; 2 s on FAT), so a second write within the
  same tick leaves them as they were: a stamp of a file that changed less than ``RACY_S`` before it was
  taken carries the file's SHA-256 too (git's "racily clean" rule), and ``file_sha256`` keeps no hash of
  such a file.
- ``file_fingerprint``: size and SHA-256 of the bytes, for records kept across processes and machines: a
  stamp changes when a file is copied or checked out with the same bytes (another inode, another ctime),
  and ``cp -p`` or ``git checkout`` can give other bytes the same size and modification time.
- ``paths_stamp``: the stamps of the files a list of paths names (a folder: the entries directly in it), a
  cache key that changes when any of them is added, removed or changed.
"""

from __future__ import annotations

import hashlib
import os
import stat
import time
from collections.abc import Iterable
from pathlib import Path

RACY_S = 2.0  # a file changed less than this before its stamp: its stamp holds its hash too (docstring)

# (resolved path, file_stamp) -> the file's hex SHA-256, so that the several users of a file's identity in
# one process (the parsed-model cache, run.json, the focal cache, a photo's fingerprint) read it once.
_SHA256_SEEN: dict[tuple, str] = {}


def _read_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _stat_stamp(st: os.stat_result) -> tuple[int, int, int, int, int]:
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns


def _racy(st: os.stat_result, now_ns: int) -> bool:
    """Did the file change less than ``RACY_S`` before ``now_ns`` (or after it: a clock behind the file's)?"""
    return now_ns - max(st.st_mtime_ns, st.st_ctime_ns) < RACY_S * 1e9


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes, read in 1 MiB chunks (cache keys, run provenance, fingerprints); a
    file hashed before in this process whose stamp is the same (``file_stamp``: same inode, size,
    modification and status-change times, not changed within ``RACY_S`` of its hashing) is not read again."""
    now = time.time_ns()  # before the stat: a change after it is a later ctime
    st = os.stat(path)
    key = (str(Path(path).resolve()), *_stat_stamp(st))
    if key in _SHA256_SEEN:
        return _SHA256_SEEN[key]
    digest = _read_sha256(path)
    if not _racy(st, now):
        _SHA256_SEEN[key] = digest
    return digest


def file_stamp(path: str | Path) -> tuple:
    """The stamp of ``path`` (module docstring): (device, inode, size, mtime ns, ctime ns), and the file's
    SHA-256 when it changed within ``RACY_S``; ``OSError`` when it cannot be stat'ed (or read when racy)."""
    now = time.time_ns()
    st = os.stat(path)
    stamp = _stat_stamp(st)
    if stat.S_ISREG(st.st_mode) and _racy(st, now):
        return (*stamp, _read_sha256(path))
    return stamp


def file_fingerprint(path: str | Path) -> dict | None:
    """``{"file": name, "bytes": size, "sha256": hex}`` of a file's bytes (module docstring); None when
    ``path`` is no regular file that reads (missing, a folder, no permission)."""
    try:
        if not Path(path).is_file():
            return None
        return {"file": Path(path).name, "bytes": os.stat(path).st_size, "sha256": file_sha256(path)}
    except OSError:
        return None


def _stamp_or_none(path: str | Path) -> tuple | None:
    try:
        return file_stamp(path)
    except OSError:
        return None


def paths_stamp(paths: Iterable[str | Path | None]) -> tuple:
    """The stamps of ``paths`` (None entries left out): a file's ``file_stamp``; a folder's, the sorted
    names of its entries with each one's (a sub-folder's own stat alone); a missing path's None."""
    stamps = []
    for path in paths:
        if path is None:
            continue
        path = Path(path).expanduser()
        if path.is_dir():
            try:
                names = sorted(os.listdir(path))
            except OSError:
                stamps.append((str(path), None))
                continue
            stamps.append((str(path), tuple((n, _stamp_or_none(path / n)) for n in names)))
        else:
            stamps.append((str(path), _stamp_or_none(path)))
    return tuple(stamps)

"""A run folder on disk: its file names, atomic writes, JSON normalisation, ``run.json`` and the resume
check, and the progress bar.

Why its own module: every benchmark run (simulated or over a data set) keeps its output the same way, so
a killed run resumes and a run with other arguments is refused; none of it depends on what is localized.

Folder ``DIR`` of a run:

- ``run.json``: what decides the numbers (the spec's ``run_config``), written first. A later call with
  other arguments is refused with ``ResumeMismatchError`` naming the differing keys, unless ``overwrite``
  (which deletes the old results).
- ``results.csv``: one row per finished query (``benchmark.results``).
- ``details/qNNNN.npz``: the report's figures for the first ``keep_details`` queries.
- ``summary.json``: the metrics, written when every query is done.
- ``estimates/<name>.json``: the localized poses in the data set's world frame (data-set runs only);
  ``estimates_colmap/``: all of them as a COLMAP text model.
- a photo run (``semcityloc run``, ``benchmark.photo_source``): ``poses/<stem>.json`` per photo,
  ``overlays/<stem>.png``, and when every photo is done ``colmap/``, ``geotags.csv``, ``geo.txt``,
  ``cameras.geojson``.

A run started again with ``overwrite`` deletes all of these (``RUN_OUTPUTS``) before it starts.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Any, TextIO

from semcityloc.errors import ResumeMismatchError
from semcityloc.geometry.io import json_default

RUN_FILE = "run.json"
RESULTS_FILE = "results.csv"
SUMMARY_FILE = "summary.json"
DETAILS_DIR = "details"
ESTIMATES_DIR = "estimates"
ESTIMATES_COLMAP_DIR = "estimates_colmap"
POSES_DIR, OVERLAYS_DIR, COLMAP_DIR = "poses", "overlays", "colmap"
GEOTAGS_FILE, ODM_GEO_FILE, GEOJSON_FILE = "geotags.csv", "geo.txt", "cameras.geojson"
# Everything a run writes besides run.json (removed when a run with other arguments overwrites the folder).
RUN_OUTPUTS = (
    RESULTS_FILE,
    SUMMARY_FILE,
    DETAILS_DIR,
    ESTIMATES_DIR,
    ESTIMATES_COLMAP_DIR,
    POSES_DIR,
    OVERLAYS_DIR,
    COLMAP_DIR,
    GEOTAGS_FILE,
    ODM_GEO_FILE,
    GEOJSON_FILE,
)

# Keys of run.json that do not change the numbers (not compared on resume).
NOT_IDENTITY = ("city", "keep_details", "semcityloc_version")  # "city": as typed; city_path counts


def plain(value: Any) -> Any:
    """JSON-normalised copy (tuples -> lists, numpy scalars -> Python) for storing and comparing."""
    return json.loads(json.dumps(value, default=json_default))


def json_safe(value: Any) -> Any:
    """Non-finite floats -> None (strict JSON), recursively."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_all(fd: int, data: bytes) -> None:
    """``os.write`` until every byte is written."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


def write_atomic(path: Path, data: bytes | str) -> None:
    """Write ``path`` through a temporary file in the same folder and ``os.replace`` (never half-written)."""
    if isinstance(data, str):
        data = data.encode("utf-8")
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def write_json_atomic(path: Path, value: Any) -> None:
    """``value`` as strict, indented JSON (non-finite floats -> null), atomically."""
    write_atomic(path, json.dumps(json_safe(value), indent=2) + "\n")


def prepare_output(out_dir: Path, config: dict, overwrite: bool = False) -> None:
    """Create ``out_dir`` and its ``run.json``; refuse a folder holding a run with other arguments."""
    out_dir.mkdir(parents=True, exist_ok=True)
    run_file, results = out_dir / RUN_FILE, out_dir / RESULTS_FILE
    mismatch = None
    if run_file.exists():
        try:
            old = json.loads(run_file.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            old = None
            mismatch = f"its {RUN_FILE} is unreadable ({exc})"
        if old is not None:
            differ = [
                f"{k}: {old.get(k)!r} -> {config.get(k)!r}"
                for k in sorted(set(old) | set(config))
                if k not in NOT_IDENTITY and old.get(k) != config.get(k)
            ]
            if differ:
                mismatch = (
                    "arguments differ (" + "; ".join(differ[:4]) + ("; ..." if len(differ) > 4 else "") + ")"
                )
    elif results.exists():
        mismatch = f"it has a {RESULTS_FILE} but no {RUN_FILE}"
    if mismatch and not overwrite:
        raise ResumeMismatchError(
            f"{out_dir} holds another benchmark run: {mismatch}; pass --overwrite or choose another --out"
        )
    if mismatch:
        for name in RUN_OUTPUTS:
            path = out_dir / name
            if path.is_dir():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)
    if mismatch or not run_file.exists():
        write_atomic(run_file, json.dumps(config, indent=2) + "\n")


class Progress:
    """One-line ``\\r`` progress bar with ETA on a TTY; elsewhere silent except a final line."""

    def __init__(self, total: int, done: int = 0, stream: TextIO | None = None, label: str = "benchmark"):
        self.total, self.done, self.start_done = total, done, done
        self.stream = stream if stream is not None else sys.stderr
        self.label = label
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.t0 = time.monotonic()
        self._last = 0.0
        if self.tty:
            self._draw()

    def update(self, n: int = 1) -> None:
        self.done += n
        now = time.monotonic()
        if self.tty and (now - self._last > 0.2 or self.done >= self.total):
            self._draw()
            self._last = now

    def _draw(self) -> None:
        width = 30
        frac = self.done / self.total if self.total else 1.0
        bar = "#" * int(frac * width)
        new = self.done - self.start_done
        elapsed = time.monotonic() - self.t0
        eta = _duration(elapsed / new * (self.total - self.done)) if new else "?"
        self.stream.write(f"\r{self.label} [{bar:<{width}}] {self.done}/{self.total} ETA {eta}   ")
        self.stream.flush()

    def close(self) -> None:
        new = self.done - self.start_done
        elapsed = time.monotonic() - self.t0
        rate = f", {elapsed / new:.2f} s/query" if new else ""
        if self.tty:
            self._draw()
            self.stream.write("\n")
        self.stream.write(
            f"{self.label}: {self.done}/{self.total} queries done ({new} new in {_duration(elapsed)}{rate})\n"
        )
        self.stream.flush()


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else f"{m}m{s:02d}s" if m else f"{s}s"

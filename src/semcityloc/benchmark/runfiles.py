"""A run folder on disk: its file names, atomic writes, JSON normalisation, ``run.json`` and the resume
check, and the progress bar.

Why its own module: every benchmark run (simulated or over a data set) keeps its output the same way, so
a killed run resumes and a run with other arguments is refused; none of it depends on what is localized.

Folder ``DIR`` of a run:

- ``run.json``: what decides the numbers (the spec's ``run_config``), written first. A later call with
  other arguments is refused with ``ResumeMismatchError`` naming the differing keys with both values
  (``differing_settings``), unless ``overwrite`` (which deletes the old results, whatever the arguments:
  it always starts the run again). It also keeps
  ``code``, the package source that started the run: a resume by changed code is not refused but told
  that its results mix (``code_change_note``). A run that fails (or is interrupted) before the folder
  holds its first row - a backend without its weights - leaves nothing of itself (``run_entries``,
  ``remove_entries``, ``benchmark.run``): the corrected command is not "another run".
- ``results.csv``: one row per finished query (``benchmark.results``).
- ``details/qNNNN.npz``: the report's figures for the first ``keep_details`` queries (a resume makes a
  deleted one again: ``results.missing_details``).
- ``summary.json``: the metrics, written when every query is done.
- ``estimates/<name>.json``: the localized poses in the data set's world frame (data-set runs only);
  ``estimates_colmap/``: all of them as a COLMAP text model.
- a photo run (``semcityloc run``, ``benchmark.photo_spec``): ``poses/<stem>.json`` per photo,
  ``overlays/<stem>.png``, and when every photo is done ``colmap/``, ``geotags.csv``, ``geo.txt``,
  ``cameras.geojson``.
- ``report/``: not the run's own, but ``semcityloc report RUN``'s default output, a report of these rows.

A run started again with ``overwrite`` deletes all of these (``RUN_OUTPUTS``) before it starts. A write that
fails mid-run (a full disk) is ``write_error``: one line naming the file; it leaves no temporary file, and a
resumed run removes those a killed one left (``remove_stale_temps``). A ``results.csv`` that is there but
cannot be read (no permission, a folder, no UTF-8 text) is ``read_error``: "cannot read", the file and
the fix; so is such a ``run.json`` (not "another run"), which ``overwrite`` replaces unread.

- ``run.lock``: held while a run writes the folder (``run_lock``): an exclusive ``flock`` on it, and the
  pid, host and start time of its holder inside. A second run on the same folder is refused
  (``RunLockedError`` naming that pid); the kernel drops the lock when its holder dies, so the file a
  killed run leaves behind is stale and the next run takes it over.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import re
import shutil
import socket
import sys
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, TextIO

from semcityloc.errors import (
    OutputPathError,
    ResumeMismatchError,
    RunFileError,
    RunLockedError,
    counted,
    parameter,
)
from semcityloc.io.files import json_default, write_atomic

RUN_FILE = "run.json"
LOCK_FILE = "run.lock"
RESULTS_FILE = "results.csv"
SUMMARY_FILE = "summary.json"
DETAILS_DIR = "details"
ESTIMATES_DIR = "estimates"
ESTIMATES_COLMAP_DIR = "estimates_colmap"
POSES_DIR, OVERLAYS_DIR, COLMAP_DIR = "poses", "overlays", "colmap"
GEOTAGS_FILE, ODM_GEO_FILE, GEOJSON_FILE = "geotags.csv", "geo.txt", "cameras.geojson"
# ``semcityloc report RUN``'s default output (inside the run): a report of the results --overwrite deletes
REPORT_DIR = "report"
# Everything a run writes besides run.json (removed by ``overwrite``).
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
    REPORT_DIR,
)

# The key of run.json naming the package source that started the run (``code_fingerprint``).
CODE_KEY = "code"
# Keys of run.json that do not change the numbers (not compared on resume). A run resumed by changed code
# is not refused (a fix of a typo would cost every finished query) but told (``code_change_note``).
# "city": as typed (city_path counts); "searched_map": follows from "method" and "localizer", and runs
# started before it was recorded resume.
NOT_IDENTITY = ("city", "keep_details", "semcityloc_version", CODE_KEY, "searched_map")
# Keys of a photo (or data-set) run's run.json that its folder decides, not its arguments: the photos to
# run and those skipped (a simulated run's "queries" is its --queries). When only they differ, the refusal
# says so: the same command on a changed folder, or a newer version that skips other photos (since stop 48
# a photo of the truth whose mask is missing or of another aspect is a miss, no longer skipped).
SKIPPED_KEY = "skipped_photos"
PHOTO_SET_KEYS = ("queries", "query_names", SKIPPED_KEY)
PHOTOS_DIFFER = (
    "the photos to run differ (photos added, removed or repaired since, or this version skips other photos "
    "than the one that started the run did: a photo of the truth whose mask is missing or does not fit is "
    "now a miss, not skipped): "
)
# Keys of run.json holding a whole configuration (every field of a dataclass, defaults too). A field that
# only one side holds was added or removed by the code, not by the arguments: a resume across it is told
# like any code change (``code_change_note``), not refused.
FULL_CONFIGS = ("localizer", "query_config", "seg_preset")
# The fingerprints of a photo run's perception weights (``PhotoSpec.run_config``): a head retrained at the
# same path differs here, and the run is refused as one of other arguments, naming the file that changed.
WEIGHTS_KEY = "perception_weights"
# Keys recorded since a later version: a stored run.json without one is not compared for it (a run made
# before stop 56 kept no weight fingerprints and resumes as it did).
ADDED_KEYS = (WEIGHTS_KEY,)


def plain(value: Any) -> Any:
    """JSON-normalised copy (tuples -> lists, numpy scalars -> Python) for storing and comparing."""
    return json.loads(json.dumps(value, default=json_default))


def write_all(fd: int, data: bytes) -> None:
    """``os.write`` until every byte is written."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


# What the user can do about an output that cannot be written, by errno.
_WRITE_FIX = {
    errno.ENOSPC: "free space",
    errno.EDQUOT: "free space",
    errno.EROFS: "make it writable",
    errno.EACCES: "make it writable",
    errno.EPERM: "make it writable",
}


def write_error(path: Path | str, exc: OSError) -> OutputPathError:
    """The one-line error for an output that could not be written mid-run: the file, the cause and what to
    do ("cannot write OUT/results.csv: No space left on device; free space and run the same command
    again"). The run loop adds how many finished rows are kept."""
    fix = _WRITE_FIX.get(exc.errno, "fix it")
    return OutputPathError(f"cannot write {path}: {_cause(exc)}; {fix} and run the same command again")


# What the user can do about a run's file that is there but cannot be read, by errno.
_READ_FIX = {
    errno.EACCES: "make it readable",
    errno.EPERM: "make it readable",
    errno.EISDIR: "move that folder out of the run's folder",
}
_START_AGAIN = f"pass {parameter('overwrite')} to start the run again"


def read_error(
    path: Path | str, exc: OSError | UnicodeDecodeError, what: str = "results file"
) -> RunFileError:
    """The one-line error for a file of a run (``results.csv``, ``run.json``: ``what``) that is there but
    cannot be read: the file, the cause and what to do ("cannot read OUT/results.csv: Permission denied;
    make it readable and run the same command again, or pass --overwrite to start the run again"). Not
    ``write_error``: its "cannot write ... make it writable" would send the user to the wrong fix."""
    if isinstance(exc, UnicodeDecodeError):
        byte = exc.object[exc.start : exc.start + 1].hex()
        return RunFileError(
            f"cannot read {path}: byte 0x{byte} at offset {exc.start} is not UTF-8 text, so it is no {what} "
            f"of this runner; {_START_AGAIN}, or choose another {parameter('out_dir')}"
        )
    fix = _READ_FIX.get(exc.errno, "fix it")
    again = f"run the same command again, or {_START_AGAIN}"
    return RunFileError(f"cannot read {path}: {_cause(exc)}; {fix} and {again}")


def _cause(exc: OSError) -> str:
    """An ``OSError``'s cause in words ("No space left on device")."""
    return exc.strerror or str(exc) or type(exc).__name__


def read_run_file(path: Path) -> bytes:
    """The bytes of a run's file, ``b""`` when there is none; ``read_error`` when it is there but cannot be
    read (no permission, a folder of that name)."""
    if not os.path.lexists(path):
        return b""
    try:
        return path.read_bytes()
    except OSError as exc:
        raise read_error(path, exc) from exc


@contextlib.contextmanager
def writing(path: Path | str | None = None, folder: Path | str = "the run's folder") -> Iterator[None]:
    """Turn an ``OSError`` of the block (writing ``path``; None: the file the error names, else ``folder``)
    into ``write_error``."""
    try:
        yield
    except OSError as exc:
        raise write_error(path if path is not None else exc.filename or folder, exc) from exc


# A temporary file of an atomic write: ``.NAME.PID.tmp``, ``.STEM.PID.tmp.npz``, ``.ID.tmp.json``.
# The temporary files this package's atomic writes make: ``.NAME.PID.tmp``, ``.qNNNN.PID.tmp.npz`` (with the
# writer's pid), and the two without one (``.qNNNN.tmp.json`` estimates, ``.cameras.geojson.tmp``). Nothing
# else is touched: an --out folder may hold the user's own hidden files.
_TMP_NAME = re.compile(r"^\.(?:.+\.(\d+)\.tmp(?:\.\w+)?|q\d+\.tmp\.json|cameras\.geojson\.tmp)$")


def kept_note(done: int, total: int, out: Path | str) -> str:
    """What an interrupted command that resumes says it keeps: ``done`` of ``total`` finished in ``out`` and
    that the same command goes on (``run``, ``benchmark``, ``dataset benchmark``, ``label``)."""
    return f"semcityloc: note: {done}/{total} done and kept in {out}; the same command again goes on"


def remove_stale_temps(out_dir: Path, folders: tuple[str, ...] = ("",)) -> int:
    """Remove the temporary files of atomic writes in ``out_dir`` (and its ``folders``) that no live
    process owns: left by a run killed, or stopped by a full disk, between writing and renaming one. Only
    called by the holder of the folder's lock (no other run writes it); a file named by the pid of a live
    process is kept. Returns how many were removed."""
    removed = 0
    for name in folders:
        folder = out_dir / name if name else out_dir
        try:
            entries = list(os.scandir(folder))
        except OSError:
            continue
        for entry in entries:
            match = _TMP_NAME.match(entry.name)
            if not match or not entry.is_file(follow_symlinks=False):
                continue
            if match.group(1) and _alive(int(match.group(1))):
                continue
            with contextlib.suppress(OSError):
                os.unlink(entry.path)
                removed += 1
    return removed


def _alive(pid: int) -> bool:
    """Whether a process ``pid`` exists (ours or another user's)."""
    if pid == os.getpid():
        return False  # this process writes nothing while it cleans up
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):
        return False
    except PermissionError:
        return True
    return True


@contextlib.contextmanager
def run_lock(out_dir: Path) -> Iterator[None]:
    """Hold ``out_dir/run.lock`` while the block runs; ``RunLockedError`` when another live run holds it.

    A lock file left by a run that was killed is not held (the kernel released its ``flock``): it is taken
    over, with a note on stderr naming the old pid.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / LOCK_FILE
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = _lock_holder(fd)
            os.close(fd)
            raise RunLockedError(
                f"{out_dir} is in use by another run ({holder}); wait for it to finish or choose another "
                f"{parameter('out_dir')}"
            ) from None
        try:  # the file may have been removed by its last holder between our open and flock: retry
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    stale = _lock_holder(fd, default="")
    if stale:
        print(f"{out_dir}: taking over the stale lock of a run that ended ({stale})", file=sys.stderr)
    info = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.strftime("%Y-%m-%dT%H:%M:%S")}
    os.ftruncate(fd, 0)
    os.pwrite(fd, (json.dumps(info) + "\n").encode(), 0)
    try:
        yield
    finally:
        with contextlib.suppress(OSError):
            path.unlink()
        os.close(fd)  # releases the flock


def _lock_holder(fd: int, default: str = "pid unknown") -> str:
    """ "pid N on HOST since T" from an open lock file (``default`` when it is empty or unreadable)."""
    try:
        info = json.loads(os.pread(fd, 4096, 0) or b"null")
        return f"pid {int(info['pid'])} on {info['host']} since {info['started']}"
    except (OSError, ValueError, TypeError, KeyError):
        return default


_SHORT_VALUE = 40  # a differing value longer than this (as repr) is shown cut to it, "..." at the end


def _shortened(value: object) -> str:
    """``repr(value)``, cut to ``_SHORT_VALUE`` characters ending in ``...`` when longer."""
    text = repr(value)
    return text if len(text) <= _SHORT_VALUE else text[: _SHORT_VALUE - 3] + "..."


def differing_settings(old: dict, new: dict, prefix: str = "", full: bool = False) -> list[str]:
    """The keys (dotted into nested objects) whose values differ, each with ``stored -> now`` (a long value
    cut short, ``_shortened``): what a refused resume names (never whole configurations; stop 55: a long
    value's key was named without either value). Inside ``FULL_CONFIGS`` (``full``), a key only one side
    has is the code's difference, not named."""
    out = []
    for k in sorted(set(old) | set(new), key=str):
        if not prefix and k in NOT_IDENTITY:
            continue
        if full and (k in old) != (k in new):
            continue
        a, b = old.get(k), new.get(k)
        if a == b:
            continue
        if isinstance(a, dict) and isinstance(b, dict):
            out += differing_settings(a, b, f"{prefix}{k}.", full or (not prefix and k in FULL_CONFIGS))
            continue
        out.append(f"{prefix}{k}: {_shortened(a)} -> {_shortened(b)}")
    return out


def prepare_output(out_dir: Path, config: dict, overwrite: bool = False) -> dict | None:
    """Create ``out_dir`` and its ``run.json``; refuse a folder holding a run with other arguments.
    ``overwrite`` deletes the run's files (``RUN_OUTPUTS``) and starts again, with the same arguments too
    (a damaged ``results.csv``, a run to redo with new code). Returns the ``run.json`` of the run being
    resumed (None when the run starts here).

    A ``run.json`` that is there but cannot be read (no permission, a folder, no UTF-8 text) is
    ``read_error`` ("cannot read"), not another run; ``overwrite`` does not read it but replaces it (a
    folder of that name is removed, as ``overwrite`` removes one named like an output). One that reads but
    is no JSON object is another run's, refused unless ``overwrite``. A run of other arguments whose
    ``results.csv`` holds no row (its setup failed, e.g. under a version that left such folders) is started
    again: nothing of it is lost."""
    out_dir.mkdir(parents=True, exist_ok=True)
    run_file, results = out_dir / RUN_FILE, out_dir / RESULTS_FILE
    mismatch = None
    old = None
    if run_file.exists() and not overwrite:  # --overwrite starts again: the old run.json is not read
        old, mismatch = _read_old_run(run_file)
        if old is not None:
            differ = _settings_differ(old, config)
            if not differ and old.get(SKIPPED_KEY) != config.get(SKIPPED_KEY):  # the same photos, reworded
                old = {**old, SKIPPED_KEY: config.get(SKIPPED_KEY)}
                write_atomic(run_file, json.dumps(old, indent=2) + "\n")
            if differ and _only_the_query_count(old, differ):
                write_atomic(run_file, json.dumps(config, indent=2) + "\n")  # the run grows or shrinks
                return old
            if differ:
                mismatch = _differ_phrase(differ)
                if results.is_file() and not holds_rows(results):  # begun, no query finished: nothing to keep
                    overwrite = True
    elif results.exists() and not run_file.exists():
        mismatch = f"it has a {RESULTS_FILE} but no {RUN_FILE}"
    if mismatch and not overwrite:
        raise _mismatch_error(out_dir, mismatch)
    if mismatch or overwrite:  # --overwrite starts the run again, whatever the folder holds
        remove_entries(out_dir, RUN_OUTPUTS)
        if run_file.is_dir() and not run_file.is_symlink():  # only --overwrite gets here with one
            shutil.rmtree(run_file, ignore_errors=True)
    if mismatch or overwrite or not run_file.exists():
        write_atomic(run_file, json.dumps(config, indent=2) + "\n")
        return None
    return old


def check_resumable(out_dir: Path, config: dict) -> None:
    """Raise the refusal ``prepare_output`` (without ``overwrite``) would raise for ``config`` in
    ``out_dir``, writing nothing: a command that writes before its runs start (``demo`` generates its city)
    checks every run first, so a refused run leaves the folder as it was."""
    run_file, results = out_dir / RUN_FILE, out_dir / RESULTS_FILE
    if not run_file.exists():
        if results.exists():
            raise _mismatch_error(out_dir, f"it has a {RESULTS_FILE} but no {RUN_FILE}")
        return
    old, mismatch = _read_old_run(run_file)
    if mismatch is not None:
        raise _mismatch_error(out_dir, mismatch)
    differ = _settings_differ(old, config)
    begun = not results.is_file() or holds_rows(results)  # no query finished: started again, not refused
    if differ and begun and not _only_the_query_count(old, differ):
        raise _mismatch_error(out_dir, _differ_phrase(differ))


def _read_old_run(run_file: Path) -> tuple[dict | None, str | None]:
    """(the ``run.json`` at ``run_file``, None) or (None, why it is another run's: no JSON, no object);
    ``read_error`` when it cannot be read at all. Shared by ``prepare_output`` and ``check_resumable``."""
    data = read_run_file(run_file)  # its own one-line error when unreadable (no permission, a folder)
    try:
        old = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise read_error(run_file, exc, RUN_FILE) from exc
    except ValueError as exc:
        return None, f"its {RUN_FILE} is not JSON ({exc})"
    if not isinstance(old, dict):  # JSON null too: None means "starts here"
        return None, f"its {RUN_FILE} is not a JSON object"
    return old, None


def _settings_differ(old: dict, config: dict) -> list[str]:
    """The settings ``config`` differs from the resumed run's ``old`` in (``differing_settings``; the
    skipped photos' reasons aside, and keys added since ``old`` was written, ``ADDED_KEYS``, not counted)."""
    recorded = {k: v for k, v in config.items() if k in old or k not in ADDED_KEYS}
    return differing_settings(_reasons_aside(old), _reasons_aside(recorded))


def _differ_phrase(differ: list[str]) -> str:
    """What a refused resume says of the settings that differ (``differing_settings``)."""
    shown = "; ".join(differ[:6]) + ("; ..." if len(differ) > 6 else "")
    changed = {d.split(":")[0].split(".")[0] for d in differ}
    folder = changed <= set(PHOTO_SET_KEYS) and ("query_names" in changed or changed == {SKIPPED_KEY})
    return (PHOTOS_DIFFER if folder else "arguments differ: ") + shown


def _mismatch_error(out_dir: Path, mismatch: str) -> ResumeMismatchError:
    return ResumeMismatchError(
        f"{out_dir} holds another benchmark run: {mismatch}; pass {parameter('overwrite')} or choose "
        f"another {parameter('out_dir')}"
    )


def _reasons_aside(config: dict) -> dict:
    """``config`` with its skipped photos' names and not their reasons, for the resume's comparison: which
    photos were skipped decides the numbers, not the words a version says why in (a reason reworded, a
    parameter named otherwise: ``errors.as_flags``). The reasons are kept in ``run.json`` as this version
    words them (``prepare_output``)."""
    skipped = config.get(SKIPPED_KEY)
    return {**config, SKIPPED_KEY: sorted(skipped)} if isinstance(skipped, dict) else config


# The settings that count a simulated run's queries: a difference a resume may have (``prepare_output``).
QUERY_COUNT_KEYS = ("queries", "query_config.queries")


def _only_the_query_count(old: dict, differ: list[str]) -> bool:
    """Whether a simulated run differs from ``old`` in its number of queries alone. Query ``i`` is drawn from
    its own generator (``queries``: seeded by (seed, i, ...), its view kind by a sequence over ``i``), so the
    first n queries of a run of m are those of a run of n: a finished run grows (``--queries 25`` after 20
    localizes 5 more) or is reported on fewer, with nothing redone. A data set's or a flight's query count is
    its images', never an argument."""
    names = {d.split(":")[0] for d in differ}
    return old.get("mode") is None and names <= set(QUERY_COUNT_KEYS) and "queries" in names


def run_entries(out_dir: Path) -> set[str]:
    """The names of ``run.json`` and the run's outputs (``RUN_OUTPUTS``) that ``out_dir`` holds (a dangling
    link too): what a run that fails at setup compares with the folder it found (``remove_entries``)."""
    return {name for name in (RUN_FILE, *RUN_OUTPUTS) if os.path.lexists(out_dir / name)}


def remove_entries(out_dir: Path, names: Iterable[str]) -> None:
    """Delete ``names`` (files, links or folders) from ``out_dir``: the outputs ``overwrite`` clears, or
    those a run that failed before its first row made (``benchmark.run``). Not there: nothing to do."""
    for name in names:
        path = out_dir / name
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)


def holds_rows(path: Path) -> bool:
    """Whether the ``results.csv`` at ``path`` holds anything beyond its header (a torn row too). One that
    cannot be read counts as holding rows: a run's results are never deleted on a guess."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return False
    except OSError:
        return True
    return bool(data.partition(b"\n")[2].strip())


def code_change_note(out_dir: Path, old: dict | None, config: dict, done: int, todo: int) -> str | None:
    """What a user should hear when ``done`` finished queries of a resumed run were made by other package
    code than the ``todo`` ones about to be made (``CODE_KEY`` of the old and new ``run.json``); None when
    nothing mixes or the old run did not record its code."""
    before, now = (old or {}).get(CODE_KEY), config.get(CODE_KEY)
    if not (done and todo) or before is None or now is None or before == now:
        return None
    return (
        f"{out_dir}: resuming a run started by other semcityloc code (source {before}, now {now}): its "
        f"{counted(done, 'finished query was', 'finished queries were')} made by that code and the {todo} "
        f"left {'is' if todo == 1 else 'are'} made by this one, so its "
        f"results mix both; pass {parameter('overwrite')} to make them all anew"
    )


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
        """Count ``n`` more queries done; the bar is redrawn at most every 0.2 s on a TTY."""
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
        """End the bar with one line of what was done, how long it took and the time per query."""
        new = self.done - self.start_done
        elapsed = time.monotonic() - self.t0
        rate = f", {elapsed / new:.2f} s/query" if new else ""
        if self.tty:
            self._draw()
            self.stream.write("\n")
        self.stream.write(
            f"{self.label}: {self.done}/{counted(self.total, 'query')} done ({new} new in "
            f"{_duration(elapsed)}{rate})\n"
        )
        self.stream.flush()


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else f"{m}m{s:02d}s" if m else f"{s}s"

"""``--out`` checked before any work: an output path that cannot be written is one line and exit 2.

Why: a command that computes for minutes and only then fails to write its result loses that work, and the
failure would surface as a traceback from deep inside ``mkdir``. The check walks up to the nearest folder
that exists and proves it writable by creating (and removing) a temporary file there: that also catches
read-only mounts and immutable folders, which permission bits do not show (root passes ``os.access``).
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from semcityloc.errors import OutputPathError

# Commands whose ``out`` is a file (the others write a folder); every command creates missing parents.
FILE_OUTPUTS = {("dataset", "dji-prior"), ("city", "convert")}


def check_output_args(args: argparse.Namespace) -> None:
    """``OutputPathError`` when the command's ``--out`` (or ``city convert``'s OUT) cannot be written."""
    out = getattr(args, "out", None)
    if out is None:
        return
    command = (args.command, getattr(args, "dataset_command", None) or getattr(args, "city_command", None))
    check_output_path(out, is_file=command in FILE_OUTPUTS)


def check_output_path(out: str | os.PathLike, is_file: bool = False) -> None:
    """Raise ``OutputPathError`` unless ``out`` (a folder, or a file with ``is_file``) can be written."""
    path = Path(out)
    if is_file and path.is_dir():
        raise OutputPathError(f"--out {out}: is a folder; give the name of the file to write")
    if not is_file and path.exists() and not path.is_dir():
        raise OutputPathError(f"--out {out}: is a file; give a folder (it is created if missing)")
    folder = path.parent if is_file else path
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise OutputPathError(f"--out {out}: {existing} is a file, not a folder")
    try:
        fd, probe = tempfile.mkstemp(prefix=".semcityloc-write-test-", dir=existing)
        os.close(fd)
        os.unlink(probe)
        if is_file and path.exists():
            with open(path, "ab"):  # an existing file that is read-only or immutable
                pass
    except OSError as exc:
        where = path if is_file and path.exists() else existing
        raise OutputPathError(f"--out {out}: cannot write to {where} ({exc.strerror or exc})") from exc

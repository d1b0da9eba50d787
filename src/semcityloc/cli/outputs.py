"""``--out`` checked before any work: an output path that cannot be written is one line and exit 2.

Why: a command that computes for minutes and only then fails to write its result loses that work, and the
failure would surface as a traceback from deep inside ``mkdir``. The check walks up to the nearest folder
that exists and proves it writable by creating (and removing) a temporary file there: that also catches
read-only mounts and immutable folders, which permission bits do not show (root passes ``os.access``).

``check_outputs`` (stop 55) is the second check, once a command knows the files it will write: none of
them may be one of its inputs (``label --images photos --out photos`` of PNG photos replaced each photo by
its label map; ``city convert u.obj u.obj`` the user's model), and no two inputs may write one file
(``X.JPG`` and ``X.png`` both to ``X.png``, the second overwriting the first). ``label``, ``render``,
``localize``, ``city convert``, ``dataset overlay``, ``dataset colmap`` and ``dataset dji-prior`` call it
before any work.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from collections.abc import Iterable
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


def _file_key(path: Path) -> tuple[int, int] | None:
    """The (device, inode) of an existing file (what ``os.path.samefile`` compares), else None."""
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_dev, st.st_ino)


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether ``a`` and ``b`` are one existing file (also through a link or another spelling of its
    path)."""
    key = _file_key(Path(a))
    return key is not None and key == _file_key(Path(b))


def check_outputs(
    outputs: Iterable[tuple[str, Path]], inputs: Iterable[str | os.PathLike | None], flag: str = "--out"
) -> None:
    """Refuse (``OutputPathError``, before any work) a run whose files to write overlap its inputs.

    ``outputs``: (what it is written from, e.g. the photo's name; the file to write) pairs. Refused: an
    output that is one of ``inputs`` (the same file, also through a link or another spelling of its path:
    it would be overwritten by what is made from it), and two outputs of one file (the second would replace
    the first while both are counted). Inputs that are no file (a folder, ``generated``, None) are skipped.
    ``flag``: how the command's user names the output (``--out``, ``city convert``'s ``OUT``)."""
    keys = {}
    for given in inputs:
        if given is None:
            continue
        key = _file_key(Path(given))
        if key is not None and Path(given).is_file():
            keys.setdefault(key, Path(given))
    written: dict[str, tuple[int, str]] = {}
    for index, (source, path) in enumerate(outputs):
        first, source_of = written.setdefault(os.path.normcase(os.path.realpath(path)), (index, source))
        if first != index:
            raise OutputPathError(
                f"{source_of} and {source} would both be written to {path} (the second replacing the first): "
                "rename one of them or write them to separate folders"
            )
        key = _file_key(Path(path))
        if key is not None and key in keys:
            same = "" if os.path.realpath(keys[key]) == os.path.realpath(path) else f" ({keys[key]})"
            raise OutputPathError(
                f"{path} is an input of this command{same}: writing it would overwrite the input; give "
                f"another {flag}"
            )

"""``io.stamps``: a file's stamp and its SHA-256 read once while the stamp holds, without taking a changed
file for the one hashed before (the status-change time, and the hash of a file that changed just now)."""

from __future__ import annotations

import hashlib
import os

import pytest

from semcityloc.citymodel import io
from semcityloc.io import stamps


def _rewrite_keeping_times(path, data: bytes) -> None:
    """``data`` into ``path`` with its modification time put back, as ``cp -p`` or ``touch -d`` leave it."""
    before = path.stat()
    path.write_bytes(data)
    os.utime(path, ns=(before.st_atime_ns, before.st_mtime_ns))


@pytest.mark.parametrize("racy_s", [stamps.RACY_S, 0.0])
def test_a_file_rewritten_with_its_size_and_modification_time_is_hashed_again(tmp_path, monkeypatch, racy_s):
    """The hash of a city (or any input) was kept by path, inode, size and modification time: a file
    rewritten in place with bytes of the same size and its old modification time (``cp -p`` of another
    version, a restore) kept the old hash in that process (the parse cache's key, a run's provenance;
    fixer, stop 52). Now the status-change time is in the key too (no program can set it back), and a file
    changed within ``RACY_S`` is read again each time (its times may not have moved at all)."""
    monkeypatch.setattr(stamps, "RACY_S", racy_s)
    path = tmp_path / "mask.png"
    path.write_bytes(b"A" * 64)
    first = io.file_sha256(path)
    _rewrite_keeping_times(path, b"B" * 64)
    assert io.file_sha256(path) == hashlib.sha256(b"B" * 64).hexdigest() != first


def test_a_stamp_changes_with_a_files_bytes_or_a_folders_entries_and_only_then(tmp_path):
    """``paths_stamp`` (the key of a photo run's inputs in a process): the same while nothing changes; a
    same-size rewrite within the clock tick changes it (the file's hash is in a fresh file's stamp), as
    do an added file and a removed one; a missing path is a stamp too."""
    folder = tmp_path / "masks"
    folder.mkdir()
    (folder / "a.png").write_bytes(b"A" * 64)
    named = [folder, tmp_path / "prior.csv", None]
    first = stamps.paths_stamp(named)
    assert stamps.paths_stamp(named) == first
    _rewrite_keeping_times(folder / "a.png", b"B" * 64)
    second = stamps.paths_stamp(named)
    assert second != first
    (folder / "b.png").write_bytes(b"")
    assert stamps.paths_stamp(named) != second
    (tmp_path / "prior.csv").write_text("name,x\n")
    assert stamps.paths_stamp(named)[1][1] is not None


def test_a_fingerprint_is_size_and_sha256_of_the_bytes_and_none_for_no_file(tmp_path):
    path = tmp_path / "P0.JPG"
    path.write_bytes(b"\xff\xd8\xff" * 10)
    assert stamps.file_fingerprint(path) == {
        "file": "P0.JPG",
        "bytes": 30,
        "sha256": hashlib.sha256(b"\xff\xd8\xff" * 10).hexdigest(),
    }
    (tmp_path / "P1.JPG").mkdir()
    assert stamps.file_fingerprint(tmp_path / "P1.JPG") is None
    assert stamps.file_fingerprint(tmp_path / "P2.JPG") is None

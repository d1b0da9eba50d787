"""A photo run's flight focal-length estimate kept between runs, so that a resumed or repeated run reads it.

Why: the estimate localizes up to 20 oblique photos at 9 focal scales (``localization.focal``), 1-2 min
on 2 cores, and a run that is stopped and resumed, or run again with other outputs, would pay it every
time. The estimate is deterministic, so it is kept under ``cache.cache_root() / "focal"``, keyed by
everything that decides it:

- the package's source (``code_fingerprint``): any change of the code computes it anew;
- the city (its file's or tile store's sha256), LoD and CRS, and the localizer's settings;
- how the masks and depth are made (the backends and their options, lossy masks allowed);
- per photo the estimate uses: its name, camera, lens, prior pose, stated uncertainty, and the bytes of its
  mask and depth files (of the photo itself when a backend segments it).

Anything else different gives another key. A cache file that does not read back as an estimate is
ignored (and replaced). ``--no-cache`` turns it off with the city-model cache.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from semcityloc.benchmark.code_version import code_fingerprint
from semcityloc.cache import cache_root
from semcityloc.errors import ParameterError
from semcityloc.io.files import write_json_atomic
from semcityloc.io.stamps import file_sha256
from semcityloc.localization.focal import FocalEstimate

FORMAT = 1


def cache_file(key: str) -> Path:
    """The file an estimate of key ``key`` is kept in, under ``cache.cache_root()`` so that one setting moves
    every cache.
    """
    return cache_root() / "focal" / f"{key}.json"


def estimate_key(run: dict[str, Any], photos: Sequence[Any]) -> str:
    """The key of an estimate from the run's settings that decide it (``run``: JSON-ready) and the photos
    it uses (``PhotoInput``: name, camera, distortion, prior, uncertainty, path, mask, depth)."""
    digest = hashlib.sha256()
    digest.update(json.dumps({"format": FORMAT, "code": code_fingerprint(), **run}, sort_keys=True).encode())
    for p in photos:
        pose = p.prior.pose_world
        files = [path for path in (p.mask, p.depth) if path is not None] or [p.path]
        record = {
            "name": p.name,
            "camera": asdict(p.camera),
            "distortion": asdict(p.distortion),
            "prior_R": np.asarray(pose.R, dtype=np.float64).round(12).tolist(),
            "prior_t": np.asarray(pose.t, dtype=np.float64).round(9).tolist(),
            "uncertainty": p.uncertainty.as_dict(),
            "files": [file_sha256(path) for path in files],
        }
        digest.update(json.dumps(record, sort_keys=True).encode())
    return digest.hexdigest()[:32]


def read_estimate(key: str) -> FocalEstimate | None:
    """The cached estimate of ``key``; None when there is none or the file is not one."""
    path = cache_file(key)
    try:
        return FocalEstimate.from_dict(json.loads(path.read_text(encoding="utf-8")))
    except (OSError, ValueError, ParameterError):
        return None


def write_estimate(key: str, estimate: FocalEstimate) -> None:
    """Keep ``estimate`` under ``key`` (a cache that cannot be written is skipped: it only saves time)."""
    path = cache_file(key)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(path, estimate.as_dict())
    except OSError:
        pass

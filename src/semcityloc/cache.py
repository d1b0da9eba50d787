"""Where semcityloc keeps what it computed once and may need again: one root for every cache.

Why one place: parsed city models (``citymodel.io``), the generated district (``citymodel.generator``),
photo runs' focal-length estimates (``benchmark.focal_cache``) and the default folder of perception weights
(``perception.base.weights_dir``, unless ``SEMCITYLOC_WEIGHTS`` names another) all live under the same
folder, so a user who sets ``SEMCITYLOC_CACHE`` (or ``XDG_CACHE_HOME``) moves them all, and deleting it
clears them all.
"""

from __future__ import annotations

import os
from pathlib import Path


def cache_root() -> Path:
    """``$SEMCITYLOC_CACHE`` or ``$XDG_CACHE_HOME`` or ``~/.cache``, then ``semcityloc``."""
    root = os.environ.get("SEMCITYLOC_CACHE") or os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(root) / "semcityloc"

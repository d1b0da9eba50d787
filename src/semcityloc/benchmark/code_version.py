"""A fingerprint of the package's own source code, for caches of expensive results made by that code.

Why: the tuning scripts cache simulated queries (``benchmarks/compare_configs.py``) and localizations'
features (``benchmarks/calibrate_confidence.py``) between runs. A cache keyed only by city, seed and
settings silently serves results of an older simulation or localizer after the code changed; the
comparisons and the fitted models would then describe code that no longer exists. Keying the cache by
the source of what made it turns "delete the cache by hand after a change" into a re-run.

``code_fingerprint(exclude=("localization",))``: the simulation's cache survives changes to the
localizer alone (that is what a comparison varies) and nothing else.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from pathlib import Path

PACKAGE_ROOT = Path(__file__).resolve().parents[1]


def code_fingerprint(exclude: Iterable[str] = ()) -> str:
    """16 hex digits of the sha256 over the package's ``*.py`` files (relative path and bytes, in path
    order), leaving out the top-level subpackages named in ``exclude`` (e.g. ``"localization"``)."""
    skip = set(exclude)
    digest = hashlib.sha256()
    for path in sorted(PACKAGE_ROOT.rglob("*.py")):
        rel = path.relative_to(PACKAGE_ROOT)
        if rel.parts[0] in skip:
            continue
        digest.update(rel.as_posix().encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
        digest.update(b"\0")
    return digest.hexdigest()[:16]

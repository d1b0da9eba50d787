"""Compile the numba kernels once, ahead of use: ``semcityloc warmup``, and "will this command compile?".

Why: the renderer, the localizer's fused scoring kernels and the wireframe baseline's edge scoring are numba
functions compiled on their first call and cached on disk (``cache=True``: ``__pycache__`` beside the
source, or ``NUMBA_CACHE_DIR``). That first call costs tens of seconds to a minute and a half on 2 cores
(measured in docs/your-data.md), once per install and again after a kernel's source changes. Unannounced,
it looks like a hang or a slow localizer; so ``warm_up()`` runs every kernel once on a tiny model (what
``make demo`` / ``make test`` do after installing), and ``kernels_cached()`` tells the CLI whether a command
is about to compile, so it can say so once.

``KERNEL_GROUPS``: the modules holding cached kernels, by what needs them (``render``: every render and
automatic label; ``localize``: the localizer's scoring; ``wireframe``: the LoD-Loc-style baseline). Every
non-inlined ``cache=True`` dispatcher defined in them is warmed; inlined helpers are compiled into their
callers and have no cache of their own. ``kernels_cached(groups)`` checks the groups a command uses, so a
command that will not compile says nothing.

Why a stamp of the sources: numba keys a cached kernel by its own file only, so a kernel that calls (and
inlines) one of another module, as the localizer's scoring kernels call the rasteriser's ``render_view``,
keeps running its cached old copy after that other module changed. ``warm_up()`` writes the fingerprint
of every kernel module (and of ``classes``, whose ids the kernels bake in) beside the caches;
``kernels_cached()`` is False when the sources differ from it, and ``warm_up()`` then recompiles every
kernel from today's sources instead of loading the old ones.
"""

from __future__ import annotations

import hashlib
import importlib
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TextIO

import numpy as np
from numba.core.registry import CPUDispatcher

from semcityloc.benchmark.methods import get_method
from semcityloc.benchmark.queries import BenchmarkQuery
from semcityloc.citymodel.io import load_city_model
from semcityloc.errors import parameter
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.localization.config import LocalizerConfig
from semcityloc.render import Renderer

KERNEL_GROUPS = {
    "render": ("semcityloc.render.raster_numba", "semcityloc.render.terrain"),
    "localize": ("semcityloc.localization.kernels", "semcityloc.localization.resample"),
    "wireframe": ("semcityloc.baselines.edge_score",),
}
# Modules whose code or constants the kernels compile in, besides KERNEL_GROUPS' own.
BAKED_IN_MODULES = ("semcityloc.classes",)
STAMP_NAME = "semcityloc-kernels.stamp"
COMPILE_NOTICE = (
    "compiling the numba kernels this command needs: about a minute, once per install for each kind of "
    f"command ({parameter('warmup')} compiles all of them ahead of time)"
)
# Methods run by the warm-up: each reaches kernels (or signatures) the others do not.
WARMUP_METHODS = ("semcityloc", "no-depth", "lodloc-wireframe")


def kernel_groups(method: str) -> tuple[str, ...]:
    """The kernel groups a run of ``method`` uses (every localizer and baseline renders and scores)."""
    return ("render", "localize", "wireframe") if method == "lodloc-wireframe" else ("render", "localize")


def cached_kernels(groups: tuple[str, ...] | None = None) -> list[CPUDispatcher]:
    """The cached, non-inlined numba dispatchers of ``KERNEL_GROUPS`` (``groups``: those only)."""
    out = []
    modules = [m for g, ms in KERNEL_GROUPS.items() if groups is None or g in groups for m in ms]
    for name in modules:
        module = importlib.import_module(name)
        for obj in vars(module).values():
            if (
                isinstance(obj, CPUDispatcher)
                and obj.py_func.__module__ == name
                and obj.targetoptions.get("inline", "never") != "always"
                and getattr(obj, "_cache", None) is not None
                and type(obj._cache).__name__ != "NullCache"
            ):
                out.append(obj)
    return out


def sources_fingerprint() -> str:
    """sha256 of the source files of every kernel module and of ``BAKED_IN_MODULES``."""
    names = sorted({m for ms in KERNEL_GROUPS.values() for m in ms} | set(BAKED_IN_MODULES))
    digest = hashlib.sha256()
    for name in names:
        digest.update(name.encode() + b"\0" + Path(importlib.import_module(name).__file__).read_bytes())
    return digest.hexdigest()


def _stamp_path() -> Path | None:
    """Where the stamp lives (beside the rasteriser's cache), or None when numba's cache cannot be
    inspected (its internals changed)."""
    try:
        return Path(cached_kernels(("render",))[0]._cache._cache_path) / STAMP_NAME
    except Exception:  # numba-internal API: any failure means "cannot tell"
        return None


def sources_match_cache() -> bool | None:
    """True when the kernels were compiled from today's sources by ``warm_up``, False when not (another
    version of a kernel module, or compiled outside ``warm_up``), None when it cannot be told."""
    path = _stamp_path()
    if path is None:
        return None
    try:
        return path.read_text(encoding="utf-8").strip() == sources_fingerprint()
    except OSError:
        return False


def _has_cache_entry(kernel: CPUDispatcher) -> bool | None:
    """Whether ``kernel`` has a compiled version in its on-disk cache valid for its current source; None
    when numba's cache cannot be inspected (its internals changed)."""
    try:
        return bool(kernel._cache._cache_file._load_index())
    except Exception:  # numba-internal API: any failure means "cannot tell"
        return None


def kernels_cached(groups: tuple[str, ...] | None = None) -> bool:
    """False when a kernel of ``groups`` (default: every group) that commands use has no cached
    compilation, or when the cache was not stamped by ``warm_up`` with today's sources: the next command
    using it will compile."""
    if sources_match_cache() is False:
        return False
    return all(_has_cache_entry(k) is not False for k in cached_kernels(groups))


def ensure_compiled(groups: tuple[str, ...] | None, stream: TextIO | None = None) -> float | None:
    """Compile (``warm_up``) when a kernel of ``groups`` is not cached, saying so on ``stream`` (default
    stderr); the seconds it took, or None when nothing was to compile. The run loop calls it before the
    first query, so that no query's time holds a compilation."""
    if kernels_cached(groups):
        return None
    stream = stream if stream is not None else sys.stderr
    stream.write(f"semcityloc: {COMPILE_NOTICE}\n")
    stream.flush()
    seconds = warm_up()["total_s"]
    stream.write(f"semcityloc: kernels compiled and cached in {seconds:.0f} s\n")
    stream.flush()
    return seconds


def box_city_obj() -> str:
    """A 4 x 4 block of boxes of varied heights as Wavefront OBJ text (a tiny model for the warm-up)."""
    faces = [(1, 4, 3, 2), (5, 6, 7, 8), (1, 2, 6, 5), (2, 3, 7, 6), (3, 4, 8, 7), (4, 1, 5, 8)]
    lines, base = [], 0
    for i in range(4):
        for j in range(4):
            x0, y0, h = i * 30.0 - 60.0, j * 30.0 - 60.0, 8.0 + 5.0 * ((i * 3 + j * 5) % 5)
            corners = [(x0, y0, 0.0), (x0 + 18, y0, 0.0), (x0 + 18, y0 + 16, 0.0), (x0, y0 + 16, 0.0)]
            corners += [(x, y, h) for x, y, _ in corners]
            lines += [f"v {x:.1f} {y:.1f} {z:.1f}" for x, y, z in corners]
            lines += ["f " + " ".join(str(k + base) for k in f) for f in faces]
            base += 8
    return "\n".join(lines) + "\n"


def warm_up(say: Callable[[str], None] | None = None) -> dict[str, float]:
    """Run every kernel once (render, the localizer with and without depth, the wireframe baseline) so
    numba compiles and caches it, then stamp the caches with the sources; returns seconds per step. When
    the sources differ from the stamp, every kernel's cache (and any copy already loaded) is dropped
    first, so nothing compiled from older sources survives."""
    say = say or (lambda text: None)
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    if sources_match_cache() is False:
        for kernel in cached_kernels():
            kernel.recompile()  # drops the cached and loaded versions; recompiles those loaded from source
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "warmup_city.obj"
        path.write_text(box_city_obj(), encoding="utf-8")
        model = load_city_model(path, cache=False)
    camera = Camera.from_fov(128, 96, 60.0)
    truth = Pose.from_xyz_rpy(np.array([5.0, -4.0, 90.0]), 1.0, 25.0, 30.0)
    prior = Pose.from_xyz_rpy(np.array([8.0, -1.0, 92.0]), 0.0, 24.0, 33.0)
    say("render")
    renderer = Renderer(model, engine="numba")
    view = renderer.render(camera, truth, depth=True, face_ids=True)
    labels, depth = view.labels[0], np.where(np.isfinite(view.depth[0]), view.depth[0], np.nan)
    times["render_s"] = time.perf_counter() - t0
    config = LocalizerConfig.preset("fast")
    for name in WARMUP_METHODS:
        t = time.perf_counter()
        say(name)
        query = BenchmarkQuery("q0000", 0, camera, truth, prior, labels, depth, 100.0, {})
        get_method(name, model, config).localize(query)
        times[f"{name}_s"] = time.perf_counter() - t
    times["total_s"] = time.perf_counter() - t0
    stamp = _stamp_path()
    if stamp is not None:
        try:
            stamp.write_text(sources_fingerprint() + "\n", encoding="utf-8")
        except OSError:  # a read-only cache: the kernels work, the next warm-up cannot skip
            pass
    return times

"""Rendering semantic masks of a city model: the engine under every pose search.

``Renderer(model).render(camera, cams_from_local)`` gives (N, H, W) class masks (and z-depth / face ids on
request) of poses in the model's local frame. Lower-level pieces for fused scoring: ``RenderScene`` (the
triangle, class and tile arrays) and the numba kernels in ``semcityloc.render.raster_numba``
(``render_view`` per view, which the fused scoring kernels of ``semcityloc.localization.kernels`` call).
Many yaws about one camera centre: the coarse search's wide views and lookup tables
(``semcityloc.localization.coarse.yaw_lookup``).
"""

import os

from semcityloc.render.engine import Renderer
from semcityloc.render.output import RenderOutput
from semcityloc.render.scene import RenderScene, build_scene

__all__ = ["Renderer", "RenderOutput", "RenderScene", "build_scene"]

# OpenMP's idle threads wait asleep, not spinning, unless the user chose otherwise (``OMP_WAIT_POLICY``, read
# when numba first starts its OpenMP threads: at the first parallel kernel call, after this package, which
# every kernel module imports, is loaded). Why: on cores shared with other processes a spinning thread holds
# a core the thread it waits for needs, and every parallel kernel call waited about 8 ms for the scheduler
# (a localization makes ~35: 0.85 s per image spinning against 0.33 s asleep, 2 threads on a busy 2-core VM,
# stop 54; docs/localization.md, "Speed"). Asleep costs a wake-up of microseconds per call. No result
# depends on it: every view is computed on its own.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

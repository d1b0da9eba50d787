"""Rendering semantic masks of a city model: the engine under every pose search.

``Renderer(model).render(camera, cams_from_local)`` gives (N, H, W) class masks (and z-depth / face ids on
request) of poses in the model's local frame. Lower-level pieces for fused scoring: ``RenderScene`` (the
triangle, class and tile arrays) and the numba kernels in ``semcityloc.render.raster_numba``
(``render_view`` per view, which the fused scoring kernels of ``semcityloc.localization.kernels`` call).
Many yaws about one camera centre: the coarse search's wide views and lookup tables
(``semcityloc.localization.coarse.yaw_lookup``).
"""

from semcityloc.render.engine import Renderer
from semcityloc.render.output import RenderOutput
from semcityloc.render.scene import RenderScene, build_scene

__all__ = ["Renderer", "RenderOutput", "RenderScene", "build_scene"]

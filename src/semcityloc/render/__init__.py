"""Rendering semantic masks of a city model: the engine under every pose search.

``Renderer(model).render(camera, poses)`` gives (N, H, W) class masks (and z-depth / face ids on request).
Lower-level pieces for fused scoring: ``RenderScene`` (the triangle, class and tile arrays) and the numba
kernels in ``semcityloc.render.raster_numba`` (``render_view`` per view; ``render_confusion`` shows
where to hook a per-view reduction). ``render_yaw_fan`` renders many yaws about one camera centre from a
few wide views.
"""

from semcityloc.render.engine import Renderer
from semcityloc.render.output import RenderOutput
from semcityloc.render.rotation_reuse import render_yaw_fan
from semcityloc.render.scene import RenderScene, build_scene

__all__ = ["Renderer", "RenderOutput", "RenderScene", "build_scene", "render_yaw_fan"]

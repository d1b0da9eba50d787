"""``Renderer``: semantic masks (and z-depth, face ids) of a ``CityModel`` seen by pinhole cameras.

One ``Renderer`` per model. It builds the ``RenderScene`` once (terrain, tiles) and hands each batch of
poses to an engine:

- ``"numba"``: the CPU z-buffer rasteriser (``raster_numba``), the default;
- ``"embree"``: the Embree ray-casting reference (``embree_ref``; optional ``embreex``);
- ``"gpu"``: nvdiffrast (``gpu``; optional, never executed yet: only when asked for by name);
- ``"auto"``: ``"numba"``. Never the GPU engine, even where it would load: it has not run anywhere, so
  labels and overlays must not come from it unless a caller asks for ``"gpu"`` (``render/gpu.py``).

Poses are ``cam_from_local``: ``cam_from_world`` with the model's LOCAL frame as the world (world =
``model.origin`` + local), ``Renderer.render(camera, cams_from_local)``; bring a world pose over with
``model.pose_to_local(pose_world)``. The engines take the same transforms as arrays,
``render(camera, R_cams_from_local (N, 3, 3), t_cams_from_local (N, 3))``.
"""

from __future__ import annotations

import copy

import numpy as np

from semcityloc.citymodel.model import CityModel
from semcityloc.errors import ArgumentTypeError, PoseError, RenderError, ShapeError, unknown_choice
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose, local_frame_problem
from semcityloc.render.embree_ref import EmbreeEngine
from semcityloc.render.gpu import GpuEngine
from semcityloc.render.output import RenderOutput
from semcityloc.render.raster_numba import NumbaEngine
from semcityloc.render.scene import RenderScene, build_scene

ENGINES = ("auto", "numba", "embree", "gpu")
# Pixels one render call may produce (all its views): ~13 bytes each with depth and face ids, so about
# 13 GB at the bound. The largest aerial sensors have 150 MP a view; more is a size given in the wrong unit.
MAX_RENDER_PIXELS = 1_000_000_000


def pose_arrays(cams_from_local: Pose) -> tuple[np.ndarray, np.ndarray]:
    """(R (N, 3, 3), t (N, 3)) contiguous float64 of the ``cam_from_local`` transforms of a single pose or
    a (N,) batch (``x_cam = R @ x_local + t``)."""
    if not isinstance(cams_from_local, Pose):
        raise ArgumentTypeError(
            "cams_from_local must be a semcityloc Pose (single, or a batch: Pose.stack), got "
            f"{type(cams_from_local).__name__}"
        )
    shape = cams_from_local.batch_shape
    if len(shape) > 1:
        raise ShapeError(
            f"cams_from_local must be a single pose or a 1-D batch (N,), got batch shape {shape}"
        )
    R_cams_from_local = np.ascontiguousarray(cams_from_local.R.reshape(-1, 3, 3), dtype=np.float64)
    t_cams_from_local = np.ascontiguousarray(cams_from_local.t.reshape(-1, 3), dtype=np.float64)
    return R_cams_from_local, t_cams_from_local


def check_camera(camera: Camera) -> Camera:
    """``camera`` if it is a ``Camera``, else an ``ArgumentTypeError`` saying how to make one; library callers
    passing a K matrix get a clear error, not a numpy one deep in a kernel.
    """
    if not isinstance(camera, Camera):
        raise ArgumentTypeError(
            f"camera must be a semcityloc Camera (Camera.from_K(K, width, height), read_lens(...)), got "
            f"{type(camera).__name__}"
        )
    return camera


def make_engine(name: str, scene: RenderScene):
    """The engine object for ``name`` (see module docstring)."""
    if name not in ENGINES:
        raise unknown_choice("render engine", name, ENGINES, RenderError)
    if name == "gpu":  # only by name: "auto" never picks the unexecuted GPU engine (module docstring)
        return GpuEngine(scene)  # raises RenderError with an install hint when unavailable
    if name == "embree":
        return EmbreeEngine(scene)

    return NumbaEngine(scene)


class Renderer:
    """Render a ``CityModel`` (module docstring).

    Args:
        model: the city model; ``EmptyModelError`` if it has nothing to draw.
        engine: ``"auto"`` (``"numba"``) | ``"numba"`` | ``"embree"`` | ``"gpu"`` (module docstring).
        ground: add the terrain TIN of class GROUND between the buildings (``terrain.py``).
        tile_size_m: edge of the square ground tiles used for view culling.
    """

    def __init__(
        self, model: CityModel, engine: str = "auto", ground: bool = True, tile_size_m: float = 25.0
    ):
        if not isinstance(model, CityModel):
            raise ArgumentTypeError(
                f"model must be a CityModel (load_city_model(path)), got {type(model).__name__}"
            )
        if not isinstance(engine, str):
            raise ArgumentTypeError(f"engine must be a string, got {type(engine).__name__}")
        self.model = model
        self.scene = build_scene(model, ground=ground, tile_size_m=tile_size_m)
        self.engine = make_engine(engine, self.scene)

    @property
    def engine_name(self) -> str:
        return self.engine.name

    def with_scene(self, scene: RenderScene) -> Renderer:
        """A renderer of the same model on the same engine drawing ``scene`` instead: a variant of this
        one's scene with some model triangles moved (``render.scene.with_model_triangles``: the map with
        eaves the localizer searched), so that a drawing of the map shows the map a pose was found on."""
        if not isinstance(scene, RenderScene):
            raise ArgumentTypeError(
                "scene must be a RenderScene (a variant of this renderer's scene: "
                f"render.scene.with_model_triangles), got {type(scene).__name__}"
            )
        other = copy.copy(self)
        other.scene = scene
        other.engine = make_engine(self.engine_name, scene)
        return other

    def render(
        self, camera: Camera, cams_from_local: Pose, depth: bool = False, face_ids: bool = False
    ) -> RenderOutput:
        """Labels (N, H, W) uint8, and z-depth / face ids when asked, for N poses (N = 1 for one pose):
        ``cams_from_local``, a ``Pose`` (or ``Pose.stack``) in the model's local frame
        (``model.pose_to_local(pose_world)``)."""
        check_camera(camera)
        R_cams_from_local, t_cams_from_local = pose_arrays(cams_from_local)
        problem = local_frame_problem(cams_from_local.center)  # a world pose draws nothing, silently
        if problem is not None:
            raise PoseError(f"Renderer.render takes poses in the model's local frame: {problem}")
        n_views = len(R_cams_from_local)
        pixels = n_views * camera.width * camera.height
        if pixels > MAX_RENDER_PIXELS:
            raise RenderError(
                f"{n_views} view(s) of {camera.width}x{camera.height} pixels ({pixels:,}) exceed the "
                f"{MAX_RENDER_PIXELS:,} one render may make: check the image size, or render fewer views "
                "at once"
            )
        return self.engine.render(
            camera, R_cams_from_local, t_cams_from_local, depth=bool(depth), face_ids=bool(face_ids)
        )

    def __repr__(self) -> str:
        s = self.scene
        return (
            f"Renderer(engine={self.engine_name!r}, triangles={s.num_triangles} "
            f"(terrain {s.num_terrain_triangles}), tiles={s.num_tiles}, blocks={s.num_blocks})"
        )

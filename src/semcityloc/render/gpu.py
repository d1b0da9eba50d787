"""Optional GPU engine: nvdiffrast (CUDA rasteriser) over the same ``RenderScene``.

Chosen only by ``engine="gpu"``, never by ``engine="auto"`` (the numba engine), because of its STATUS
below: a user who asks for it by name knows it is unexecuted. Without ``torch`` with CUDA, ``nvdiffrast``
and a GPU, ``"gpu"`` raises ``RenderError`` with an install hint. Once ``tests/test_render_gpu.py`` has
passed on a GPU, ``"auto"`` may choose it again (``render.engine.make_engine``).

STATUS: written without a GPU to run it on (none on the development machines); it has NOT been executed.
The conventions it relies on, so that whoever first runs it can check them against the numba engine
(``tests/test_render_gpu.py`` does exactly that when a GPU is present):

- clip space: ``x_clip = (2 fx / W) x + (2 cx / W - 1) z``, ``y_clip = (2 fy / H) y + (2 cy / H - 1) z``,
  ``w = z`` (camera frame, OpenCV axes), so NDC -1..1 spans the image edges and pixel centres are sampled
  at (j + 0.5, i + 0.5) as by the other engines; nvdiffrast's output row 0 is NDC y = -1, which with this
  mapping is image row 0 (top), so no flip is needed;
- depth: z-depth is interpolated perspective-correctly as a vertex attribute (exact, not from z/w);
- visibility uses nvdiffrast's float32 z/w buffer with ``GPU_NEAR_M``/``GPU_FAR_M``: farther than ~1 km,
  surfaces closer together than a few centimetres may resolve differently from the CPU engines.
"""

from __future__ import annotations

import importlib.util

import numpy as np

from semcityloc.errors import RenderError, parameter
from semcityloc.geometry.camera import Camera
from semcityloc.render.output import RenderOutput
from semcityloc.render.scene import RenderScene

GPU_NEAR_M = 1.0
GPU_FAR_M = 100_000.0
INSTALL_HINT = (
    f"pip install torch nvdiffrast (needs an NVIDIA GPU with CUDA); or use {parameter('engine', 'numba')}"
)


def gpu_status() -> tuple[bool, str]:
    """(available, reason it is not) for the nvdiffrast engine; never raises.

    Looks for the packages before importing anything, so that asking on a machine without nvdiffrast
    does not pay for importing torch.
    """
    for package in ("nvdiffrast", "torch"):
        try:
            if importlib.util.find_spec(package) is None:
                return False, f"{package} is not installed"
        except (ImportError, ValueError):
            return False, f"{package} is not installed"
    try:
        import torch  # optional dependency, loaded only when used

        if not torch.cuda.is_available():
            return False, "torch finds no CUDA GPU"
        # optional (nvdiffrast): imported only to probe the GPU engine, never with the package
        import nvdiffrast.torch  # noqa: F401
    except Exception as exc:  # a broken CUDA install is a reason, not a traceback
        return False, f"the GPU stack failed to load: {exc}"
    return True, ""


class GpuEngine:
    """nvdiffrast rasteriser; same interface as the numba engine (see module docstring: untested)."""

    name = "gpu"
    views_per_call = 256

    def __init__(self, scene: RenderScene):
        ok, why = gpu_status()
        if not ok:
            raise RenderError(f"the GPU engine is not available: {why}. {INSTALL_HINT}")
        import nvdiffrast.torch as dr  # optional dependency, loaded only when used
        import torch  # optional dependency, loaded only when used

        self._torch, self._dr = torch, dr
        self.scene = scene
        self._dev = torch.device("cuda")
        self._ctx = dr.RasterizeCudaContext(device=self._dev)
        t = scene.num_triangles
        self._verts = torch.from_numpy(scene.tri_xyz.reshape(-1, 3).astype(np.float32)).to(self._dev)
        self._tris = torch.arange(3 * t, dtype=torch.int32, device=self._dev).reshape(t, 3)
        self._classes = torch.from_numpy(scene.classes.astype(np.int64)).to(self._dev)

    def render(
        self,
        camera: Camera,
        R_cams_from_local: np.ndarray,
        t_cams_from_local: np.ndarray,
        depth: bool = False,
        face_ids: bool = False,
    ) -> RenderOutput:
        torch, dr = self._torch, self._dr
        n, h, w = len(R_cams_from_local), camera.height, camera.width
        labels = np.empty((n, h, w), dtype=np.uint8)
        dep = np.empty((n, h, w), dtype=np.float32) if depth else None
        ids_out = np.empty((n, h, w), dtype=np.int32) if face_ids else None
        n_, f_ = GPU_NEAR_M, GPU_FAR_M
        for s in range(0, n, self.views_per_call):
            batch = slice(s, s + self.views_per_call)
            R = torch.from_numpy(R_cams_from_local[batch].astype(np.float32)).to(self._dev)
            t = torch.from_numpy(t_cams_from_local[batch].astype(np.float32)).to(self._dev)
            cam = torch.einsum("bij,vj->bvi", R, self._verts) + t[:, None, :]  # (B, V, 3)
            x, y, z = cam[..., 0], cam[..., 1], cam[..., 2]
            clip = torch.stack(
                [
                    (2 * camera.fx / w) * x + (2 * camera.cx / w - 1) * z,
                    (2 * camera.fy / h) * y + (2 * camera.cy / h - 1) * z,
                    (f_ + n_) / (f_ - n_) * z - 2 * f_ * n_ / (f_ - n_),
                    z,
                ],
                dim=-1,
            ).contiguous()
            rast, _ = dr.rasterize(self._ctx, clip, self._tris, resolution=[h, w])
            tri = rast[..., 3].round().long() - 1  # (B, H, W), -1 = empty
            hit = tri >= 0
            lab = torch.where(hit, self._classes[tri.clamp(min=0)], torch.zeros_like(tri))
            m = len(R)
            labels[s : s + m] = lab.to(torch.uint8).cpu().numpy()
            if face_ids:
                ids_out[s : s + m] = tri.to(torch.int32).cpu().numpy()
            if depth:
                zattr = z[..., None].contiguous()
                zi, _ = dr.interpolate(zattr, rast, self._tris)
                zi = torch.where(hit, zi[..., 0], torch.full_like(zi[..., 0], float("inf")))
                dep[s : s + m] = zi.cpu().numpy()
        return RenderOutput(labels=labels, depth=dep, face_ids=ids_out)

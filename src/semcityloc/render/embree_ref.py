"""Reference engine: Intel Embree ray casting (``embreex``) over the same ``RenderScene``.

One ray per pixel from the camera centre through the pixel centre (u, v) = (j + 0.5, i + 0.5). Directions
are the camera rays with z = 1 turned into the world, so the hit distance ``tfar`` IS the z-depth along the
optical axis. Embree works in float32; the scene is already float32 in the local frame.

Slower than the numba rasteriser for small masks, but independent of it: tests and the benchmark use it
to check the rasteriser's coverage and depth. ``embreex`` is an optional extra (``semcityloc[reference]``).
"""

from __future__ import annotations

import numpy as np

from semcityloc.errors import OptionalDependencyError
from semcityloc.geometry.camera import Camera
from semcityloc.render.output import RenderOutput
from semcityloc.render.scene import RenderScene

# Rays cast per Embree call (bounds the temporary arrays).
RAYS_PER_CALL = 1 << 20


def embree_available() -> bool:
    """Whether the optional ``embreex`` imports; the reference engine and its tests are offered only then."""
    try:
        # optional [reference] extra: only probed here, never imported with the package
        import embreex.mesh_construction  # noqa: F401
        import embreex.rtcore_scene  # noqa: F401
    except ImportError:
        return False
    return True


class EmbreeEngine:
    """Ray-cast labels / z-depth / face ids; same interface as the numba engine."""

    name = "embree"

    def __init__(self, scene: RenderScene):
        try:
            from embreex import rtcore_scene as rtcs  # optional dependency, loaded only when used
            from embreex.mesh_construction import TriangleMesh  # optional dependency, loaded only when used
        except ImportError as exc:
            raise OptionalDependencyError("embreex", "reference", "the Embree reference renderer") from exc
        self.scene = scene
        self._embree = rtcs.EmbreeScene()
        # Keep a reference: Embree shares the buffer.
        self._corners = np.ascontiguousarray(scene.corners, dtype=np.float32)
        TriangleMesh(self._embree, self._corners)

    def render(
        self,
        camera: Camera,
        R_cams_from_local: np.ndarray,
        t_cams_from_local: np.ndarray,
        depth: bool = False,
        face_ids: bool = False,
    ) -> RenderOutput:
        n, h, w = len(R_cams_from_local), camera.height, camera.width
        rays_cam = camera.ray_directions(normalize=False).reshape(-1, 3)  # z = 1
        npx = h * w
        ids = np.empty((n, npx), dtype=np.int32)
        dep = np.empty((n, npx), dtype=np.float32) if depth else None
        views_per_call = max(1, RAYS_PER_CALL // npx)
        for s in range(0, n, views_per_call):
            R, t = R_cams_from_local[s : s + views_per_call], t_cams_from_local[s : s + views_per_call]
            centres = -np.einsum("nji,nj->ni", R, t)  # (m, 3)
            dirs = np.einsum("nji,pj->npi", R, rays_cam)  # R^T ray, (m, P, 3)
            origins = np.broadcast_to(centres[:, None, :], dirs.shape)
            hit = self._embree.run(
                np.ascontiguousarray(origins.reshape(-1, 3), dtype=np.float32),
                np.ascontiguousarray(dirs.reshape(-1, 3), dtype=np.float32),
                output=1,
            )
            prim = hit["primID"].reshape(len(R), npx)
            ids[s : s + len(R)] = prim
            if depth:
                tfar = hit["tfar"].reshape(len(R), npx).astype(np.float32)
                dep[s : s + len(R)] = np.where(prim >= 0, tfar, np.float32(np.inf))
        labels = np.where(ids >= 0, self.scene.classes[np.maximum(ids, 0)], 0).astype(np.uint8)
        return RenderOutput(
            labels=labels.reshape(n, h, w),
            depth=dep.reshape(n, h, w) if depth else None,
            face_ids=ids.reshape(n, h, w) if face_ids else None,
        )

"""Cast shadows of the simulated reality: a sun direction per query and a shadow mask per view.

Why: a segmentation network errs more in cast shadows (dark ground taken for a facade, shaded roof parts
for ground); issue 12 asks for shadows computed from the geometry, so that these errors sit where a real
image would have them.

``sun_direction(rng)``: the unit vector from the scene TOWARD the sun in the local frame (x east, y
north, z up). Elevation uniform in ``SUN_ELEVATION_DEG`` = 25-65 deg (daytime survey flights at central
European latitudes: the sun stands 15-62 deg high at noon over the year in Berlin / Fuerth, and flights
avoid the long shadows of low sun; a judgement, not a measurement), azimuth uniform in [0, 360) deg,
clockwise from north (compass bearing of the sun).

``shadow_mask(renderer, camera, pose_local, depth, sun_dir)``: every pixel with a finite depth is
unprojected to its 3D point; a depth map of the scene is rendered from a "sun camera" (a pinhole camera
``SUN_DISTANCE_M`` = 50 km away along ``sun_dir``, looking back along -``sun_dir``, whose field of view just
covers the points: within 0.6 deg of parallel light for a 1 km wide view) and a pixel is in shadow when
the surface the sun camera sees at the point's sun pixel is nearer to the sun than the point by more than
a bias (``bias_m`` plus the slope term ``sun pixel size x tan(angle between the surface normal and the
sun)``, capped at ``MAX_SLOPE_TAN``: the depth a surface spans within one sun pixel). When normals are
given, surfaces that face away from the sun (normal . sun <= 0: attached shadow, e.g. the facades on a
building's shaded side) are in shadow too, or, with ``attached=False``, left out (only cast shadows on
sunward surfaces: what ``seg_errors`` uses, since networks handle a facade's own shade well). The sun
map's pixel is the query's ground sample distance near the camera (10th percentile of depth / fx), at
least ``MIN_SUN_PX_M``, made coarser when the points' extent would need more than ``max_px`` pixels.
Points off the sun map (none by construction) count as lit.
"""

from __future__ import annotations

import math

import numpy as np

from semcityloc.errors import ShapeError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose

SUN_ELEVATION_DEG = (25.0, 65.0)
SUN_DISTANCE_M = 50_000.0
MIN_SUN_PX_M = 0.1  # finest sun-map pixel (metres at the scene)
MAX_SUN_PX = 2048  # longest side of the sun map
MAX_SLOPE_TAN = 4.0  # cap of the slope-scaled bias term (a surface 76 deg off the sun)
SHADOW_BIAS_M = 0.15


def sun_direction(rng: np.random.Generator) -> np.ndarray:
    """(3,) float64 unit vector toward the sun (module docstring): elevation uniform in 25-65 deg,
    azimuth uniform, clockwise from north."""
    elevation = float(rng.uniform(*SUN_ELEVATION_DEG))
    return sun_from_angles(elevation, float(rng.uniform(0.0, 360.0)))


def sun_from_angles(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """The unit vector toward a sun at ``elevation_deg`` above the horizon, ``azimuth_deg`` clockwise from
    north."""
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    return np.array([math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e)])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def sun_rotation(sun_dir: np.ndarray) -> np.ndarray:
    """R_world_from_cam (3, 3) of a camera looking along -``sun_dir`` (columns: image x, image y, axis)."""
    z = -_unit(np.asarray(sun_dir, dtype=np.float64))
    helper = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = _unit(np.cross(helper, z))
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


def world_points(camera: Camera, pose_local: Pose, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(valid (H, W) bool, points (N, 3) float64 in the local frame) of the pixels with a finite depth."""
    d = np.asarray(depth, dtype=np.float64)
    if d.shape != (camera.height, camera.width):
        raise ShapeError(f"depth {d.shape} does not match the camera ({camera.height}, {camera.width})")
    valid = np.isfinite(d) & (d > 0)
    rows, cols = np.nonzero(valid)
    uv = np.stack([cols + 0.5, rows + 0.5], 1)  # pixel centres
    return valid, pose_local.points_to_world(camera.unproject(uv, d[valid]))


def _apply(M: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``p @ M.T`` for (N, 3) points, elementwise (no BLAS: identical on every machine, and not slowed by
    a busy multi-threaded BLAS)."""
    return p[:, :1] * M[:, 0] + p[:, 1:2] * M[:, 1] + p[:, 2:3] * M[:, 2]


def shadow_mask(
    renderer,
    camera: Camera,
    pose_local: Pose,
    depth: np.ndarray,
    sun_dir: np.ndarray,
    *,
    normals: np.ndarray | None = None,
    attached: bool = True,
    bias_m: float = SHADOW_BIAS_M,
    max_px: int = MAX_SUN_PX,
    distance_m: float = SUN_DISTANCE_M,
) -> np.ndarray:
    """(H, W) bool: pixels whose 3D point (unprojected with ``depth``, z-depth, +inf = nothing) is hidden
    from the sun by the scene of ``renderer`` (module docstring). ``normals``: optional (H, W, 3) unit
    normals of the hit surfaces (any sign) for the slope-scaled bias and attached shadows; with normals,
    ``attached=False`` leaves the surfaces facing away from the sun out (cast shadows on sunward
    surfaces only)."""
    s = _unit(np.asarray(sun_dir, dtype=np.float64).reshape(3))
    valid, pts = world_points(camera, pose_local, depth)
    out = np.zeros(valid.shape, dtype=bool)
    if len(pts) == 0:
        return out
    Rws = sun_rotation(s)
    centre = pts.mean(0) + distance_m * s
    q = _apply(Rws.T, pts - centre)  # sun-camera coordinates
    un, vn = q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]
    d = np.asarray(depth, dtype=np.float64)[valid]
    px_m = max(float(np.percentile(d, 10)) / camera.fx, MIN_SUN_PX_M)
    span = max(float(un.max() - un.min()), float(vn.max() - vn.min())) * distance_m
    px_m = max(px_m, span / max(int(max_px) - 4, 1))
    f = distance_m / px_m
    width = int(math.ceil((un.max() - un.min()) * f)) + 4
    height = int(math.ceil((vn.max() - vn.min()) * f)) + 4
    cx, cy = 2.0 - un.min() * f, 2.0 - vn.min() * f
    sun_cam = Camera(f, f, cx, cy, width, height)
    sun_pose = Pose.from_rotation_center(Rws, centre)
    sun_depth = renderer.render(sun_cam, sun_pose, depth=True).depth[0]
    col = np.floor(un * f + cx).astype(np.intp)
    row = np.floor(vn * f + cy).astype(np.intp)
    inside = (col >= 0) & (col < width) & (row >= 0) & (row < height)
    seen = np.full(len(pts), np.inf)
    seen[inside] = sun_depth[row[inside], col[inside]]
    bias = np.full(len(pts), float(bias_m) + px_m * MAX_SLOPE_TAN / 2)
    facing_away = np.zeros(len(pts), dtype=bool)
    if normals is not None:
        n = np.asarray(normals, dtype=np.float64)
        if n.shape != valid.shape + (3,):
            raise ShapeError(f"normals must have shape {valid.shape + (3,)}, got {n.shape}")
        n = n[valid]
        ok = np.all(np.isfinite(n), axis=1)
        # Orient each normal toward the camera (the visible side), then compare with the sun.
        view = pts - pose_local.center
        n = np.where((np.einsum("ij,ij->i", n, view) > 0)[:, None], -n, n)
        cos = np.einsum("ij,j->i", n, s)
        tan = np.sqrt(np.maximum(1.0 - cos**2, 0.0)) / np.maximum(np.abs(cos), 1e-6)
        bias = np.where(ok, float(bias_m) + px_m * np.minimum(tan, MAX_SLOPE_TAN), bias)
        facing_away = ok & (cos <= 0.0)
    cast = q[:, 2] > seen + bias
    out[valid] = (cast | facing_away) if attached else (cast & ~facing_away)
    return out

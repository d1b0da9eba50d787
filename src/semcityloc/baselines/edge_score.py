"""Scoring poses against an edge-probability map: the map pyramid and the fused numba kernels.

Why its own module: the wireframe search scores ~24,000 pose hypotheses x a few thousand model edge
points per stage, three stages per query. The kernel ``grid_scores`` exploits the grid's structure: all
hypotheses share roll and pitch, so for each yaw the rotated points ``Q_y = M_y P`` are computed once
(``M_y`` the cam_from_world rotation of that yaw) and a hypothesis with centre ``C`` only subtracts
``M_y C``: per point three subtractions, a division and a bilinear lookup.

Score of a pose = mean over ALL map points of the bilinearly interpolated edge probability at their
projections; points behind the camera or outside the image count 0 (LoD-Loc averages over all points
too; it clamps outside points to the border instead, see docs/baselines.md).

Pixel convention (``geometry/camera.py``): pixel (row i, col j) holds the value at image coordinates
(j + 0.5, i + 0.5). Coordinates outside [0, W) x [0, H) read 0; inside, the half-pixel border
replicates the edge pixels.

``EdgePyramid``: the query map resampled to the working resolution and to each stage's resolution
(block max when shrinking, so thin lines survive; bilinear when enlarging), then blurred with a
Gaussian scaled so that a 1 px line of value 1 keeps a peak of 1 (``edge_sim.blur_normalised``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange
from scipy import ndimage

from semcityloc.baselines.edge_sim import blur_normalised
from semcityloc.errors import ShapeError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose

NEAR_M = 0.5  # points closer than this to the camera plane score 0


# ------------------------------------------------------------------------------------------ kernels
def pad_map(emap: np.ndarray) -> np.ndarray:
    """The map with a one-pixel border replicating its edge pixels, float32: the kernels' lookup form.

    Image coordinates (u, v) inside [0, W) x [0, H) read the padded map at (u + 0.5, v + 0.5) with plain
    bilinear weights and no clamping."""
    return np.ascontiguousarray(np.pad(np.asarray(emap, dtype=np.float32), 1, mode="edge"))


@njit(cache=True, inline="always", fastmath=True)
def _lookup(pmap, width, height, u, v):
    """Bilinear value at image coordinates (u, v) of the padded map; 0 outside [0, W) x [0, H)."""
    x = u + 0.5
    y = v + 0.5
    if not (x >= 0.5 and x < width + 0.5 and y >= 0.5 and y < height + 0.5):
        return 0.0
    c0 = int(x)
    r0 = int(y)
    ax = x - c0
    ay = y - r0
    top = pmap[r0, c0] + (pmap[r0, c0 + 1] - pmap[r0, c0]) * ax
    bottom = pmap[r0 + 1, c0] + (pmap[r0 + 1, c0 + 1] - pmap[r0 + 1, c0]) * ax
    return top + (bottom - top) * ay


@njit(parallel=True, cache=True, fastmath=True)
def grid_scores(Qx, Qy, Qz, T, fx, fy, cx, cy, pmap, width, height, near, out):
    """Mean edge probability of every (centre, yaw) hypothesis.

    Qx, Qy, Qz: (Y, N) coordinates of the points rotated by each yaw's cam_from_world rotation; T:
    (Y, C, 3) that rotation applied to each centre, so a point's camera coordinates are
    ``Q[y, i] - T[y, c]``. pmap: ``pad_map`` of the (height, width) map. out: (C, Y) float64.
    """
    n_yaw, n_pts = Qx.shape
    n_centres = T.shape[1]
    inv_n = 1.0 / max(n_pts, 1)
    for c in prange(n_centres):
        for y in range(n_yaw):
            tx, ty, tz = T[y, c, 0], T[y, c, 1], T[y, c, 2]
            acc = 0.0
            for i in range(n_pts):
                z = Qz[y, i] - tz
                if z <= near:
                    continue
                iz = 1.0 / z
                u = fx * (Qx[y, i] - tx) * iz + cx
                v = fy * (Qy[y, i] - ty) * iz + cy
                acc += _lookup(pmap, width, height, u, v)
            out[c, y] = acc * inv_n


@njit(parallel=True, cache=True, fastmath=True)
def pose_scores(
    points_local, R_cams_from_local, t_cams_from_local, fx, fy, cx, cy, pmap, width, height, near, out
):
    """Mean edge probability of ``points_local`` (N, 3) at each pose (``R_cams_from_local`` (K, 3, 3),
    ``t_cams_from_local`` (K, 3)); out (K,)."""
    n_pts = points_local.shape[0]
    inv_n = 1.0 / max(n_pts, 1)
    for k in prange(R_cams_from_local.shape[0]):
        R_cam_from_local = R_cams_from_local[k]
        t_cam_from_local = t_cams_from_local[k]
        r00, r01, r02 = R_cam_from_local[0, 0], R_cam_from_local[0, 1], R_cam_from_local[0, 2]
        r10, r11, r12 = R_cam_from_local[1, 0], R_cam_from_local[1, 1], R_cam_from_local[1, 2]
        r20, r21, r22 = R_cam_from_local[2, 0], R_cam_from_local[2, 1], R_cam_from_local[2, 2]
        t0, t1, t2 = t_cam_from_local[0], t_cam_from_local[1], t_cam_from_local[2]
        acc = 0.0
        for i in range(n_pts):
            X, Y, Z = points_local[i, 0], points_local[i, 1], points_local[i, 2]
            z = r20 * X + r21 * Y + r22 * Z + t2
            if z <= near:
                continue
            iz = 1.0 / z
            u = fx * (r00 * X + r01 * Y + r02 * Z + t0) * iz + cx
            v = fy * (r10 * X + r11 * Y + r12 * Z + t1) * iz + cy
            acc += _lookup(pmap, width, height, u, v)
        out[k] = acc * inv_n


def sample_bilinear(
    emap: np.ndarray, u: np.ndarray, v: np.ndarray, pmap: np.ndarray | None = None
) -> np.ndarray:
    """numpy twin of the kernels' lookup: values at image coordinates (u, v), 0 outside the image.

    Pass ``pmap = pad_map(emap)`` when calling many times on the same map."""
    h, w = emap.shape
    pm = pad_map(emap) if pmap is None else pmap
    x = np.asarray(u, dtype=np.float64) + 0.5
    y = np.asarray(v, dtype=np.float64) + 0.5
    inside = (x >= 0.5) & (x < w + 0.5) & (y >= 0.5) & (y < h + 0.5)
    x, y = np.where(inside, x, 1.0), np.where(inside, y, 1.0)
    c0, r0 = x.astype(np.int64), y.astype(np.int64)
    ax, ay = x - c0, y - r0
    top = pm[r0, c0] + (pm[r0, c0 + 1] - pm[r0, c0]) * ax
    bottom = pm[r0 + 1, c0] + (pm[r0 + 1, c0 + 1] - pm[r0 + 1, c0]) * ax
    return np.where(inside, top + (bottom - top) * ay, 0.0)


def score_poses(points_local: np.ndarray, poses_local: Pose, camera: Camera, emap: np.ndarray) -> np.ndarray:
    """Mean edge probability of ``points_local`` (N, 3) at each of ``poses_local`` (single or batch)
    on ``emap`` (H, W) seen by ``camera`` (same size). Returns (K,) float64."""
    if emap.shape != (camera.height, camera.width):
        raise ShapeError(f"edge map {emap.shape} does not match the camera ({camera.height}, {camera.width})")
    R_cams_from_local = np.ascontiguousarray(poses_local.R.reshape(-1, 3, 3))
    t_cams_from_local = np.ascontiguousarray(poses_local.t.reshape(-1, 3))
    out = np.empty(len(R_cams_from_local))
    pose_scores(
        np.ascontiguousarray(points_local, dtype=np.float64),
        R_cams_from_local,
        t_cams_from_local,
        camera.fx,
        camera.fy,
        camera.cx,
        camera.cy,
        pad_map(emap),
        camera.width,
        camera.height,
        NEAR_M,
        out,
    )
    return out


# ------------------------------------------------------------------------------------------ the map
def check_edge_map(edge_map: np.ndarray, camera: Camera) -> np.ndarray:
    """The query edge map as float64 (H, W) in [0, 1] (non-finite -> 0, clipped); ``ShapeError`` unless it
    is a non-empty numeric 2D array with the camera's aspect ratio (within 2 %)."""
    arr = np.asarray(edge_map)
    if arr.ndim != 2 or arr.size == 0:
        raise ShapeError(f"edge map must be a non-empty (H, W) array, got shape {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise ShapeError(f"edge map must hold numbers (probabilities in [0, 1]), got dtype {arr.dtype}")
    h, w = arr.shape
    if abs((w / h) / (camera.width / camera.height) - 1.0) > 0.02:
        raise ShapeError(
            f"edge map {w}x{h} does not have the camera's aspect ({camera.width}x{camera.height})"
        )
    arr = arr.astype(np.float64)
    return np.clip(np.where(np.isfinite(arr), arr, 0.0), 0.0, 1.0)


def resample_max(img: np.ndarray, height: int, width: int) -> np.ndarray:
    """(height, width) version of ``img``: block maximum when shrinking, bilinear when enlarging."""
    h, w = img.shape
    if (h, w) == (height, width):
        return img.copy()
    if h >= height and w >= width:
        rows = (np.arange(h) * height) // h
        cols = (np.arange(w) * width) // w
        idx = (rows[:, None] * width + cols[None, :]).reshape(-1)
        out = np.zeros(height * width)
        np.maximum.at(out, idx, img.reshape(-1))
        return out.reshape(height, width)
    return ndimage.zoom(img, (height / h, width / w), order=1, mode="nearest", grid_mode=True)


@dataclass
class EdgeLevel:
    """One resolution of the query map: its camera, the (H, W) float32 map and its ``pad_map`` form."""

    camera: Camera
    emap: np.ndarray
    padded: np.ndarray = None  # type: ignore[assignment]

    def __post_init__(self) -> None:
        self.emap = np.ascontiguousarray(self.emap, dtype=np.float32)
        self.padded = pad_map(self.emap)


class EdgePyramid:
    """The query map at the working resolution and at each stage's resolution (module docstring)."""

    def __init__(
        self,
        edge_map: np.ndarray,
        camera: Camera,
        width: int,
        scales: tuple[float, ...],
        blurs_px: tuple[float, ...],
        refine_blur_px: float,
    ):
        base = check_edge_map(edge_map, camera)
        height = max(1, round(width * camera.height / camera.width))
        self.camera = camera.scaled(width, height)
        self.base = resample_max(base, height, width)
        self.levels: list[EdgeLevel] = []
        for scale, blur in zip(scales, blurs_px, strict=True):
            w = max(8, round(width * scale))
            h = max(6, round(w * height / width))
            img = resample_max(self.base, h, w)
            self.levels.append(EdgeLevel(self.camera.scaled(w, h), blur_normalised(img, blur)))
        self.refine = EdgeLevel(self.camera, blur_normalised(self.base, refine_blur_px))

    def edge_fraction(self, threshold: float = 0.2) -> float:
        """Share of working-resolution pixels with edge probability above ``threshold``."""
        return float(np.mean(self.base > threshold))

"""Coarse pose selection: a 4D (x, y, z, yaw) semantic cost volume around the prior (paper Sec. 3.1).

Roll and pitch stay at the prior's (gravity). The hypotheses are a uniform grid: along each axis
``n`` samples from ``prior - range/2`` to ``prior + range/2``. Hypotheses sharing a camera centre differ
only by a rotation about world z through that centre, so each centre is rendered once, at a wider field
of view, and every yaw reads its pixels through a lookup table (``yaw_lookup``): a pure rotation maps
rays to rays, independent of the scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose, rotation_about_world_z
from semcityloc.localization.config import CoarseConfig
from semcityloc.localization.kernels import N_SLOTS, coarse_scores
from semcityloc.render.raster_numba import NEAR_M, work_chunks
from semcityloc.render.scene import RenderScene

# Wide render focal length relative to the target's: > 1 samples the wide view finer than the target so
# nearest-neighbour lookups agree with direct renders more often. Measured on Berlin at 64x48, 13 yaws over
# 18 deg, 20 nadir/oblique centres: agreement 95.3% at 1.0, 96.9% at 1.5, 97.3% at 2.0 for ~14% more time.
WIDE_OVERSAMPLE = 1.0  # default of CoarseConfig.wide_oversample


@dataclass
class CostVolume:
    """Scores of the coarse grid, axis order (x, y, z, yaw); ``*_values`` are the sample positions
    (local frame metres / degrees of yaw)."""

    scores: np.ndarray  # (nx, ny, nz, nyaw) float64, mean per-class IoU
    x_values: np.ndarray
    y_values: np.ndarray
    z_values: np.ndarray
    yaw_values: np.ndarray
    roll: float
    pitch: float

    def best_indices(self, k: int = 1) -> np.ndarray:
        """(k, 4) grid indices of the k best cells, best first."""
        flat = self.scores.reshape(-1)
        k = min(k, flat.size)
        top = np.argpartition(-flat, k - 1)[:k]
        top = top[np.argsort(-flat[top], kind="stable")]
        return np.stack(np.unravel_index(top, self.scores.shape), axis=1)

    def score_margin(self) -> float:
        """Best score minus the best score of cells more than 2 grid steps away in x or y: how much the
        winner stands out from look-alikes elsewhere (small = ambiguous). NaN if the grid is too small."""
        s = self.scores
        best = np.unravel_index(int(np.argmax(s)), s.shape)
        far = np.ones(s.shape[:2], dtype=bool)
        far[max(0, best[0] - 2) : best[0] + 3, max(0, best[1] - 2) : best[1] + 3] = False
        if not far.any():
            return float("nan")
        return float(s[best] - s[far].max())

    def xyz_rpy(self, index: np.ndarray) -> np.ndarray:
        """(x, y, z, roll, pitch, yaw) of a grid cell."""
        i, j, k, l = (int(v) for v in index)
        return np.array(
            [self.x_values[i], self.y_values[j], self.z_values[k], self.roll, self.pitch, self.yaw_values[l]]
        )

    def as_dict(self) -> dict:
        return {
            "shape": list(self.scores.shape),
            "x": self.x_values.tolist(),
            "y": self.y_values.tolist(),
            "z": self.z_values.tolist(),
            "yaw": self.yaw_values.tolist(),
            "roll": self.roll,
            "pitch": self.pitch,
        }


def axis_samples(centre: float, full_range: float, n: int) -> np.ndarray:
    if n <= 1:
        return np.array([centre], dtype=np.float64)
    return centre + np.linspace(-full_range / 2, full_range / 2, n)


def yaw_lookup(
    camera: Camera, R_base: np.ndarray, yaw_offsets_deg: np.ndarray, oversample: float = WIDE_OVERSAMPLE
) -> tuple[Camera, np.ndarray]:
    """Wide camera and lookup table for a fan of yaws around one base orientation.

    ``R_base``: cam_from_world rotation of the base (yaw offset 0) view. The target camera turned by
    ``d`` about world z has ``R_d = R_base @ Rz(d)^T``; its pixel ray r maps into the base (wide) camera
    frame as ``R_base Rz(d) R_base^T r``. Returns the wide camera (same orientation as the base, focal x
    ``oversample``, principal point and size covering all rays) and an int32 (Y, H*W) table of wide
    pixel indices (-1 where a ray points behind the wide camera).
    """
    rays = camera.ray_directions().reshape(-1, 3)  # target pixel centres, z = 1
    M = R_base @ rotation_about_world_z(yaw_offsets_deg) @ R_base.T  # (Y, 3, 3)
    d = np.einsum("yij,pj->ypi", M, rays)
    front = d[..., 2] > 1e-6
    z = np.where(front, d[..., 2], 1.0)
    fx, fy = camera.fx * oversample, camera.fy * oversample
    u = fx * d[..., 0] / z
    v = fy * d[..., 1] / z
    umin, umax = u[front].min(), u[front].max()
    vmin, vmax = v[front].min(), v[front].max()
    margin = 1.0
    # Whole-pixel offsets from the target's principal point (scaled): the zero-yaw view then samples
    # exactly the target's pixel centres when oversample is 1.
    cx = camera.cx * oversample + math.ceil(margin - umin - camera.cx * oversample)
    cy = camera.cy * oversample + math.ceil(margin - vmin - camera.cy * oversample)
    width = int(math.ceil(cx + umax + margin))
    height = int(math.ceil(cy + vmax + margin))
    wide = Camera(fx, fy, cx, cy, width, height)
    col = np.floor(u + cx).astype(np.int64)
    row = np.floor(v + cy).astype(np.int64)
    inside = front & (col >= 0) & (col < width) & (row >= 0) & (row < height)
    lut = np.where(inside, row * width + col, -1).astype(np.int32)
    return wide, lut


def coarse_search(
    scene: RenderScene,
    camera: Camera,
    prior_xyz_rpy: np.ndarray,
    query_labels: np.ndarray,
    class_on: np.ndarray,
    config: CoarseConfig,
) -> CostVolume:
    """Score the whole 4D grid. ``camera`` is at the coarse resolution; ``query_labels`` flat uint8 at it."""
    x0, y0, z0, roll, pitch, yaw0 = (float(v) for v in prior_xyz_rpy)
    xs = axis_samples(x0, config.range_xy_m, config.n_xy)
    ys = axis_samples(y0, config.range_xy_m, config.n_xy)
    zs = axis_samples(z0, config.range_z_m, config.n_z)
    yaw_offsets = axis_samples(0.0, config.range_yaw_deg, config.n_yaw)
    base = Pose.from_xyz_rpy(np.zeros(3), roll, pitch, yaw0)
    wide, lut = yaw_lookup(camera, base.R, yaw_offsets, config.wide_oversample)
    gx, gy, gz = np.meshgrid(xs, ys, zs, indexing="ij")
    centres = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
    Rs = np.ascontiguousarray(np.broadcast_to(base.R, (len(centres), 3, 3)))
    ts = -centres @ base.R.T
    scores = np.empty((len(centres), len(yaw_offsets)))
    coarse_scores(
        scene.tri_xyz,
        scene.classes,
        scene.tile_start,
        scene.tile_bbox,
        scene.block_start,
        scene.block_bbox,
        Rs,
        np.ascontiguousarray(ts),
        wide.fx,
        wide.fy,
        wide.cx,
        wide.cy,
        wide.width,
        wide.height,
        NEAR_M,
        lut,
        np.ascontiguousarray(query_labels, dtype=np.uint8),
        _slots(class_on),
        scores,
        work_chunks(len(centres)),
    )
    return CostVolume(
        scores=scores.reshape(len(xs), len(ys), len(zs), len(yaw_offsets)),
        x_values=xs,
        y_values=ys,
        z_values=zs,
        yaw_values=yaw0 + yaw_offsets,
        roll=roll,
        pitch=pitch,
    )


def _slots(class_on: np.ndarray) -> np.ndarray:
    slots = np.zeros(N_SLOTS, dtype=np.bool_)
    slots[: len(class_on)] = class_on
    return slots

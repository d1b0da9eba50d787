"""Coarse pose selection: a 4D (x, y, z, yaw) semantic cost volume around the prior (paper Sec. 3.1).

``score_rotations`` is the shared primitive: hypotheses sharing a camera centre differ only by a rotation
about it, so each centre is rendered once, at a wider field of view, and every rotation reads its pixels
through a lookup table (``rotation_lookup``; ``yaw_lookup`` for a fan of yaws): a pure rotation maps rays
to rays, independent of the scene. The cascade search (``cascade.py``) and the first design's uniform
grid (``coarse_search``: along each axis ``n`` samples from ``prior - range/2`` to ``prior + range/2``,
roll and pitch at the prior's) both score through it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from semcityloc.errors import CameraError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose, rotation_about_world_z, yaw_fan_rotations
from semcityloc.localization.config import CoarseConfig
from semcityloc.localization.kernels import N_SLOTS, coarse_scores
from semcityloc.render.raster_numba import NEAR_M, work_chunks
from semcityloc.render.scene import RenderScene

# Wide render focal length relative to the target's: > 1 samples the wide view finer than the target so
# nearest-neighbour lookups agree with direct renders more often. Measured on Berlin at 64x48, 13 yaws over
# 18 deg, 20 nadir/oblique centres: agreement 95.3% at 1.0, 96.9% at 1.5, 97.3% at 2.0 for ~14% more time.
WIDE_OVERSAMPLE = 1.0  # default of CoarseConfig.wide_oversample
# A hypothesis' ray turned more than this from the wide view's axis reads nothing (as a ray behind it):
# near 90 deg a pinhole's image coordinate runs to infinity, and the wide view with it. The views of the
# benchmark and of real drones stay far below (a 70 deg camera's corner rays lie 41 deg off its axis).
MAX_WIDE_RAY_DEG = 80.0
# A fan of yaws whose rays reach beyond ``MAX_WIDE_RAY_DEG`` of one wide view (an oblique view turned by
# tens of degrees: a prior without a heading) is scored in sectors (``yaw_sectors``), each read from a wide
# view of its own at its middle yaw, cut until every ray lies within this of its sector's axis (a 70 deg
# camera's corner rays lie 41 deg off its axis: a full circle is 8 sectors of 45 deg for a view 30-84 deg
# from nadir, one for a view up to 20 deg from it, which turns about nearly its own axis).
SECTOR_MAX_RAY_DEG = 60.0
# The wide view's size bound: a few thousand pixels in every search the project measured; tens of millions
# only for intrinsics or rotation ranges no drone photo has.
MAX_WIDE_PIXELS = 4_000_000


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
        """The axes' values and the shape (not the scores), for a query's details file."""
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
    """``n`` evenly spaced samples over ``full_range`` centred on ``centre`` (ends included; the centre alone
    when ``n`` <= 1): one axis of the grid search.
    """
    if n <= 1:
        return np.array([centre], dtype=np.float64)
    return centre + np.linspace(-full_range / 2, full_range / 2, n)


def rotation_lookup(
    camera: Camera, offsets: np.ndarray, oversample: float = WIDE_OVERSAMPLE
) -> tuple[Camera, np.ndarray]:
    """Wide camera and lookup table for a set of rotations about one camera centre.

    ``offsets``: (Y, 3, 3) camera-frame rotations ``A_h``; hypothesis h has cam_from_world
    ``R_h = A_h @ R_base`` where ``R_base`` is the wide (base) view's. A pixel ray r of hypothesis h is the
    ray ``A_h^T r`` of the base camera: a pure rotation maps rays to rays, whatever the scene and wherever
    the centre, so one table serves every centre with that base. Returns the wide camera (the base
    orientation, focal x ``oversample``, principal point and size covering every hypothesis' rays) and an
    int32 (Y, H*W) table of wide pixel indices (-1 where a ray points behind the wide camera).
    """
    rays = camera.ray_directions().reshape(-1, 3)  # target pixel centres, z = 1
    # d[y, p] = A_y^T rays[p]; batched matmul (einsum is ~10x slower here).
    d = np.matmul(rays[None], np.asarray(offsets, dtype=np.float64))
    front = _within(d, MAX_WIDE_RAY_DEG)
    if not front.any():
        raise CameraError("every ray of the search's rotations points away from its wide view")
    z = np.where(front, d[..., 2], 1.0)
    fx, fy = camera.fx * oversample, camera.fy * oversample
    u = fx * d[..., 0] / z
    v = fy * d[..., 1] / z
    u_front, v_front = u[front], v[front]
    umin, umax = u_front.min(), u_front.max()
    vmin, vmax = v_front.min(), v_front.max()
    margin = 1.0
    # Whole-pixel offsets from the target's principal point (scaled): a hypothesis equal to the base
    # then samples exactly the target's pixel centres when oversample is 1.
    cx = camera.cx * oversample + math.ceil(margin - umin - camera.cx * oversample)
    cy = camera.cy * oversample + math.ceil(margin - vmin - camera.cy * oversample)
    width = int(math.ceil(cx + umax + margin))
    height = int(math.ceil(cy + vmax + margin))
    if width * height > MAX_WIDE_PIXELS:
        raise CameraError(
            f"the search's rotations need a {width}x{height} wide view of this "
            f"{camera.hfov_deg:.3g} deg camera (at most {MAX_WIDE_PIXELS:,} pixels): state a smaller yaw or "
            "roll/pitch uncertainty, or check the intrinsics"
        )
    wide = Camera(fx, fy, cx, cy, width, height)
    col = np.floor(u + cx).astype(np.int64)
    row = np.floor(v + cy).astype(np.int64)
    inside = front & (col >= 0) & (col < width) & (row >= 0) & (row < height)
    lut = np.where(inside, row * width + col, -1).astype(np.int32)
    return wide, lut


def rotation_offsets(R_base: np.ndarray, R_hyps: np.ndarray) -> np.ndarray:
    """(Y, 3, 3) camera-frame offsets ``A_h = R_h @ R_base^T`` of cam_from_world rotations ``R_hyps``.
    Hypotheses that differ from their base only in yaw about world z have offsets that do not depend on
    the base's yaw: bases that share roll and pitch share one lookup table."""
    return np.asarray(R_hyps, dtype=np.float64) @ np.asarray(R_base, dtype=np.float64).T


def yaw_lookup(
    camera: Camera, R_base: np.ndarray, yaw_offsets_deg: np.ndarray, oversample: float = WIDE_OVERSAMPLE
) -> tuple[Camera, np.ndarray]:
    """``rotation_lookup`` for a fan of yaws about world z: hypothesis d has ``R_d = R_base @ Rz(d)^T``."""
    R_hyps = np.asarray(R_base) @ np.swapaxes(rotation_about_world_z(yaw_offsets_deg), -1, -2)
    return rotation_lookup(camera, rotation_offsets(R_base, R_hyps), oversample)


def _within(d: np.ndarray, max_deg: float) -> np.ndarray:
    """Which ray directions ``d`` (..., 3) of the base camera lie within ``max_deg`` of its axis."""
    # |d| summed as ``np.linalg.norm(d, axis=-1)`` sums it, (x^2 + y^2) + z^2 (the same bits), without its
    # reduction over an axis of 3: a fifth of the time (stop 54)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return z > math.cos(math.radians(max_deg)) * np.sqrt((x * x + y * y) + z * z)


def _rays_within(rays: np.ndarray, offsets: np.ndarray, max_deg: float) -> bool:
    """Do all ``rays`` (P, 3) turned by every offset (Y, 3, 3) lie within ``max_deg`` of the base axis?"""
    return bool(np.all(_within(np.matmul(rays[None], offsets), max_deg)))


def yaw_sectors(
    camera: Camera, roll: float, pitch: float, yaws: np.ndarray, R_base: np.ndarray
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The fan of ``yaws`` (degrees, ascending) at ``roll``/``pitch`` as (base rotation, yaw indices)
    sectors, each scored through a wide view of its own. One sector on ``R_base`` when every hypothesis'
    rays lie within ``MAX_WIDE_RAY_DEG`` of its axis (every search of a heading known to a few degrees);
    else the fan halved until each sector's rays lie within ``SECTOR_MAX_RAY_DEG`` of its middle yaw's
    axis. Why: a ray turned farther reads nothing, so an oblique view turned by 90-180 deg (the heading of
    a prior without a compass) could not be scored from the prior's wide view."""
    rays = camera.ray_directions().reshape(-1, 3)
    yaws = np.asarray(yaws, dtype=np.float64)
    R_hyps = yaw_fan_rotations(roll, pitch, yaws)
    if _rays_within(rays, rotation_offsets(R_base, R_hyps), MAX_WIDE_RAY_DEG):
        return [(np.asarray(R_base), np.arange(len(yaws)))]
    out: list[tuple[np.ndarray, np.ndarray]] = []
    todo = [np.arange(len(yaws))]
    while todo:
        idx = todo.pop(0)
        base = R_hyps[idx[len(idx) // 2]]
        if len(idx) > 1 and not _rays_within(rays, rotation_offsets(base, R_hyps[idx]), SECTOR_MAX_RAY_DEG):
            half = len(idx) // 2
            todo[:0] = [idx[:half], idx[half:]]
            continue
        out.append((base, idx))
    return out


def score_rotations(
    scene: RenderScene,
    camera: Camera,
    centres: np.ndarray,
    R_bases: np.ndarray,
    offsets: np.ndarray,
    query_labels: np.ndarray,
    class_on: np.ndarray,
    oversample: float = WIDE_OVERSAMPLE,
) -> np.ndarray:
    """Mean per-class IoU of every (centre, rotation) hypothesis, (C, Y).

    ``centres`` (C, 3) in the local frame; ``R_bases`` (3, 3) or (C, 3, 3) cam_from_world rotation of each
    centre's wide render; ``offsets`` (Y, 3, 3) camera-frame rotations (``rotation_lookup``): hypothesis
    (c, h) is the pose ``R = offsets[h] @ R_bases[c]`` at centre c. ``camera``/``query_labels``: the
    scoring resolution."""
    centres = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    wide, lut = rotation_lookup(camera, offsets, oversample)
    Rs = np.ascontiguousarray(np.broadcast_to(R_bases, (len(centres), 3, 3)), dtype=np.float64)
    ts = np.ascontiguousarray(-np.einsum("cij,cj->ci", Rs, centres))
    scores = np.empty((len(centres), lut.shape[0]))
    coarse_scores(
        scene.tri_xyz,
        scene.classes,
        scene.tile_start,
        scene.tile_bbox,
        scene.block_start,
        scene.block_bbox,
        Rs,
        ts,
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
    return scores


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
    R_hyps = base.R @ np.swapaxes(rotation_about_world_z(yaw_offsets), -1, -2)
    gx, gy, gz = np.meshgrid(xs, ys, zs, indexing="ij")
    centres = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
    offsets = rotation_offsets(base.R, R_hyps)
    scores = score_rotations(
        scene, camera, centres, base.R, offsets, query_labels, class_on, config.wide_oversample
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

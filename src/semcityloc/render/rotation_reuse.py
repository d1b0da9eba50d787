"""Rotation reuse: many yaw hypotheses about ONE camera centre from a few wide renders.

Views that share a camera centre and differ only by a rotation about the world z axis through it
(``Pose.rotate_world_z``) see the same rays, so they need not each be rendered. ``render_yaw_fan``:

1. sorts the yaws around the circle and cuts them into clusters spanning at most ``max_span_deg``;
2. renders, per cluster, one WIDE pinhole view: the base pose turned by the cluster's middle yaw, with
   ``oversample`` times the target's focal length (pixels per radian) and a field of view (principal
   point off-centre if need be) that holds every target view of the cluster; all clusters share one
   wide camera, so the wide views are one batched render;
3. resamples each target from its cluster's wide view by the pure-rotation homography
   ``H = K_w R_delta K_t^-1`` (``R_delta = R_wide R_target^T``): nearest neighbour for labels and face
   ids; depth is moved along the ray: a wide z-depth ``d_w`` on the ray ``r_w = R_delta r_t`` (target ray
   with z = 1) is the target z-depth ``d_w / r_w.z``.

It is an approximation: each target pixel takes the wide pixel its centre falls in, whose centre is up to
half a wide pixel away, so labels differ from a direct render along class boundaries (measured in
``tests/test_render_rotation.py`` and ``benchmarks/bench_render.py``). Whether it is faster depends on how
many yaws share a centre: the wide views cost more than one target each (more pixels, wider view), so
it pays from a few dozen yaws per centre on; below that, render directly.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from semcityloc.errors import RenderError, ShapeError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.render.engine import check_camera, pose_arrays
from semcityloc.render.output import RenderOutput

# A cluster whose wide view would need rays this close to 90 degrees off its axis is split further.
MAX_OFF_AXIS_TAN = 4.0


def _cluster_yaws(yaws: np.ndarray, max_span: float) -> tuple[np.ndarray, np.ndarray]:
    """Assign each yaw (degrees) to a cluster spanning <= max_span; returns (cluster id, cluster mid yaw)."""
    n = len(yaws)
    w = np.mod(yaws, 360.0)
    order = np.argsort(w)
    ws = w[order]
    # Start the sweep after the largest gap so that no cluster straddles it.
    gaps = np.diff(np.append(ws, ws[0] + 360.0))
    start = (int(np.argmax(gaps)) + 1) % n
    ws = np.roll(ws, -start)
    order = np.roll(order, -start)
    unwrapped = ws.copy()
    unwrapped[unwrapped < unwrapped[0]] += 360.0
    cluster = np.empty(n, dtype=np.int64)
    mids = []
    c0 = 0
    for k in range(1, n + 1):
        if k == n or unwrapped[k] - unwrapped[c0] > max_span:
            mids.append(0.5 * (unwrapped[c0] + unwrapped[k - 1]))
            cluster[order[c0:k]] = len(mids) - 1
            c0 = k
    return cluster, np.array(mids)


def _wide_camera(
    camera: Camera, R_targets: np.ndarray, R_wides: np.ndarray, cluster: np.ndarray, oversample: float
) -> Camera | None:
    """One pinhole camera that, placed at each wide orientation, sees all of its cluster's targets.

    None when some target ray would be too far off the wide axis (cluster too wide for a pinhole).
    """
    w, h = camera.width, camera.height
    # Target image border, sampled densely enough (lines map to lines, but a corner may be the extreme).
    s = np.linspace(0.0, 1.0, 9)
    border = np.concatenate(
        [np.stack([s * w, np.zeros_like(s)], 1), np.stack([s * w, np.full_like(s, h)], 1),
         np.stack([np.zeros_like(s), s * h], 1), np.stack([np.full_like(s, w), s * h], 1)]
    )
    rays = np.stack([(border[:, 0] - camera.cx) / camera.fx, (border[:, 1] - camera.cy) / camera.fy,
                     np.ones(len(border))], 1)
    delta = R_wides[cluster] @ np.swapaxes(R_targets, 1, 2)  # (N, 3, 3): target cam -> wide cam
    rw = np.einsum("nij,pj->npi", delta, rays)
    if np.any(rw[..., 2] <= 1.0 / MAX_OFF_AXIS_TAN):
        return None
    x = rw[..., 0] / rw[..., 2]
    y = rw[..., 1] / rw[..., 2]
    if max(np.abs(x).max(), np.abs(y).max()) > MAX_OFF_AXIS_TAN:
        return None
    fxw, fyw = oversample * camera.fx, oversample * camera.fy
    x0, x1 = x.min() * fxw - 1.0, x.max() * fxw + 1.0  # one wide pixel of margin
    y0, y1 = y.min() * fyw - 1.0, y.max() * fyw + 1.0
    ww, hh = int(math.ceil(x1 - x0)), int(math.ceil(y1 - y0))
    return Camera(fxw, fyw, -x0, -y0, ww, hh)


@njit(parallel=True, cache=True)
def _resample(
    wide_labels, wide_depth, wide_ids, cluster, homog, rz_row, width, height, want_depth, want_ids,
    labels, depth, face_ids,
):
    """Nearest-neighbour pull of each target pixel from its wide view.

    homog[v] maps target pixel coordinates (u, v, 1) to homogeneous wide pixel coordinates; rz_row[v]
    (3,) gives the wide-camera z of the target ray with z = 1: rz = a*u + b*v + c (for depth).
    """
    n = homog.shape[0]
    hw, ww = wide_labels.shape[1], wide_labels.shape[2]
    for v in prange(n):
        c = cluster[v]
        h00, h01, h02 = homog[v, 0, 0], homog[v, 0, 1], homog[v, 0, 2]
        h10, h11, h12 = homog[v, 1, 0], homog[v, 1, 1], homog[v, 1, 2]
        h20, h21, h22 = homog[v, 2, 0], homog[v, 2, 1], homog[v, 2, 2]
        for i in range(height):
            py = i + 0.5
            for j in range(width):
                px = j + 0.5
                hz = h20 * px + h21 * py + h22
                jj = -1
                ii = -1
                if hz > 0.0:
                    uw = (h00 * px + h01 * py + h02) / hz
                    vw = (h10 * px + h11 * py + h12) / hz
                    if 0.0 <= uw < ww and 0.0 <= vw < hw:
                        jj = int(uw)
                        ii = int(vw)
                if jj < 0:
                    labels[v, i, j] = 0
                    if want_depth:
                        depth[v, i, j] = np.inf
                    if want_ids:
                        face_ids[v, i, j] = -1
                    continue
                labels[v, i, j] = wide_labels[c, ii, jj]
                if want_depth:
                    rz = rz_row[v, 0] * px + rz_row[v, 1] * py + rz_row[v, 2]
                    depth[v, i, j] = np.float32(wide_depth[c, ii, jj] / rz)
                if want_ids:
                    face_ids[v, i, j] = wide_ids[c, ii, jj]


def render_yaw_fan(
    renderer,
    camera: Camera,
    base_pose: Pose,
    yaws_deg,
    depth: bool = False,
    face_ids: bool = False,
    oversample: float = 2.0,
    max_span_deg: float = 90.0,
) -> RenderOutput:
    """Render ``base_pose.rotate_world_z(yaw)`` for every yaw by resampling a few wide views.

    Args:
        renderer: a ``Renderer``.
        camera: the target camera.
        base_pose: ONE pose (local frame, like ``Renderer.render``).
        yaws_deg: (N,) yaw offsets in degrees, added to the base pose's yaw (any order, any range).
        depth / face_ids: as in ``Renderer.render``.
        oversample: wide-view pixels per target pixel (along each axis, at the image centre).
        max_span_deg: the widest yaw range one wide view covers.

    Returns the same ``RenderOutput`` as ``renderer.render(camera, base_pose.rotate_world_z(yaws))``,
    up to resampling differences along class boundaries (module docstring).
    """
    check_camera(camera)
    R_base, _ = pose_arrays(base_pose)
    if base_pose.batch_shape != ():
        raise ShapeError(f"render_yaw_fan needs ONE base pose, got batch shape {base_pose.batch_shape}")
    yaws = np.asarray(yaws_deg, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(yaws)):
        raise ShapeError("yaws_deg must be finite")
    if not (oversample >= 1.0 and math.isfinite(oversample)):
        raise RenderError(f"oversample must be >= 1, got {oversample}")
    if not (0.0 < max_span_deg <= 180.0):
        raise RenderError(f"max_span_deg must be in (0, 180], got {max_span_deg}")
    n = len(yaws)
    h, w = camera.height, camera.width
    if n == 0:
        return RenderOutput(
            labels=np.zeros((0, h, w), dtype=np.uint8),
            depth=np.zeros((0, h, w), dtype=np.float32) if depth else None,
            face_ids=np.zeros((0, h, w), dtype=np.int32) if face_ids else None,
        )
    targets = base_pose.rotate_world_z(yaws)
    R_t, _ = pose_arrays(targets)
    span = float(max_span_deg)
    while True:
        cluster, mids = _cluster_yaws(yaws, span)
        wide_poses = base_pose.rotate_world_z(mids)
        R_w, t_w = pose_arrays(wide_poses)
        wide_cam = _wide_camera(camera, R_t, R_w, cluster, oversample)
        if wide_cam is not None:
            break
        if span < 1.0:
            raise RenderError("render_yaw_fan: no pinhole wide view holds these targets")
        span /= 2.0
    wide = renderer.render(wide_cam, wide_poses, depth=depth, face_ids=face_ids)
    delta = R_w[cluster] @ np.swapaxes(R_t, 1, 2)  # target camera -> wide camera
    k_inv = np.linalg.inv(camera.K)
    homog = np.ascontiguousarray(wide_cam.K @ delta @ k_inv)
    rz_row = np.ascontiguousarray((delta @ k_inv)[:, 2, :])
    labels = np.empty((n, h, w), dtype=np.uint8)
    dep = np.empty((n, h, w), dtype=np.float32) if depth else np.empty((1, 1, 1), dtype=np.float32)
    ids = np.empty((n, h, w), dtype=np.int32) if face_ids else np.empty((1, 1, 1), dtype=np.int32)
    dummy_f = np.empty((1, 1, 1), dtype=np.float32)
    dummy_i = np.empty((1, 1, 1), dtype=np.int32)
    _resample(
        wide.labels, wide.depth if depth else dummy_f, wide.face_ids if face_ids else dummy_i, cluster, homog,
        rz_row, w, h, depth, face_ids, labels, dep, ids,
    )
    return RenderOutput(labels=labels, depth=dep if depth else None, face_ids=ids if face_ids else None)

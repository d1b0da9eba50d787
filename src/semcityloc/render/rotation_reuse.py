"""Rotation reuse: many yaw hypotheses about ONE camera centre from a few wide renders.

Views that share a camera centre and differ only by a rotation about the world z axis through it
(``Pose.rotate_world_z``) see the same rays, so they need not each be rendered. ``render_yaw_fan``:

1. sorts the yaws around the circle and cuts them into clusters spanning at most a yaw span (by default
   the span with the least estimated cost: near nadir one wide view holds all 360 degrees; oblique
   views need several);
2. renders, per cluster, one WIDE pinhole view: the base pose turned by the cluster's middle yaw, with
   ``oversample`` times the target's focal length (pixels per radian) and a field of view (principal
   point off-centre if need be) that holds every target view of the cluster; all clusters share one
   wide camera, so the wide views are one batched render;
3. resamples each target from its cluster's wide view by the pure-rotation homography
   ``H = K_w R_delta K_t^-1`` (``R_delta = R_wide R_target^T``): nearest neighbour for labels and face
   ids; depth is moved along the ray: a wide z-depth ``d_w`` on the ray ``r_w = R_delta r_t`` (target ray
   with z = 1) is the target z-depth ``d_w / r_w.z``. ``R_delta`` depends only on the yaw offset from
   the cluster's middle and on the base pose's pitch and roll (not its yaw), so the pixel lookup tables
   are computed once per distinct ``R_delta`` and shared by every centre of a search grid.

It is an approximation: each target pixel takes the wide pixel its centre falls in, whose centre is up to
half a wide pixel away (none when the target looks the same way as its wide view: the wide pixel grid is
aligned to the target's), so labels differ from a direct render along class boundaries (about 1-2% of
the pixels at 64 x 48 and ``oversample=2``; ``tests/test_render_rotation.py``,
``benchmarks/bench_render.py``). It pays only with many yaws per centre: near nadir one wide view holds
every yaw, but oblique views need several wide views, each costing a few direct renders. A simple cost
model (``VIEW_COST_PIXELS``, ``RESAMPLE_COST_PIXELS``) picks the yaw span per wide view and, with
``allow_direct`` (default), renders the targets directly, exactly, unless the wide views are expected to
be ``FAN_MIN_GAIN`` times faster.
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
# Yaw spans per wide view tried by default (360: one wide view for all yaws, e.g. near nadir).
AUTO_SPANS_DEG = (360.0, 180.0, 120.0, 90.0, 60.0, 45.0, 30.0, 20.0, 10.0)
# Cost model, in units of "one target-image pixel rendered" (measured on Berlin, 64 x 48 targets):
# rendering a view of P pixels costs P + v * (target pixels), where the fixed per-view part v (triangle
# setup and culling; oblique views see many more, mostly tiny, triangles) grows from ~0 at nadir to
# VIEW_COST_PIXELS from 45 degrees of pitch on; resampling one target pixel costs RESAMPLE_COST_PIXELS.
# The wide views are used only when the model expects them FAN_MIN_GAIN times faster than direct.
VIEW_COST_PIXELS = 2.0
RESAMPLE_COST_PIXELS = 0.18
FAN_MIN_GAIN = 1.2


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
    # Target image border: corners and edge midpoints (pinhole to pinhole maps lines to lines, so the
    # extremes are at corners unless the horizon of the wide view cuts the border; the midpoints and
    # the off-axis limit below guard that case).
    us = np.array([0.0, w / 2, w, w, w, w / 2, 0.0, 0.0])
    vs = np.array([0.0, 0.0, 0.0, h / 2, h, h, h, h / 2])
    rays = np.stack([(us - camera.cx) / camera.fx, (vs - camera.cy) / camera.fy, np.ones(len(us))])  # (3, P)
    delta = np.matmul(R_wides[cluster], np.swapaxes(R_targets, 1, 2))  # (N, 3, 3): target cam -> wide cam
    rw = np.matmul(delta, rays)  # (N, 3, P)
    if np.any(rw[:, 2] <= 1.0 / MAX_OFF_AXIS_TAN):
        return None
    x = rw[:, 0] / rw[:, 2]
    y = rw[:, 1] / rw[:, 2]
    if max(np.abs(x).max(), np.abs(y).max()) > MAX_OFF_AXIS_TAN:
        return None
    fxw, fyw = oversample * camera.fx, oversample * camera.fy
    cxw = _aligned_principal_point(-x.min() * fxw + 1.0, camera.cx, oversample)  # >= 1 px margin
    cyw = _aligned_principal_point(-y.min() * fyw + 1.0, camera.cy, oversample)
    ww = int(math.ceil(cxw + x.max() * fxw + 1.0))
    hh = int(math.ceil(cyw + y.max() * fyw + 1.0))
    return Camera(fxw, fyw, cxw, cyw, ww, hh)


def _aligned_principal_point(at_least: float, c: float, oversample: float) -> float:
    """Smallest principal point >= ``at_least`` that puts the wide pixel CENTRES on the target's pixel
    centres when the two cameras look the same way (u_w = s u + c_w - s c; for s = 2 a target centre would
    otherwise fall exactly on a wide pixel border and be decided by rounding)."""
    want = (0.5 - 0.5 * oversample) % 1.0  # fractional part of c_w - s c that aligns the centres
    off = at_least - oversample * c
    off += (want - off) % 1.0
    return oversample * c + off


@njit(parallel=True, cache=True)
def _build_luts(homog, rz_row, width, height, wide_w, wide_h, want_depth, lut, inv_rz):
    """Per distinct target->wide rotation u: lut[u, p] = flat wide pixel that target pixel p falls in
    (-1 outside the wide view), and inv_rz[u, p] = 1 / (wide-camera z of the target ray with z = 1).

    homog[u] maps target pixel coordinates (u, v, 1) to homogeneous wide pixel coordinates.
    """
    fw, fh = float(wide_w), float(wide_h)
    for q in prange(homog.shape[0]):
        h00, h01, h02 = homog[q, 0, 0], homog[q, 0, 1], homog[q, 0, 2]
        h10, h11, h12 = homog[q, 1, 0], homog[q, 1, 1], homog[q, 1, 2]
        h20, h21, h22 = homog[q, 2, 0], homog[q, 2, 1], homog[q, 2, 2]
        for i in range(height):
            py = i + 0.5
            bx = h01 * py + h02
            by = h11 * py + h12
            bz = h21 * py + h22
            for j in range(width):
                px = j + 0.5
                hz = h20 * px + bz
                k = i * width + j
                lut[q, k] = -1
                if hz > 0.0:
                    inv = 1.0 / hz
                    uw = (h00 * px + bx) * inv
                    vw = (h10 * px + by) * inv
                    if uw >= 0.0 and uw < fw and vw >= 0.0 and vw < fh:
                        lut[q, k] = int(vw) * wide_w + int(uw)
                if want_depth:
                    rz = rz_row[q, 0] * px + rz_row[q, 1] * py + rz_row[q, 2]
                    inv_rz[q, k] = np.float32(1.0 / rz) if rz > 0.0 else np.float32(0.0)


@njit(parallel=True, cache=True)
def _gather(
    wide_labels,
    wide_depth,
    wide_ids,
    wide_of,
    lut_of,
    lut,
    inv_rz,
    want_depth,
    want_ids,
    labels,
    depth,
    face_ids,
):
    """Nearest-neighbour pull: target v takes wide view wide_of[v] through lookup table lut_of[v]."""
    npx = labels.shape[1]
    for v in prange(labels.shape[0]):
        c = wide_of[v]
        q = lut_of[v]
        for k in range(npx):
            src = lut[q, k]
            if src < 0:
                labels[v, k] = 0
                if want_depth:
                    depth[v, k] = np.inf
                if want_ids:
                    face_ids[v, k] = -1
            else:
                labels[v, k] = wide_labels[c, src]
                if want_depth:
                    depth[v, k] = wide_depth[c, src] * inv_rz[q, k]
                if want_ids:
                    face_ids[v, k] = wide_ids[c, src]


def _turned(base: Pose, yaws_deg: np.ndarray) -> Pose:
    """(M * N,) poses: every base pose (M,) turned about world z by every yaw (N,), centre-major."""
    a = np.radians(yaws_deg)
    c, s = np.cos(a), np.sin(a)
    rz = np.zeros((len(a), 3, 3))
    rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1], rz[:, 2, 2] = c, -s, s, c, 1.0
    rwc = base.R_world_from_cam.reshape(-1, 3, 3)
    centres = base.center.reshape(-1, 3)
    R = np.einsum("nij,mjk->mnik", rz, rwc).reshape(-1, 3, 3)
    C = np.repeat(centres, len(a), axis=0)
    return Pose.from_rotation_center(R, C)


def render_yaw_fan(
    renderer,
    camera: Camera,
    base_pose: Pose,
    yaws_deg,
    depth: bool = False,
    face_ids: bool = False,
    oversample: float = 2.0,
    max_span_deg: float | None = None,
    allow_direct: bool = True,
) -> RenderOutput:
    """Render ``base_pose.rotate_world_z(yaw)`` for every yaw by resampling a few wide views.

    Args:
        renderer: a ``Renderer``.
        camera: the target camera.
        base_pose: one pose, or a batch of M poses (M camera centres; local frame like ``Renderer.render``).
        yaws_deg: (N,) yaw offsets in degrees, added to the base pose's yaw (any order, any range).
        depth / face_ids: as in ``Renderer.render``.
        oversample: wide-view pixels per target pixel (along each axis, at the image centre).
        max_span_deg: the widest yaw range one wide view covers; None (default) picks, among
            ``AUTO_SPANS_DEG``, the one with the least estimated cost (wide pixels + a per-view cost).
        allow_direct: when the cost model says the wide views cost more than rendering the targets
            (few yaws per centre, steep oblique views), render them directly (exact) instead.

    Returns the same ``RenderOutput`` as ``renderer.render(camera, base_pose.rotate_world_z(yaws))``
    (N views; for M base poses M * N views, base-major: view ``m * N + k`` is base m turned by yaw k),
    up to resampling differences along class boundaries (module docstring), or exactly that when it
    falls back to direct rendering. All wide views are one render call and all resampling one kernel
    call, so batching the centres saves per-call overhead.
    """
    check_camera(camera)
    if not isinstance(base_pose, Pose):
        raise TypeError(f"base_pose must be a semcityloc Pose, got {type(base_pose).__name__}")
    if len(base_pose.batch_shape) > 1:
        raise ShapeError(f"render_yaw_fan needs one base pose or a 1-D batch, got {base_pose.batch_shape}")
    yaws = np.asarray(yaws_deg, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(yaws)):
        raise ShapeError("yaws_deg must be finite")
    if not (oversample >= 1.0 and math.isfinite(oversample)):
        raise RenderError(f"oversample must be >= 1, got {oversample}")
    if max_span_deg is not None and not (0.0 < max_span_deg <= 360.0):
        raise RenderError(f"max_span_deg must be in (0, 360], got {max_span_deg}")
    m = 1 if base_pose.batch_shape == () else base_pose.batch_shape[0]
    n = len(yaws)
    h, w = camera.height, camera.width
    if n * m == 0:
        return RenderOutput(
            labels=np.zeros((0, h, w), dtype=np.uint8),
            depth=np.zeros((0, h, w), dtype=np.float32) if depth else None,
            face_ids=np.zeros((0, h, w), dtype=np.int32) if face_ids else None,
        )
    R_t, _ = pose_arrays(_turned(base_pose, yaws))
    # Pitch = angle of the optical axis from nadir; the per-view cost grows with it (see VIEW_COST_PIXELS).
    pitch = np.degrees(np.arccos(np.clip(-base_pose.viewing_direction.reshape(-1, 3)[:, 2], -1.0, 1.0)))
    view_cost = VIEW_COST_PIXELS * float(np.clip(pitch.mean() / 45.0, 0.0, 1.0))
    best = None
    spans = AUTO_SPANS_DEG if max_span_deg is None else [float(max_span_deg) / 2**k for k in range(12)]
    for span in spans:
        cluster, mids = _cluster_yaws(yaws, span)
        n_c = len(mids)
        wide_poses = _turned(base_pose, mids)  # (M * C,)
        R_w, _ = pose_arrays(wide_poses)
        # Target m * N + k resamples wide view m * C + cluster[k].
        wide_of = (np.arange(m)[:, None] * n_c + cluster[None, :]).reshape(-1)
        cam_w = _wide_camera(camera, R_t, R_w, wide_of, oversample)
        if cam_w is None:
            continue
        # Cost model in pixel-equivalents: the wide pixels plus a fixed cost per view (triangle setup),
        # measured on Berlin to be about that of filling two target images.
        cost = n_c * (cam_w.width * cam_w.height + view_cost * w * h)
        if best is None or cost < best[0]:
            best = (cost, wide_poses, R_w, wide_of, cam_w)
        if max_span_deg is not None:
            break  # the widest feasible span not above the requested one
    if allow_direct:
        direct_cost = n * m * (1.0 + view_cost) * w * h
        fan_cost = None if best is None else best[0] * m + RESAMPLE_COST_PIXELS * n * m * w * h
        if fan_cost is None or FAN_MIN_GAIN * fan_cost >= direct_cost:
            return renderer.render(camera, _turned(base_pose, yaws), depth=depth, face_ids=face_ids)
    if best is None:
        raise RenderError("render_yaw_fan: no pinhole wide view holds these targets")
    _, wide_poses, R_w, wide_of, wide_cam = best
    wide = renderer.render(wide_cam, wide_poses, depth=depth, face_ids=face_ids)
    delta = R_w[wide_of] @ np.swapaxes(R_t, 1, 2)  # target camera -> wide camera
    # delta = B^T Rz(yaw - mid) B with B the base orientation without its yaw: targets whose bases
    # share pitch and roll (a search grid) share their lookup tables.
    keys, lut_of = np.unique(np.round(delta.reshape(-1, 9), 12), axis=0, return_inverse=True)
    delta_u = keys.reshape(-1, 3, 3)
    k_inv = np.linalg.inv(camera.K)
    homog = np.ascontiguousarray(wide_cam.K @ delta_u @ k_inv)
    rz_row = np.ascontiguousarray((delta_u @ k_inv)[:, 2, :])
    n_u, npx = len(delta_u), w * h
    lut = np.empty((n_u, npx), dtype=np.int64)
    inv_rz = np.empty((n_u, npx) if depth else (1, 1), dtype=np.float32)
    _build_luts(homog, rz_row, w, h, wide_cam.width, wide_cam.height, depth, lut, inv_rz)
    total = n * m
    labels = np.empty((total, npx), dtype=np.uint8)
    dep = np.empty((total, npx) if depth else (1, 1), dtype=np.float32)
    ids = np.empty((total, npx) if face_ids else (1, 1), dtype=np.int32)
    n_w = len(wide)
    wide_dep = wide.depth.reshape(n_w, -1) if depth else np.empty((1, 1), dtype=np.float32)
    wide_ids = wide.face_ids.reshape(n_w, -1) if face_ids else np.empty((1, 1), dtype=np.int32)
    _gather(
        wide.labels.reshape(n_w, -1),
        wide_dep,
        wide_ids,
        np.ascontiguousarray(wide_of),
        np.ascontiguousarray(lut_of.reshape(-1)),
        lut,
        inv_rz,
        depth,
        face_ids,
        labels,
        dep,
        ids,
    )
    return RenderOutput(
        labels=labels.reshape(total, h, w),
        depth=dep.reshape(total, h, w) if depth else None,
        face_ids=ids.reshape(total, h, w) if face_ids else None,
    )

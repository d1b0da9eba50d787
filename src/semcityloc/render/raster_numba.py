"""CPU z-buffer rasteriser in numba: many small views of one ``RenderScene``, in parallel over views.

Sampling is exactly that of a ray caster: pixel (i, j) is the ray through its centre
(u, v) = (j + 0.5, i + 0.5) (COLMAP convention, ``geometry/camera.py``). A pixel is covered when its centre
is inside the projected triangle; centres exactly on an edge go to exactly one of the two triangles that
share it (a consistent tie rule, see ``_raster_triangle``). Depth is z-depth along the optical axis; its
reciprocal is linear in screen space, so the kernel evaluates ``1/z`` from the triangle's 3D plane at each
pixel centre (the same number a ray caster finds, up to rounding) and keeps the largest ``1/z``.

Structure (reused by the fused render-and-score kernels: ``localization.kernels``, ``baselines.edge_score``):

- ``render_view(...)`` rasterises ONE view into two flat per-view buffers: ``inv_z`` (float64, 0 = empty)
  and ``tri_id`` (int32, -1 = empty). It culls blocks and tiles whose bounding box misses the view
  frustum (5 planes: 4 sides + near), transforms and projects the triangles of the remaining tiles,
  clips them against the near plane ``z = near`` (one triangle becomes up to two), and rasterises.
- ``render_batch(...)`` is the parallel driver: ``prange`` over chunks of views; each chunk allocates its
  buffers once, renders its views one after the other and writes labels / depth / face ids.
- A fused score calls ``render_view`` inside its own ``prange`` over views and reduces each view's
  ``tri_id`` / ``inv_z`` buffers on the spot, so nothing of size (N, H, W) is ever allocated: see
  ``localization.kernels.refine_scores`` (semantic IoU and depth cost per view).

All kernels are ``cache=True`` (compiled once per machine, ~10-30 s) and ``fastmath=False`` (the tie rule
needs exact IEEE arithmetic).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import njit, prange

from semcityloc.render.output import RenderOutput

# Geometry closer to the camera than this (metres, along the optical axis) is clipped away.
NEAR_M = 0.1
# A pixel centre closer to an edge than EDGE_EPS x (coordinate magnitudes) is decided by the exact edge
# test; farther ones cannot be misjudged by rounding (errors are ~1e-16 x magnitudes).
EDGE_EPS = 1e-9


# ---------------------------------------------------------------------------------------------- culling
@njit(cache=True, inline="always")
def _frustum_planes(R_cam_from_local, t_cam_from_local, fx, fy, cx, cy, width, height, near, planes):
    """Fill planes (5, 4) with local-frame half-spaces n.X + d >= 0 containing the view frustum."""
    # Camera-frame normals of the 4 side planes (through the centre) and the near plane.
    ncam = np.empty((5, 3))
    ncam[0, 0], ncam[0, 1], ncam[0, 2] = fx, 0.0, cx  # u >= 0
    ncam[1, 0], ncam[1, 1], ncam[1, 2] = -fx, 0.0, width - cx  # u <= W
    ncam[2, 0], ncam[2, 1], ncam[2, 2] = 0.0, fy, cy  # v >= 0
    ncam[3, 0], ncam[3, 1], ncam[3, 2] = 0.0, -fy, height - cy  # v <= H
    ncam[4, 0], ncam[4, 1], ncam[4, 2] = 0.0, 0.0, 1.0  # z >= near
    for p in range(5):
        a, b, c = ncam[p, 0], ncam[p, 1], ncam[p, 2]
        # n_local = R^T n_cam ; d = n_cam . t   (x_cam = R x_local + t, R t: cam_from_local)
        planes[p, 0] = R_cam_from_local[0, 0] * a + R_cam_from_local[1, 0] * b + R_cam_from_local[2, 0] * c
        planes[p, 1] = R_cam_from_local[0, 1] * a + R_cam_from_local[1, 1] * b + R_cam_from_local[2, 1] * c
        planes[p, 2] = R_cam_from_local[0, 2] * a + R_cam_from_local[1, 2] * b + R_cam_from_local[2, 2] * c
        planes[p, 3] = a * t_cam_from_local[0] + b * t_cam_from_local[1] + c * t_cam_from_local[2]
    planes[4, 3] -= near


@njit(cache=True, inline="always")
def _box_outside(planes, boxes, i):
    """True when box i (xmin ymin zmin xmax ymax zmax) is entirely outside one frustum plane."""
    for p in range(5):
        nx, ny, nz = planes[p, 0], planes[p, 1], planes[p, 2]
        x = boxes[i, 3] if nx >= 0.0 else boxes[i, 0]
        y = boxes[i, 4] if ny >= 0.0 else boxes[i, 1]
        z = boxes[i, 5] if nz >= 0.0 else boxes[i, 2]
        if nx * x + ny * y + nz * z + planes[p, 3] < 0.0:
            return True
    return False


# ---------------------------------------------------------------------------------------------- raster
@njit(cache=True, inline="always")
def _edge(ax, ay, bx, by, sign):
    """Canonical edge a-b: (ox, oy, mdx, mdy, owner) with inside value mdx*(py-oy) - mdy*(px-ox).

    The endpoints are ordered lexicographically so that the two triangles sharing an edge evaluate the
    very same expression up to an exact sign flip; a centre exactly on the edge (value 0) belongs to the
    triangle whose multiplier is positive ("owner"): exactly one of the two.
    """
    if ax < bx or (ax == bx and ay < by):
        m = sign
        ox, oy, dx, dy = ax, ay, bx - ax, by - ay
    else:
        m = -sign
        ox, oy, dx, dy = bx, by, ax - bx, ay - by
    return ox, oy, m * dx, m * dy, m > 0.0


@njit(cache=True, inline="always")
def _raster_triangle(u0, v0, u1, v1, u2, v2, pa, pb, pc, tid, width, height, inv_z, tri_id):
    """Z-buffer one screen triangle; 1/z at (u, v) is pa*u + pb*v + pc (the 3D plane, not clipped)."""
    umin = min(u0, min(u1, u2))
    umax = max(u0, max(u1, u2))
    vmin = min(v0, min(v1, v2))
    vmax = max(v0, max(v1, v2))
    # Pixel centres j + 0.5 within [umin, umax].
    j0 = int(math.ceil(max(umin - 0.5, 0.0)))
    j1 = int(math.floor(min(umax - 0.5, width - 1.0)))
    i0 = int(math.ceil(max(vmin - 0.5, 0.0)))
    i1 = int(math.floor(min(vmax - 0.5, height - 1.0)))
    if j0 > j1 or i0 > i1:
        return
    area = (u1 - u0) * (v2 - v0) - (v1 - v0) * (u2 - u0)
    if area == 0.0:
        return
    s = 1.0 if area > 0.0 else -1.0
    # Edges opposite to vertex 2, 0, 1 (their inside value is positive inside the triangle).
    ax_, ay_, adx, ady, aown = _edge(u0, v0, u1, v1, s)
    bx_, by_, bdx, bdy, bown = _edge(u1, v1, u2, v2, s)
    cx_, cy_, cdx, cdy, cown = _edge(u2, v2, u0, v0, s)
    # Per row, each edge bounds the inside centres from one side: px <= o + r/dy (dy > 0) or
    # px >= o + r/dy (dy < 0). Each edge value is a monotone function of px even in floating point (a
    # chain of correctly rounded monotone operations), so the inside centres of a row form ONE run.
    # Fast path: when the run's end centres are farther than `eps` from the computed bounds, the exact
    # edge tests could not decide otherwise, so the run is filled untested. Otherwise (a centre within
    # eps of an edge: ties, exactly aligned geometry) the exact tests find the run's ends.
    ia = 1.0 / ady if ady != 0.0 else 0.0
    ib = 1.0 / bdy if bdy != 0.0 else 0.0
    ic = 1.0 / cdy if cdy != 0.0 else 0.0
    fj0 = float(j0)
    fj1 = float(j1)
    eps0 = EDGE_EPS * (abs(ax_) + abs(bx_) + abs(cx_) + width)
    for i in range(i0, i1 + 1):
        py = i + 0.5
        ra = adx * (py - ay_)
        rb = bdx * (py - by_)
        rc = cdx * (py - cy_)
        xl = -np.inf
        xr = np.inf
        if ady > 0.0:
            xr = min(xr, ax_ + ra * ia)
        elif ady < 0.0:
            xl = max(xl, ax_ + ra * ia)
        elif ra < 0.0 or (ra == 0.0 and not aown):
            continue
        if bdy > 0.0:
            xr = min(xr, bx_ + rb * ib)
        elif bdy < 0.0:
            xl = max(xl, bx_ + rb * ib)
        elif rb < 0.0 or (rb == 0.0 and not bown):
            continue
        if cdy > 0.0:
            xr = min(xr, cx_ + rc * ic)
        elif cdy < 0.0:
            xl = max(xl, cx_ + rc * ic)
        elif rc < 0.0 or (rc == 0.0 and not cown):
            continue
        exact = False
        first = fj0
        if xl - 0.5 > fj0 - 1.0:
            fl = xl - 0.5
            first = math.ceil(fl)
            d = first - fl  # in [0, 1): distance of the first centre past the bound
            eps = eps0 + EDGE_EPS * abs(xl)
            exact = d < eps or d > 1.0 - eps
            first = max(first, fj0)
        last = fj1
        if xr - 0.5 < fj1 + 1.0:
            fr = xr - 0.5
            last = math.floor(fr)
            d = fr - last
            eps = eps0 + EDGE_EPS * abs(xr)
            exact = exact or d < eps or d > 1.0 - eps
            last = min(last, fj1)
        if exact:
            # Search the run's ends with the exact tests around the estimates (a few tests).
            lo = int(max(first - 1.0, fj0))
            hi = int(min(last + 1.0, fj1))
            if lo > hi:
                continue
            jf = lo
            if _inside(jf, ra, rb, rc, ax_, bx_, cx_, ady, bdy, cdy, aown, bown, cown):
                while jf > j0 and _inside(jf - 1, ra, rb, rc, ax_, bx_, cx_, ady, bdy, cdy, aown, bown, cown):
                    jf -= 1
            else:
                jf += 1
                while jf <= hi and not _inside(
                    jf, ra, rb, rc, ax_, bx_, cx_, ady, bdy, cdy, aown, bown, cown
                ):
                    jf += 1
                if jf > hi:
                    continue
            jl = hi
            if _inside(jl, ra, rb, rc, ax_, bx_, cx_, ady, bdy, cdy, aown, bown, cown):
                while jl < j1 and _inside(jl + 1, ra, rb, rc, ax_, bx_, cx_, ady, bdy, cdy, aown, bown, cown):
                    jl += 1
            else:
                jl -= 1
                while not _inside(jl, ra, rb, rc, ax_, bx_, cx_, ady, bdy, cdy, aown, bown, cown):
                    jl -= 1
        else:
            if first > last:
                continue
            jf = int(first)
            jl = int(last)
        zrow = pb * py + pc
        # Branch-free depth test over the run (the order triangles arrive in says nothing about depth, so
        # a branch here mispredicts about half the time), on views of the run indexed from 0: no negative
        # index to wrap, so the compiler vectorises the loop (about a tenth less raster time than indexing
        # the whole buffer by row + j). The same arithmetic per pixel: pa * (j + 0.5) + zrow.
        start = i * width + jf
        n_run = jl - jf + 1
        z_run = inv_z[start : start + n_run]
        id_run = tri_id[start : start + n_run]
        centre0 = float(jf) + 0.5
        for m in range(n_run):
            iz = pa * (centre0 + m) + zrow
            old = z_run[m]
            closer = iz > old
            z_run[m] = iz if closer else old
            id_run[m] = tid if closer else id_run[m]


@njit(cache=True, inline="always")
def _inside(j, ra, rb, rc, ax_, bx_, cx_, ady, bdy, cdy, aown, bown, cown):
    """Exact coverage test of pixel centre (j + 0.5) in the current row (see ``_raster_triangle``)."""
    px = j + 0.5
    ea = ra - ady * (px - ax_)
    if ea < 0.0 or (ea == 0.0 and not aown):
        return False
    eb = rb - bdy * (px - bx_)
    if eb < 0.0 or (eb == 0.0 and not bown):
        return False
    ec = rc - cdy * (px - cx_)
    return ec > 0.0 or (ec == 0.0 and cown)


@njit(cache=True, inline="always")
def _covers_a_centre(u0, v0, u1, v1, u2, v2, width, height):
    """Cheap test: does the screen bounding box of the triangle hold at least one pixel centre?"""
    umin = min(u0, min(u1, u2))
    umax = max(u0, max(u1, u2))
    if umax < 0.5 or umin > width - 0.5:
        return False
    vmin = min(v0, min(v1, v2))
    vmax = max(v0, max(v1, v2))
    if vmax < 0.5 or vmin > height - 0.5:
        return False
    # No centre strictly between: [umin, umax] must contain some j + 0.5.
    if math.floor(umax - 0.5) < math.ceil(umin - 0.5):
        return False
    if math.floor(vmax - 0.5) < math.ceil(vmin - 0.5):
        return False
    return True


@njit(cache=True, inline="always")
def _inv_z_plane(x0, y0, z0, x1, y1, z1, x2, y2, z2, fx, fy, cx, cy):
    """Coefficients (pa, pb, pc, ok) with 1/z = pa*u + pb*v + pc on the triangle's plane (camera frame)."""
    ex, ey, ez = x1 - x0, y1 - y0, z1 - z0
    gx, gy, gz = x2 - x0, y2 - y0, z2 - z0
    nx = ey * gz - ez * gy
    ny = ez * gx - ex * gz
    nz = ex * gy - ey * gx
    d = nx * x0 + ny * y0 + nz * z0  # plane n.X = d; a ray X = z (xn, yn, 1) hits at 1/z = n.(xn,yn,1)/d
    nn = abs(nx) + abs(ny) + abs(nz)
    scale = abs(x0) + abs(y0) + abs(z0) + 1e-30
    if abs(d) <= 1e-12 * nn * scale:  # plane through the camera centre: seen edge-on
        return 0.0, 0.0, 0.0, False
    pa = nx / (fx * d)
    pb = ny / (fy * d)
    pc = (nz - nx * cx / fx - ny * cy / fy) / d
    return pa, pb, pc, True


@njit(cache=True)
def render_view(
    tri_xyz,
    tile_start,
    tile_bbox,
    block_start,
    block_bbox,
    R_cam_from_local,
    t_cam_from_local,
    fx,
    fy,
    cx,
    cy,
    width,
    height,
    near,
    inv_z,
    tri_id,
):
    """Rasterise one view into the flat buffers inv_z (float64, H*W) and tri_id (int32, H*W).

    Scene arrays as in ``RenderScene``; ``R_cam_from_local`` (3, 3) and ``t_cam_from_local`` (3,) float64
    the pose in the scene's local frame; ``fx, fy, cx, cy, width, height`` the pinhole camera; ``near`` the
    clipping distance (``NEAR_M``).
    On return ``tri_id[i * width + j]`` is the scene triangle seen at pixel (i, j) (-1: none) and
    ``inv_z`` its 1 / z-depth (0: none). Both buffers are overwritten (no need to clear them).
    Returns the number of triangles that reached the rasteriser (after culling), for statistics.
    """
    npx = width * height
    for k in range(npx):
        inv_z[k] = 0.0
        tri_id[k] = -1
    planes = np.empty((5, 4))
    _frustum_planes(R_cam_from_local, t_cam_from_local, fx, fy, cx, cy, width, height, near, planes)
    r00, r01, r02 = R_cam_from_local[0, 0], R_cam_from_local[0, 1], R_cam_from_local[0, 2]
    r10, r11, r12 = R_cam_from_local[1, 0], R_cam_from_local[1, 1], R_cam_from_local[1, 2]
    r20, r21, r22 = R_cam_from_local[2, 0], R_cam_from_local[2, 1], R_cam_from_local[2, 2]
    t0, t1, t2 = t_cam_from_local[0], t_cam_from_local[1], t_cam_from_local[2]
    drawn = 0
    # Clipped polygon (at most 4 vertices) in camera coordinates.
    qx = np.empty(4)
    qy = np.empty(4)
    qz = np.empty(4)
    for b in range(block_bbox.shape[0]):
        if _box_outside(planes, block_bbox, b):
            continue
        for tile in range(block_start[b], block_start[b + 1]):
            if _box_outside(planes, tile_bbox, tile):
                continue
            for f in range(tile_start[tile], tile_start[tile + 1]):
                X0, Y0, Z0 = np.float64(tri_xyz[f, 0]), np.float64(tri_xyz[f, 1]), np.float64(tri_xyz[f, 2])
                X1, Y1, Z1 = np.float64(tri_xyz[f, 3]), np.float64(tri_xyz[f, 4]), np.float64(tri_xyz[f, 5])
                X2, Y2, Z2 = np.float64(tri_xyz[f, 6]), np.float64(tri_xyz[f, 7]), np.float64(tri_xyz[f, 8])
                z0 = r20 * X0 + r21 * Y0 + r22 * Z0 + t2
                z1 = r20 * X1 + r21 * Y1 + r22 * Z1 + t2
                z2 = r20 * X2 + r21 * Y2 + r22 * Z2 + t2
                if z0 < near and z1 < near and z2 < near:
                    continue
                x0 = r00 * X0 + r01 * Y0 + r02 * Z0 + t0
                x1 = r00 * X1 + r01 * Y1 + r02 * Z1 + t0
                x2 = r00 * X2 + r01 * Y2 + r02 * Z2 + t0
                y0 = r10 * X0 + r11 * Y0 + r12 * Z0 + t1
                y1 = r10 * X1 + r11 * Y1 + r12 * Z1 + t1
                y2 = r10 * X2 + r11 * Y2 + r12 * Z2 + t1
                if z0 >= near and z1 >= near and z2 >= near:
                    i0, i1, i2 = 1.0 / z0, 1.0 / z1, 1.0 / z2
                    u0, v0 = fx * x0 * i0 + cx, fy * y0 * i0 + cy
                    u1, v1 = fx * x1 * i1 + cx, fy * y1 * i1 + cy
                    u2, v2 = fx * x2 * i2 + cx, fy * y2 * i2 + cy
                    if not _covers_a_centre(u0, v0, u1, v1, u2, v2, width, height):
                        continue
                    pa, pb, pc, ok = _inv_z_plane(x0, y0, z0, x1, y1, z1, x2, y2, z2, fx, fy, cx, cy)
                    if not ok:
                        continue
                    drawn += 1
                    _raster_triangle(u0, v0, u1, v1, u2, v2, pa, pb, pc, f, width, height, inv_z, tri_id)
                    continue
                # Near-plane clipping (Sutherland-Hodgman against z >= near): 3 or 4 vertices.
                pa, pb, pc, ok = _inv_z_plane(x0, y0, z0, x1, y1, z1, x2, y2, z2, fx, fy, cx, cy)
                if not ok:
                    continue
                n = 0
                for e in range(3):
                    if e == 0:
                        ax, ay, az, bx, by, bz = x0, y0, z0, x1, y1, z1
                    elif e == 1:
                        ax, ay, az, bx, by, bz = x1, y1, z1, x2, y2, z2
                    else:
                        ax, ay, az, bx, by, bz = x2, y2, z2, x0, y0, z0
                    a_in = az >= near
                    b_in = bz >= near
                    if a_in:
                        qx[n], qy[n], qz[n] = ax, ay, az
                        n += 1
                    if a_in != b_in:
                        s = (near - az) / (bz - az)
                        qx[n], qy[n], qz[n] = ax + s * (bx - ax), ay + s * (by - ay), near
                        n += 1
                drawn += 1
                for k in range(1, n - 1):  # fan (q0, qk, qk+1)
                    u0, v0 = fx * qx[0] / qz[0] + cx, fy * qy[0] / qz[0] + cy
                    u1, v1 = fx * qx[k] / qz[k] + cx, fy * qy[k] / qz[k] + cy
                    u2, v2 = fx * qx[k + 1] / qz[k + 1] + cx, fy * qy[k + 1] / qz[k + 1] + cy
                    if _covers_a_centre(u0, v0, u1, v1, u2, v2, width, height):
                        _raster_triangle(u0, v0, u1, v1, u2, v2, pa, pb, pc, f, width, height, inv_z, tri_id)
    return drawn


# ---------------------------------------------------------------------------------------------- drivers
def work_chunks(n_views: int) -> int:
    """Number of work chunks for the drivers: a few per thread so that uneven views balance out."""
    return max(1, min(n_views, 4 * numba.get_num_threads()))


@njit(parallel=True, cache=True)
def render_batch(
    tri_xyz,
    classes,
    tile_start,
    tile_bbox,
    block_start,
    block_bbox,
    R_cams_from_local,
    t_cams_from_local,
    fx,
    fy,
    cx,
    cy,
    width,
    height,
    near,
    labels,
    depth,
    face_ids,
    want_depth,
    want_ids,
    n_chunks,
):
    """Render views ``R_cams_from_local`` (N,3,3), ``t_cams_from_local`` (N,3) into flat outputs.

    labels: uint8 (N, H*W); depth: float32 (N, H*W) if want_depth; face_ids: int32 (N, H*W) if want_ids
    (pass (1, 1) dummies otherwise). Views are dealt to chunks round-robin (view v -> chunk v % C).
    """
    n_views = R_cams_from_local.shape[0]
    npx = width * height
    for c in prange(n_chunks):
        inv_z = np.empty(npx)
        tri_id = np.empty(npx, dtype=np.int32)
        for v in range(c, n_views, n_chunks):
            render_view(
                tri_xyz,
                tile_start,
                tile_bbox,
                block_start,
                block_bbox,
                R_cams_from_local[v],
                t_cams_from_local[v],
                fx,
                fy,
                cx,
                cy,
                width,
                height,
                near,
                inv_z,
                tri_id,
            )
            for k in range(npx):
                f = tri_id[k]
                if f >= 0:
                    labels[v, k] = classes[f]
                    if want_depth:
                        depth[v, k] = np.float32(1.0 / inv_z[k])
                else:
                    labels[v, k] = 0
                    if want_depth:
                        depth[v, k] = np.float32(np.inf)
                if want_ids:
                    face_ids[v, k] = f


# ---------------------------------------------------------------------------------------------- engine
class NumbaEngine:
    """The default CPU engine: ``render_batch`` over a ``RenderScene``."""

    name = "numba"

    def __init__(self, scene, near: float = NEAR_M):
        self.scene = scene
        self.near = float(near)

    def args(self) -> tuple:
        """The scene arrays in the order the kernels take them (after ``tri_xyz``: see ``render_view``)."""
        s = self.scene
        return s.tri_xyz, s.classes, s.tile_start, s.tile_bbox, s.block_start, s.block_bbox

    def render(
        self,
        camera,
        R_cams_from_local: np.ndarray,
        t_cams_from_local: np.ndarray,
        depth: bool = False,
        face_ids: bool = False,
    ):
        """``RenderOutput`` of the views ``x_cam = R_cams_from_local[v] @ x_local + t_cams_from_local[v]``
        ((N, 3, 3), (N, 3) float64, the scene's local frame)."""
        n, h, w = len(R_cams_from_local), camera.height, camera.width
        labels = np.empty((n, h * w), dtype=np.uint8)
        dep = np.empty((n, h * w), dtype=np.float32) if depth else np.empty((1, 1), dtype=np.float32)
        ids = np.empty((n, h * w), dtype=np.int32) if face_ids else np.empty((1, 1), dtype=np.int32)
        if n:
            render_batch(
                *self.args(),
                R_cams_from_local,
                t_cams_from_local,
                camera.fx,
                camera.fy,
                camera.cx,
                camera.cy,
                w,
                h,
                self.near,
                labels,
                dep,
                ids,
                depth,
                face_ids,
                work_chunks(n),
            )
        return RenderOutput(
            labels=labels.reshape(n, h, w),
            depth=dep.reshape(n, h, w) if depth else None,
            face_ids=ids.reshape(n, h, w) if face_ids else None,
        )

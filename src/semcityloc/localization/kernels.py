"""Fused render-and-score kernels: the search never materialises an (N, H, W) stack of masks.

``coarse_scores``: one *wide* render per camera centre; every yaw hypothesis of that centre reads its
pixels from the wide render through a lookup table (a pure rotation about the camera centre maps rays
to rays, so the table depends only on the yaw offsets and the intrinsics — it is shared by all centres).
The per-class IoU against the query mask is accumulated on the fly.

``refine_scores``: one render per particle at the fine resolution; semantic IoU and the affine-invariant
depth cost (scale/shift fit, then mean relative residual) read only the query's labelled pixels, compacted
once per batch: one pass gives the class histogram and the fit's sums, a second the residuals.

Both call ``render.raster_numba.render_view`` (the renderer's per-view rasteriser) inside ``prange``
over views, so their output matches what ``Renderer.render`` would draw.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from semcityloc.classes import IGNORE
from semcityloc.render.raster_numba import render_view

N_SLOTS = 8  # class histogram size (class ids 0..5 fit)


@njit(cache=True, inline="always")
def _mean_iou(inter, count_r, count_q, class_on):
    total = 0.0
    n = 0
    for c in range(N_SLOTS):
        if not class_on[c]:
            continue
        union = count_r[c] + count_q[c] - inter[c]
        if union > 0:
            total += inter[c] / union
            n += 1
    return total / n if n > 0 else 0.0


@njit(cache=True, inline="always")
def _query_counts(query):
    """Pixels per class of a flat query mask, leaving out background (0) and IGNORE."""
    count_q = np.zeros(N_SLOTS)
    for p in range(query.shape[0]):
        q = query[p]
        if q != IGNORE and q != 0:
            count_q[q] += 1.0
    return count_q


@njit(cache=True, inline="always")
def _iou_from_pairs(pairs, count_q, class_on):
    """Mean IoU from interleaved (rendered * N_SLOTS + query) pair counts (4 sub-histograms)."""
    total = 0.0
    n = 0
    for c in range(N_SLOTS):
        if not class_on[c]:
            continue
        inter = 0
        count_r = 0
        for k in range(4):
            base = k * N_SLOTS * N_SLOTS + c * N_SLOTS
            inter += pairs[base + c]
            for q in range(N_SLOTS):
                count_r += pairs[base + q]
        union = count_r + count_q[c] - inter
        if union > 0:
            total += inter / union
            n += 1
    return total / n if n > 0 else 0.0


@njit(parallel=True, cache=True)
def coarse_scores(
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
    lut,
    query,
    class_on,
    scores,
    n_chunks,
):
    """IoU score of every (centre, yaw) hypothesis.

    R_cams_from_local, t_cams_from_local: (C, 3, 3), (C, 3) the *wide* camera's pose at each centre.
    fx..height: the wide camera. lut: int32 (Y, P) index into the wide image for each of the P target
    pixels of yaw hypothesis y (-1: outside, counts as background). query: uint8 (P,) target-resolution
    query labels (IGNORE / background pixels are skipped). class_on: bool (N_SLOTS,). scores: (C, Y) out.
    """
    n_centres = R_cams_from_local.shape[0]
    n_yaw, n_pix = lut.shape
    npx = width * height
    # Only query pixels that take part (not background / ignore): compact them once.
    n_valid = 0
    for p in range(n_pix):
        if query[p] != IGNORE and query[p] != 0:
            n_valid += 1
    q_valid = np.empty(n_valid, dtype=np.int64)
    lut_valid = np.empty((n_yaw, n_valid), dtype=np.int64)
    count_q = _query_counts(query)
    k = 0
    for p in range(n_pix):
        q = query[p]
        if q != IGNORE and q != 0:
            q_valid[k] = q
            for y in range(n_yaw):
                # -1 (outside the wide view) points at an extra background pixel past the end.
                lut_valid[y, k] = lut[y, p] if lut[y, p] >= 0 else npx
            k += 1
    for chunk in prange(n_chunks):
        inv_z = np.empty(npx)
        tri_id = np.empty(npx, dtype=np.int32)
        wide = np.zeros(npx + 1, dtype=np.int64)  # class * N_SLOTS per pixel; [npx] = background
        pairs = np.empty(4 * N_SLOTS * N_SLOTS, dtype=np.int32)
        for c in range(chunk, n_centres, n_chunks):
            render_view(
                tri_xyz,
                tile_start,
                tile_bbox,
                block_start,
                block_bbox,
                R_cams_from_local[c],
                t_cams_from_local[c],
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
            for i in range(npx):
                f = tri_id[i]
                wide[i] = classes[f] * N_SLOTS if f >= 0 else 0
            for y in range(n_yaw):
                pairs[:] = 0
                row = lut_valid[y]
                # Four interleaved sub-histograms break the store-to-load dependency of repeated classes.
                j = 0
                while j + 3 < n_valid:
                    pairs[wide[row[j]] + q_valid[j]] += 1
                    pairs[64 + wide[row[j + 1]] + q_valid[j + 1]] += 1
                    pairs[128 + wide[row[j + 2]] + q_valid[j + 2]] += 1
                    pairs[192 + wide[row[j + 3]] + q_valid[j + 3]] += 1
                    j += 4
                while j < n_valid:
                    pairs[wide[row[j]] + q_valid[j]] += 1
                    j += 1
                scores[c, y] = _iou_from_pairs(pairs, count_q, class_on)


@njit(cache=True)
def _scored_pixels(query, query_depth, use_depth):
    """The query pixels the scores read, compacted once per batch of views: indices of labelled,
    non-background pixels, their labels, and their depth where the depth cost uses it (finite and
    positive, else 0)."""
    n = 0
    for p in range(query.shape[0]):
        if query[p] != IGNORE and query[p] != 0:
            n += 1
    idx = np.empty(n, dtype=np.int64)
    lab = np.empty(n, dtype=np.int64)
    dep = np.zeros(n)
    k = 0
    for p in range(query.shape[0]):
        q = query[p]
        if q != IGNORE and q != 0:
            idx[k] = p
            lab[k] = q
            if use_depth:
                dq = query_depth[p]
                dep[k] = dq if dq > 0.0 else 0.0  # NaN compares False: 0
            k += 1
    return idx, lab, dep


@njit(cache=True, inline="always")
def _depth_cost_affine(idx, dep, tri_id, inv_z, n, sq, sr, sqq, sqr, min_depth_pixels, invalid_cost):
    """Global least-squares scale/shift, then mean relative residual (the paper's C_d). The sums over
    the depth pixels (``n``, sum dq, sum dr, sum dq^2, sum dq dr) come from the semantic pass."""
    det = n * sqq - sq * sq
    if n < min_depth_pixels or det <= 1e-12 * n * sqq:
        return invalid_cost
    s = (n * sqr - sq * sr) / det
    t = (sr - s * sq) / n
    if s <= 0.0:
        return invalid_cost
    acc = 0.0
    for k in range(idx.shape[0]):
        dq = dep[k]
        p = idx[k]
        if dq > 0.0 and tri_id[p] >= 0:
            dr = 1.0 / inv_z[p]
            acc += abs(s * dq + t - dr) / dr
    return acc / n


@njit(cache=True, inline="always")
def _depth_cost_robust(
    idx, dep, tri_id, inv_z, n, saa, sab, sbb, sa, sb, cap, min_depth_pixels, invalid_cost
):
    """Scale/shift by relative least squares (minimise sum(((s dq + t) - dr) / dr)^2: every pixel's error
    relative to its depth, the cost's own measure, so near and far pixels count alike), then the mean
    relative residual with each pixel's capped at ``cap`` (a tree, a bled edge or a wrong label costs at
    most that). The sums (a = dq / dr, b = 1 / dr) come from the semantic pass."""
    det = saa * sbb - sab * sab
    if n < min_depth_pixels or det <= 1e-12 * saa * sbb:
        return invalid_cost
    s = (sa * sbb - sb * sab) / det
    t = (saa * sb - sab * sa) / det
    if s <= 0.0:
        return invalid_cost
    acc = 0.0
    for k in range(idx.shape[0]):
        dq = dep[k]
        p = idx[k]
        if dq > 0.0 and tri_id[p] >= 0:
            e = abs((s * dq + t) * inv_z[p] - 1.0)
            acc += e if e < cap else cap
    return acc / n


@njit(parallel=True, cache=True)
def refine_scores(
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
    query,
    query_depth,
    use_depth,
    class_on,
    min_depth_pixels,
    invalid_cost,
    sem_out,
    depth_out,
    n_chunks,
    depth_robust=False,
    depth_cap=1.0,
):
    """Semantic IoU and depth cost of each view (``R_cams_from_local``, ``t_cams_from_local``) at the fine
    camera.

    query: uint8 (H*W,); query_depth: float64 (H*W,) relative depth, NaN where invalid. The depth term
    uses pixels with a rendered surface, a finite positive query depth and a non-background query label:
    ``_depth_cost_affine`` (the paper's), or ``_depth_cost_robust`` when ``depth_robust``.
    """
    n_views = R_cams_from_local.shape[0]
    npx = width * height
    count_q = _query_counts(query)
    idx, lab, dep = _scored_pixels(query, query_depth, use_depth)
    for chunk in prange(n_chunks):
        inv_z = np.empty(npx)
        tri_id = np.empty(npx, dtype=np.int32)
        inter = np.empty(N_SLOTS)
        count_r = np.empty(N_SLOTS)
        for v in range(chunk, n_views, n_chunks):
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
            inter[:] = 0.0
            count_r[:] = 0.0
            # One pass: the class histogram and the depth fit's sums (affine: n, dq, dr, dq^2, dq dr;
            # robust: a = dq / dr, b = 1 / dr with n, a^2, a b, b^2, a, b). Pixel order as before, so the
            # sums are the same numbers.
            n = 0.0
            s1 = 0.0
            s2 = 0.0
            s3 = 0.0
            s4 = 0.0
            s5 = 0.0
            for k in range(idx.shape[0]):
                p = idx[k]
                q = lab[k]
                f = tri_id[p]
                r = classes[f] if f >= 0 else 0
                count_r[r] += 1.0
                if r == q:
                    inter[r] += 1.0
                dq = dep[k]
                if dq > 0.0 and f >= 0:
                    n += 1.0
                    if depth_robust:
                        b = inv_z[p]
                        a = dq * b
                        s1 += a * a
                        s2 += a * b
                        s3 += b * b
                        s4 += a
                        s5 += b
                    else:
                        dr = 1.0 / inv_z[p]
                        s1 += dq
                        s2 += dr
                        s3 += dq * dq
                        s4 += dq * dr
            sem_out[v] = _mean_iou(inter, count_r, count_q, class_on)
            if not use_depth:
                depth_out[v] = 0.0
            elif depth_robust:
                depth_out[v] = _depth_cost_robust(
                    idx, dep, tri_id, inv_z, n, s1, s2, s3, s4, s5, depth_cap, min_depth_pixels, invalid_cost
                )
            else:
                depth_out[v] = _depth_cost_affine(
                    idx, dep, tri_id, inv_z, n, s1, s2, s3, s4, min_depth_pixels, invalid_cost
                )

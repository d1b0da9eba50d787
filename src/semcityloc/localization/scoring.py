"""The two alignment terms of the paper, as plain numpy reference implementations.

Semantic score ``C_s`` (paper eq. for C^s): mean over classes of the per-class IoU between a rendered
label mask and the query mask. Our definition of the details, chosen and documented in docs/localization.md:
- Classes taking part: ground, wall, roof, and window/door when the map has them (``classes``).
  Background is excluded: in a query it is sky, trees, cars — things the model does not describe.
- Query pixels labelled background (or ``ignore``) are ignored in both masks: an occluder hides the
  model, so what the model renders there is neither confirmed nor contradicted.
- A class absent from both masks is left out of the mean (it says nothing); absent from one and present
  in the other scores 0. If no class is present at all, the score is 0.

Depth cost ``C_d``: on pixels where both depths are valid, solve ``s*, t*`` minimising
``sum (s D_q + t - D_r)^2`` (least squares, closed form), then ``C_d = mean(|s* D_q + t* - D_r| / D_r)``.
Invariant to any positive scale and any shift of ``D_q``. A negative ``s*`` (inverted depth) or too few
valid pixels gives the worst cost ``DEPTH_COST_INVALID``.
"""

from __future__ import annotations

import numpy as np

from semcityloc.classes import IGNORE, NUM_CLASSES, SemanticClass

DEPTH_COST_INVALID = 1.0
MIN_DEPTH_PIXELS = 16


def semantic_score(rendered: np.ndarray, query: np.ndarray, classes: tuple[int, ...]) -> float:
    """Mean per-class IoU over ``classes`` (see module docstring for absent and ignored classes)."""
    r = np.asarray(rendered).reshape(-1)
    q = np.asarray(query).reshape(-1)
    valid = (q != SemanticClass.BACKGROUND) & (q != IGNORE)
    r, q = r[valid], q[valid]
    ious = []
    for c in classes:
        in_r, in_q = r == c, q == c
        union = np.count_nonzero(in_r | in_q)
        if union:
            ious.append(np.count_nonzero(in_r & in_q) / union)
    return float(np.mean(ious)) if ious else 0.0


def fit_scale_shift(d_query: np.ndarray, d_render: np.ndarray) -> tuple[float, float]:
    """Least-squares ``s, t`` with ``s * d_query + t ~ d_render`` (1D arrays of valid pixels)."""
    n = len(d_query)
    sq, sr = d_query.sum(), d_render.sum()
    sqq, sqr = (d_query * d_query).sum(), (d_query * d_render).sum()
    det = n * sqq - sq * sq
    if det <= 1e-12 * max(n * sqq, 1e-300):
        return 0.0, float(sr / max(n, 1))
    s = (n * sqr - sq * sr) / det
    t = (sr - s * sq) / n
    return float(s), float(t)


def _depth_pairs(
    d_query: np.ndarray, d_render: np.ndarray, query_positive: bool
) -> tuple[np.ndarray, np.ndarray] | None:
    """The float64 (query, render) depths of the pixels both costs compare: finite on both sides, the
    render's positive (and the query's too when ``query_positive``); None when fewer than
    ``MIN_DEPTH_PIXELS``."""
    dq = np.asarray(d_query, dtype=np.float64).reshape(-1)
    dr = np.asarray(d_render, dtype=np.float64).reshape(-1)
    valid = np.isfinite(dq) & np.isfinite(dr) & (dr > 0)
    if query_positive:
        valid &= dq > 0
    if np.count_nonzero(valid) < MIN_DEPTH_PIXELS:
        return None
    return dq[valid], dr[valid]


def depth_cost(d_query: np.ndarray, d_render: np.ndarray) -> float:
    """Affine-invariant depth cost ``C_d`` (lower is better); invalid depth is NaN/inf/<= 0."""
    pixels = _depth_pairs(d_query, d_render, query_positive=False)
    if pixels is None:
        return DEPTH_COST_INVALID
    dq, dr = pixels
    s, t = fit_scale_shift(dq, dr)
    if s <= 0:
        return DEPTH_COST_INVALID
    return float(np.mean(np.abs(s * dq + t - dr) / dr))


def robust_depth_cost(d_query: np.ndarray, d_render: np.ndarray, cap: float) -> float:
    """The refinement's depth cost (``kernels._depth_cost_robust``, ``RefineConfig.depth_cost="robust"``)
    in numpy: scale/shift by relative least squares (``s d_q + t ~ d_r`` with every residual divided by
    ``d_r``), then the mean relative residual with each pixel's capped at ``cap``. 1D arrays of the pixels
    to compare; invalid depth (NaN, inf, <= 0) on either side is left out."""
    pixels = _depth_pairs(d_query, d_render, query_positive=True)
    if pixels is None:
        return DEPTH_COST_INVALID
    dq, dr = pixels
    a, b = dq / dr, 1.0 / dr
    # numpy's own sums, not BLAS dot products: a BLAS dot of ~10^4 terms splits across its threads, and a
    # process with another thread count (a Ray worker) would round the cost differently.
    saa, sab, sbb, sa, sb = np.sum(a * a), np.sum(a * b), np.sum(b * b), a.sum(), b.sum()
    det = saa * sbb - sab * sab
    if det <= 1e-12 * saa * sbb:
        return DEPTH_COST_INVALID
    s = (sa * sbb - sb * sab) / det
    t = (saa * sb - sab * sa) / det
    if s <= 0:
        return DEPTH_COST_INVALID
    return float(np.mean(np.minimum(np.abs(s * a + t * b - 1.0), cap)))


def map_classes(has_openings: bool) -> tuple[int, ...]:
    """Classes that take part in the IoU for a map with or without window/door surfaces."""
    base = (SemanticClass.GROUND, SemanticClass.WALL, SemanticClass.ROOF)
    if has_openings:
        base = base + (SemanticClass.WINDOW, SemanticClass.DOOR)
    return tuple(int(c) for c in base)


def merge_openings_lut(has_openings: bool) -> np.ndarray:
    """Lookup table applied to query labels: window/door become wall when the map has no openings."""
    lut = np.arange(256, dtype=np.uint8)
    if not has_openings:
        lut[SemanticClass.WINDOW] = SemanticClass.WALL
        lut[SemanticClass.DOOR] = SemanticClass.WALL
    lut[NUM_CLASSES:IGNORE] = IGNORE
    return lut

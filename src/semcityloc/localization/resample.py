"""Block downsampling of a query's label mask and depth map (numba kernels used by ``query.py``).

Why kernels: every query is brought to the search's resolutions several times (labels at the coarse and
fine sizes, depth there and at the depth checks' widths). The numpy form (a ``bincount`` over
``target pixel * 256 + label``) allocated 256 bins per target pixel and took about 50 ms of a 0.5 s
localization; these single passes over the source take about a millisecond.

Target pixel of a source pixel: row ``(i * dst_h) // h``, column ``(j * dst_w) // w`` (contiguous blocks,
every target pixel gets at least one source pixel when ``h >= dst_h`` and ``w >= dst_w``: the kernels
refuse anything else, ``query.py`` upsamples by nearest neighbour instead). Results equal the numpy form
bit for bit: the majority takes the smallest label on ties, and a block's depth sum adds its pixels in
row-major order, the order ``bincount`` adds them.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def majority_labels(labels, dst_h, dst_w):
    """(dst_h, dst_w) uint8: the most frequent label of each block of ``labels`` (h, w) uint8."""
    h, w = labels.shape
    if not (1 <= dst_h <= h and 1 <= dst_w <= w):
        raise ValueError("majority_labels only downsamples: 1 <= target size <= source size")
    out = np.empty((dst_h, dst_w), np.uint8)
    cols = (np.arange(w) * dst_w) // w
    hist = np.zeros((dst_w, 256), np.int64)
    top = 0  # largest label seen in the current block row: the vote reads bins 0..top only
    row = 0
    for i in range(h + 1):
        r = (i * dst_h) // h if i < h else dst_h
        if r != row:
            for c in range(dst_w):
                best = 0
                count = hist[c, 0]
                for k in range(1, top + 1):
                    if hist[c, k] > count:
                        best = k
                        count = hist[c, k]
                out[row, c] = best
                hist[c, : top + 1] = 0
            row = r
            top = 0
        if i == h:
            break
        for j in range(w):
            k = labels[i, j]
            hist[cols[j], k] += 1
            if k > top:
                top = k
    return out


@njit(cache=True)
def mean_depth(depth, dst_h, dst_w):
    """(dst_h, dst_w) float64: the mean of each block's finite positive values of ``depth`` (h, w) float64,
    NaN where a block has none."""
    h, w = depth.shape
    if not (1 <= dst_h <= h and 1 <= dst_w <= w):
        raise ValueError("mean_depth only downsamples: 1 <= target size <= source size")
    cols = (np.arange(w) * dst_w) // w
    sums = np.zeros((dst_h, dst_w))
    counts = np.zeros((dst_h, dst_w), np.int64)
    for i in range(h):
        r = (i * dst_h) // h
        for j in range(w):
            d = depth[i, j]
            if np.isfinite(d) and d > 0:
                sums[r, cols[j]] += d
                counts[r, cols[j]] += 1
    out = np.empty((dst_h, dst_w))
    for r in range(dst_h):
        for c in range(dst_w):
            out[r, c] = sums[r, c] / counts[r, c] if counts[r, c] > 0 else np.nan
    return out

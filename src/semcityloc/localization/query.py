"""The query side as the search sees it: a label mask and an optional relative depth map, resampled.

Labels are downsampled by majority vote over the source pixels that fall in each target pixel (robust to
boundary noise, unlike sampling one pixel); depth by the median of its valid source pixels. Labels
outside the model's classes become IGNORE; window/door merge into wall when the map has no openings.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semcityloc.classes import BUILDING_CLASSES, IGNORE, NUM_CLASSES
from semcityloc.errors import ShapeError
from semcityloc.localization.scoring import merge_openings_lut


def _block_index(src_h: int, src_w: int, dst_h: int, dst_w: int) -> np.ndarray:
    """(src_h, src_w) index of the target pixel each source pixel falls in."""
    rows = (np.arange(src_h) * dst_h) // src_h
    cols = (np.arange(src_w) * dst_w) // src_w
    return rows[:, None] * dst_w + cols[None, :]


def downsample_labels(labels: np.ndarray, width: int, height: int) -> np.ndarray:
    """Majority label per target pixel; ties go to the smaller class id. Returns (height, width) uint8."""
    labels = np.asarray(labels)
    h, w = labels.shape
    if (h, w) == (height, width):
        return labels.astype(np.uint8, copy=True)
    if h < height or w < width:
        # Upsampling: nearest neighbour at pixel centres.
        rows = np.minimum(((np.arange(height) + 0.5) * h / height).astype(int), h - 1)
        cols = np.minimum(((np.arange(width) + 0.5) * w / width).astype(int), w - 1)
        return labels[rows[:, None], cols[None, :]].astype(np.uint8)
    idx = _block_index(h, w, height, width)
    hist = np.bincount((idx * 256 + labels.astype(np.int64)).reshape(-1), minlength=height * width * 256)
    return hist.reshape(height * width, 256).argmax(1).astype(np.uint8).reshape(height, width)


def downsample_depth(depth: np.ndarray, width: int, height: int) -> np.ndarray:
    """Mean of the finite positive source depths per target pixel (NaN where none)."""
    depth = np.asarray(depth, dtype=np.float64)
    h, w = depth.shape
    if (h, w) == (height, width):
        return np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)
    if h < height or w < width:
        rows = np.minimum(((np.arange(height) + 0.5) * h / height).astype(int), h - 1)
        cols = np.minimum(((np.arange(width) + 0.5) * w / width).astype(int), w - 1)
        d = depth[rows[:, None], cols[None, :]]
        return np.where(np.isfinite(d) & (d > 0), d, np.nan)
    idx = _block_index(h, w, height, width).reshape(-1)
    d = depth.reshape(-1)
    ok = np.isfinite(d) & (d > 0)
    sums = np.bincount(idx[ok], weights=d[ok], minlength=height * width)
    counts = np.bincount(idx[ok], minlength=height * width)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    return out.reshape(height, width)


@dataclass
class Query:
    """A query prepared for the search: labels in model classes, depth as float64 with NaN = invalid."""

    labels: np.ndarray  # (H, W) uint8
    depth: np.ndarray | None  # (H, W) float64 or None

    @classmethod
    def from_arrays(cls, labels: np.ndarray, depth: np.ndarray | None, has_openings: bool) -> Query:
        labels = np.asarray(labels)
        if labels.ndim != 2 or labels.size == 0:
            raise ShapeError(f"semantic mask must be a non-empty (H, W) array, got shape {labels.shape}")
        if not np.issubdtype(labels.dtype, np.integer):
            raise ShapeError(f"semantic mask must hold integer class ids, got dtype {labels.dtype}")
        clipped = np.where((labels >= 0) & (labels < 256), labels, IGNORE).astype(np.uint8)
        clipped = merge_openings_lut(has_openings)[clipped]
        d = None
        if depth is not None:
            d = np.asarray(depth, dtype=np.float64)
            if d.ndim != 2 or d.size == 0:
                raise ShapeError(f"depth must be a non-empty (H, W) array, got shape {d.shape}")
            if d.shape != labels.shape:
                # Depth at another resolution is fine: bring it to the mask's size.
                d = downsample_depth(d, labels.shape[1], labels.shape[0])
            d = np.where(np.isfinite(d) & (d > 0), d, np.nan)
        return cls(clipped, d)

    def building_fraction(self) -> float:
        """Share of pixels labelled wall, roof, window or door."""
        return float(np.isin(self.labels, BUILDING_CLASSES).mean())

    def at(self, width: int, height: int) -> tuple[np.ndarray, np.ndarray | None]:
        """Labels (flat uint8) and depth (flat float64 or None) at a search resolution."""
        labels = downsample_labels(self.labels, width, height)
        labels[labels >= NUM_CLASSES] = IGNORE
        depth = None if self.depth is None else downsample_depth(self.depth, width, height)
        return labels.reshape(-1), None if depth is None else depth.reshape(-1)


# Depth quality (``depth_problem``): a depth map that cannot inform the search is dropped, with the reason,
# and the query is localized on semantics alone (a bad depth term can pull the pose metres off).
DEPTH_CHECK_WIDTH = 64  # checked at about the search's resolution: pixel noise there is what the cost sees
DEPTH_MIN_VALID = 0.05  # share of valid pixels below which the depth says too little
DEPTH_MIN_RELIEF = 1e-3  # (p95 - p5) / median below which the depth is constant
# Median absolute difference of neighbouring valid pixels over the interquartile range. Depth of a scene is
# piecewise smooth: jumps sit at a few edges, so the median neighbour step is small next to the spread;
# for pixel noise the two are of one size (independent noise: 0.7). Measured: clean and realistic
# simulated depth <= 0.2 at this resolution (docs/reliability.md).
DEPTH_MAX_ROUGHNESS = 0.4


def depth_roughness(depth: np.ndarray, width: int = DEPTH_CHECK_WIDTH) -> float:
    """Median absolute step between neighbouring valid pixels over the interquartile range of the depth,
    at ``width`` pixels wide (NaN when there are too few valid neighbours or no spread)."""
    d = np.asarray(depth, dtype=np.float64)
    h, w = d.shape
    d = downsample_depth(d, width, max(1, round(h * width / w))) if w > width else d
    d = np.where(np.isfinite(d) & (d > 0), d, np.nan)
    steps = np.concatenate([np.abs(np.diff(d, axis=1)).ravel(), np.abs(np.diff(d, axis=0)).ravel()])
    steps = steps[np.isfinite(steps)]
    v = d[np.isfinite(d)]
    if steps.size < 16 or v.size < 16:
        return float("nan")
    p25, p75 = np.percentile(v, [25, 75])
    return float(np.median(steps) / (p75 - p25)) if p75 > p25 else float("nan")


def depth_problem(depth: np.ndarray, width: int = DEPTH_CHECK_WIDTH) -> str | None:
    """Why a relative depth map (NaN = invalid) is unusable for the search, or None when it is usable:
    no valid pixels, too few, constant, or noise (no spatial structure: ``depth_roughness``)."""
    d = np.asarray(depth, dtype=np.float64)
    valid = np.isfinite(d) & (d > 0)
    share = float(valid.mean()) if d.size else 0.0
    if share == 0.0:
        return "no valid pixels (all NaN, zero or negative)"
    if share < DEPTH_MIN_VALID:
        return f"only {100 * share:.1f}% of its pixels are valid (needs {100 * DEPTH_MIN_VALID:.0f}%)"
    p5, p50, p95 = np.percentile(d[valid], [5, 50, 95])
    if (p95 - p5) <= DEPTH_MIN_RELIEF * p50:
        return "it is constant (no relative depth to compare)"
    roughness = depth_roughness(d, width)
    if roughness > DEPTH_MAX_ROUGHNESS:
        return (
            f"it looks like noise (neighbouring pixels differ by {roughness:.2f} of the depth spread; "
            f"a scene's depth is smooth, <= {DEPTH_MAX_ROUGHNESS})"
        )
    return None

"""The query side as the search sees it: a label mask and an optional relative depth map, resampled.

Labels are downsampled by majority vote over the source pixels that fall in each target pixel (robust to
boundary noise, unlike sampling one pixel); depth by the mean of its valid source pixels. Labels
outside the model's classes become IGNORE; window/door merge into wall when the map has no openings.
A depth map too poor to use is dropped, and noise over part of one is blanked block by block, each with a
warning (``usable_depth``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import rankdata

from semcityloc.classes import BUILDING_CLASSES, IGNORE, NUM_CLASSES
from semcityloc.errors import ShapeError
from semcityloc.io.images import resize_nearest
from semcityloc.localization.resample import majority_labels, mean_depth
from semcityloc.localization.scoring import merge_openings_lut


def downsample_labels(labels: np.ndarray, width: int, height: int) -> np.ndarray:
    """Majority label per target pixel; ties go to the smaller class id. Returns (height, width) uint8."""
    labels = np.asarray(labels)
    h, w = labels.shape
    if (h, w) == (height, width):
        return labels.astype(np.uint8, copy=True)
    if h < height or w < width:
        return resize_nearest(labels, width, height).astype(np.uint8)  # upsampling
    return majority_labels(np.ascontiguousarray(labels, dtype=np.uint8), height, width)


def downsample_depth(depth: np.ndarray, width: int, height: int) -> np.ndarray:
    """Mean of the finite positive source depths per target pixel (NaN where none)."""
    depth = np.asarray(depth, dtype=np.float64)
    h, w = depth.shape
    if (h, w) == (height, width):
        return np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)
    if h < height or w < width:
        d = resize_nearest(depth, width, height)
        return np.where(np.isfinite(d) & (d > 0), d, np.nan)
    return mean_depth(np.ascontiguousarray(depth), height, width)


@dataclass
class Query:
    """A query prepared for the search: labels in model classes, depth as float64 with NaN = invalid."""

    labels: np.ndarray  # (H, W) uint8
    depth: np.ndarray | None  # (H, W) float64 or None

    @classmethod
    def from_arrays(cls, labels: np.ndarray, depth: np.ndarray | None, has_openings: bool) -> Query:
        """A query from a label mask and optional depth, checked; out-of-range labels are IGNORE."""
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


def _at_width(depth: np.ndarray, width: int) -> np.ndarray:
    """``depth`` brought down to at most ``width`` pixels wide (``downsample_depth``), NaN = invalid."""
    d = np.asarray(depth, dtype=np.float64)
    h, w = d.shape
    d = downsample_depth(d, width, max(1, round(h * width / w))) if w > width else d
    return np.where(np.isfinite(d) & (d > 0), d, np.nan)


def _step_stats(d: np.ndarray) -> tuple[float, float, float] | None:
    """(median absolute step between neighbouring valid pixels, interquartile range, median) of the valid
    pixels of ``d``; None when there are too few valid neighbours or no spread."""
    steps = np.concatenate([np.abs(np.diff(d, axis=1)).ravel(), np.abs(np.diff(d, axis=0)).ravel()])
    steps = steps[np.isfinite(steps)]
    v = d[np.isfinite(d)]
    if steps.size < 16 or v.size < 16:
        return None
    p25, p50, p75 = np.percentile(v, [25, 50, 75])
    return (float(np.median(steps)), float(p75 - p25), float(p50)) if p75 > p25 else None


def depth_roughness(depth: np.ndarray, width: int = DEPTH_CHECK_WIDTH) -> float:
    """Median absolute step between neighbouring valid pixels over the interquartile range of the depth,
    at ``width`` pixels wide (NaN when there are too few valid neighbours or no spread)."""
    stats = _step_stats(_at_width(depth, width))
    return float("nan") if stats is None else stats[0] / stats[1]


def depth_problem(depth: np.ndarray, width: int = DEPTH_CHECK_WIDTH) -> str | None:
    """Why a relative depth map (NaN = invalid) is unusable for the search, or None when it is usable:
    no valid pixels, too few, constant, or noise (no spatial structure: ``depth_roughness``)."""
    d = np.asarray(depth, dtype=np.float64)
    valid = np.isfinite(d) & (d > 0)
    share = float(valid.mean()) if d.size else 0.0
    if share == 0.0:
        return "no valid pixels (all NaN, infinite, zero or negative)"
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


# Noise over PART of the image (a region replaced by noise, a sensor's dead band): the whole map's roughness
# stays low, so the check is repeated per block. At the search's 64 px the noise is averaged into a flat,
# wrong surface that looks like a smooth one; at ``DEPTH_BLOCK_WIDTH`` its pixels are still independent.
# A block is noise when BOTH hold (``block_measures``):
# - its roughness (``depth_roughness``'s measure, inside the block) exceeds ``DEPTH_MAX_ROUGHNESS``: no
#   structure. Alone this is not enough: a flat roof or street of good depth is a block of its own pixel
#   noise around a constant, as rough as noise;
# - its relative step (median neighbour step over the block's median depth) is ``DEPTH_MAX_BLOCK_STEP``
#   times that of the image's smooth blocks (the ``DEPTH_BLOCK_REFERENCE`` percentile over the blocks, so
#   that up to 90 % of the blocks may be noise): the pixel noise of good depth is about the same share of
#   the depth everywhere, noise differs by a share of the depth's whole range.
# Measured (``benchmarks/depth_quality.py``, docs/reliability.md): good simulated depth's worst rough block
# 1.32 times the reference, blocks of uniform noise at least 9 times.
DEPTH_BLOCK_WIDTH = 256  # the block check's width (square blocks of DEPTH_BLOCK_WIDTH / DEPTH_BLOCK_COLUMNS)
DEPTH_BLOCK_COLUMNS = 8
DEPTH_BLOCK_MIN_VALID = 0.25  # share of valid pixels a block needs to be judged (others are kept as they are)
DEPTH_BLOCK_REFERENCE = 10.0  # percentile of the blocks' relative steps taken as the smooth surfaces' step
DEPTH_MAX_BLOCK_STEP = 3.0
SEMANTICS_ALONE = "; localized on the semantic mask alone"  # the end of a warning that dropped the whole map

# Depth that runs backwards: many monocular networks (Depth Anything, MiDaS) output relative DISPARITY
# (inverse depth, larger = nearer), which the depth cost cannot fit (its scale comes out negative at every
# pose, so depth then only lowers the confidence). Told from the map: the rank correlation of the query's
# depth with the map's depth seen from the search's best hypothesis; below this the query runs the other
# way (set before measuring; no realistic depth of the calibration cities' 800 views, flown 40-150 m,
# 15-30 m, or with a 34 deg camera, fell below it: their poses were unchanged by the check, stop 37).
DEPTH_INVERTED_RANK_CORRELATION = -0.3
DEPTH_INVERTED_MIN_PIXELS = 50


def depth_rank_correlation(query_depth: np.ndarray, map_depth: np.ndarray) -> float:
    """Spearman rank correlation of two same-shaped depth maps over the pixels valid in both (finite,
    > 0); NaN with fewer than ``DEPTH_INVERTED_MIN_PIXELS`` such pixels or no spread."""
    q = np.asarray(query_depth, dtype=np.float64).reshape(-1)
    m = np.asarray(map_depth, dtype=np.float64).reshape(-1)
    if q.shape != m.shape:
        raise ValueError(f"depth maps of {q.size} and {m.size} pixels")  # internal invariant
    both = np.isfinite(q) & (q > 0) & np.isfinite(m) & (m > 0)
    if both.sum() < DEPTH_INVERTED_MIN_PIXELS:
        return float("nan")
    rq, rm = rankdata(q[both]), rankdata(m[both])
    if rq.std() == 0 or rm.std() == 0:
        return float("nan")
    return float(np.corrcoef(rq, rm)[0, 1])


def inverted_depth_warning(rank_correlation: float) -> str | None:
    """The warning for a query depth that runs against the map's (``DEPTH_INVERTED_RANK_CORRELATION``),
    else None."""
    if not rank_correlation < DEPTH_INVERTED_RANK_CORRELATION:
        return None
    return (
        f"depth map dropped: it runs backwards against the map (rank correlation {rank_correlation:+.2f} "
        "at the best hypothesis: larger values nearer, a disparity or inverse-depth map?); give depth that "
        f"grows with distance (for a network's disparity, 1 / disparity){SEMANTICS_ALONE}"
    )


COARSE_MASK_WARNING = "semantic mask coarser than the refinement"


def check_mask_pixels(mask_shape: tuple[int, int], level_width: int, level_height: int) -> None:
    """``ShapeError`` for a mask with fewer pixels than the search's coarsest level (``level_width`` x
    ``level_height``, the sweep's pixel budget). Why: every level would enlarge it, and a 10 x 8 mask was
    accepted 9 m off with only ``coarse_mask_warning`` said; such a mask is a wrong file, not a query."""
    height, width = mask_shape
    if width * height < level_width * level_height:
        raise ShapeError(
            f"semantic mask {width}x{height} has fewer pixels than the search's coarsest level "
            f"({level_width}x{level_height}): give the mask at the photo's resolution"
        )


def coarse_mask_warning(mask_shape: tuple[int, int], fine_width: int, fine_height: int) -> str | None:
    """The warning for a mask with fewer pixels across or down than the refinement's final level
    (``fine_width`` x ``fine_height``, ``Localizer.fine_camera``), else None. Why: the refinement and the
    acceptance read the mask at that level, so a coarser mask is enlarged to it; the pose can be no finer
    than the mask's pixels, and the acceptance probability was fitted on masks of 512 x 384."""
    height, width = mask_shape
    if width >= fine_width and height >= fine_height:
        return None
    return (
        f"{COARSE_MASK_WARNING} ({width}x{height} against {fine_width}x{fine_height}): the pose is no finer "
        "than the mask's pixels and its probability was fitted on finer masks; give the mask at the photo's "
        "resolution or at least the refinement's"
    )


@dataclass(frozen=True)
class BlockMeasures:
    """Per block of a depth map (``block_measures``): (rows, cols) roughness and relative step over the
    reference (NaN where a block is not judged), and each source pixel's block row and column."""

    roughness: np.ndarray
    step_ratio: np.ndarray
    pixel_row: np.ndarray  # (H,) block row of each source row
    pixel_col: np.ndarray  # (W,) block column of each source column

    @property
    def noisy(self) -> np.ndarray:
        """(rows, cols) bool: the blocks that look like noise (the comment above ``DEPTH_BLOCK_WIDTH``)."""
        return (self.roughness > DEPTH_MAX_ROUGHNESS) & (self.step_ratio > DEPTH_MAX_BLOCK_STEP)


def block_measures(depth: np.ndarray, width: int = DEPTH_BLOCK_WIDTH) -> BlockMeasures:
    """The per-block measures of a relative depth map (NaN = invalid) at ``width`` pixels wide."""
    full = np.asarray(depth, dtype=np.float64)
    d = _at_width(full, width)
    h, w = d.shape
    size = max(2, -(-w // DEPTH_BLOCK_COLUMNS))
    rows, cols = -(-h // size), -(-w // size)
    # Every block at once (it runs on every query): (rows, cols, size, size), NaN beyond the map's edge.
    padded = np.full((rows * size, cols * size), np.nan)
    padded[:h, :w] = d
    blocks = padded.reshape(rows, size, cols, size).swapaxes(1, 2)
    steps = np.concatenate(
        [
            np.abs(np.diff(blocks, axis=3)).reshape(rows, cols, -1),
            np.abs(np.diff(blocks, axis=2)).reshape(rows, cols, -1),
        ],
        axis=2,
    )
    values = blocks.reshape(rows, cols, -1)
    median_step, n_steps = _finite_quantiles(steps, (0.5,))
    (p25, p50, p75), n_values = _finite_quantiles(values, (0.25, 0.5, 0.75))
    pixels = np.minimum(size, h - size * np.arange(rows))[:, None] * np.minimum(
        size, w - size * np.arange(cols)
    )
    judged_blocks = (
        (n_steps >= 16) & (n_values >= 16) & (p75 > p25) & (n_values / pixels >= DEPTH_BLOCK_MIN_VALID)
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        roughness = np.where(judged_blocks, median_step[0] / (p75 - p25), np.nan)
        step = np.where(judged_blocks, median_step[0] / p50, np.nan)
    judged = step[np.isfinite(step)]
    reference = float(np.percentile(judged, DEPTH_BLOCK_REFERENCE)) if judged.size else 0.0
    ratio = step / reference if reference > 0 else np.full_like(step, np.nan)
    H, W = full.shape
    pixel_row = (np.arange(H) * h // H) // size  # the check pixel of each source pixel, then its block
    pixel_col = (np.arange(W) * w // W) // size
    return BlockMeasures(roughness, ratio, pixel_row, pixel_col)


def _finite_quantiles(x: np.ndarray, qs: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """((len(qs), ...) quantiles of the finite values along the last axis, numpy's linear method; the
    count of finite values), NaN where there are none: ``np.nanpercentile`` without its per-row loop."""
    finite = np.isfinite(x)
    n = finite.sum(axis=-1)
    ordered = np.sort(np.where(finite, x, np.inf), axis=-1)  # the finite values first, in order
    out = []
    for q in qs:
        pos = q * np.maximum(n - 1, 0)
        lo = np.floor(pos).astype(np.intp)
        hi = np.minimum(lo + 1, np.maximum(n - 1, 0))
        a = np.take_along_axis(ordered, lo[..., None], axis=-1)[..., 0]
        b = np.take_along_axis(ordered, hi[..., None], axis=-1)[..., 0]
        with np.errstate(invalid="ignore"):
            out.append(np.where(n > 0, a + (b - a) * (pos - lo), np.nan))
    return np.stack(out), n


def usable_depth(depth: np.ndarray | None) -> tuple[np.ndarray | None, str | None]:
    """(the depth the search may use, a warning or None) of a relative depth map (NaN = invalid).

    A map unusable as a whole (``depth_problem``) is dropped: (None, why). Else the blocks that look like
    noise (``block_measures``) are set to NaN and the rest is kept, the warning naming the share dropped;
    if what is left is unusable, the map is dropped. Good depth comes back unchanged, without a warning.
    """
    if depth is None:
        return None, None
    problem = depth_problem(depth)
    if problem is not None:
        return None, f"depth map dropped: {problem}{SEMANTICS_ALONE}"
    measures = block_measures(depth)
    noisy = measures.noisy
    if not noisy.any():
        return depth, None
    d = np.asarray(depth, dtype=np.float64)
    valid = np.isfinite(d) & (d > 0)
    drop = noisy[measures.pixel_row[:, None], measures.pixel_col[None, :]] & valid
    kept = np.where(drop, np.nan, d)
    share = 100.0 * drop.sum() / max(int(valid.sum()), 1)
    why = (
        f"{int(noisy.sum())} of {noisy.size} blocks look like noise (no structure, pixel steps over "
        f"{DEPTH_MAX_BLOCK_STEP:g} times those of the smooth surfaces)"
    )
    problem = depth_problem(kept)
    if problem is not None:
        return None, f"depth map dropped: {why}, and the rest: {problem}{SEMANTICS_ALONE}"
    return kept, f"depth dropped over {share:.0f}% of its valid pixels: {why}; the rest is used"

"""Simulated perception for the benchmark: a noisy segmentation and a MoGe-2-like relative depth map.

Why: the paper's queries come from a DINOv3 segmentation head (88 % mIoU on SemCityLockeD when trained,
32-37 % zero-shot) and MoGe-2 depth. The benchmark renders the *clean* labels and depth of a simulated
reality and degrades them here with the error types such networks make, at a tunable quality, so every
change of the localizer can be measured against a known truth.

Segmentation (``simulate_segmentation``). Ground, wall, roof and background are "stuff" and get the
stuff noise; windows and doors are small "things" handled on their own, because at 512 px a window is
about 6 x 7 px and any pixel of boundary noise would erase it. In this order:

1. openings: each window / door (connected component) is found with probability 1 - ``opening_to_wall``;
   its pixels become wall in the stuff map either way;
2. class confusions: for each ``(from, to, area, cell_px)`` in ``confusions``, the ``from`` pixels inside
   smooth random regions covering about ``area`` of the image (blobs of roughly ``cell_px`` pixels) are
   relabelled ``to`` (wall <-> roof patches, roof <-> ground; zero-shot: large ground / roof swaps and
   facades lost to background);
3. mislabelled blobs: a Poisson(``blobs``) number of ellipses of radius ``blob_radius`` (share of the
   image's shorter side) painted with a random class from ``blob_classes``. Found openings whose facade
   pixels were taken by steps 2-3 are dropped;
4. boundary noise: a smooth random displacement field of amplitude ``boundary_px`` warps the stuff map
   (boundaries wobble by about that many pixels; the openings follow ``opening_warp`` of it), then each
   stuff class in a random order is dilated by 1..``dilate_px`` pixels with probability 1/2 (systematic
   over / under-segmentation: dilating one class erodes its neighbours; ``scipy.ndimage``);
5. patch resolution (ViT/16 + a light decoder): class shares are block-averaged over ``patch_px`` x
   ``patch_px`` patches and bilinearly upsampled; a pixel keeps its own class unless another class's
   upsampled share beats its own by more than ``patch_detail`` (0 = pure patch argmax, 1 = no blur);
6. the found openings (eroded by ``opening_erode_px``) are pasted over the result: sharp small things, as
   the decoder's high-resolution path gives them.

With ``truth`` (a ``seg_errors.ViewTruth`` of the view: normals, buildings, what is behind trees and
cars, cast shadows), the preset's structured errors (``SegPreset`` fields from ``occluder_to_behind`` on,
all 0 = off by default; ``seg_errors`` module docstring) are applied to the clean labels first, from a
generator seeded by one draw of ``rng`` taken only then; steps 1-6 follow on the result. Without
``truth`` nothing changes: the same generator state gives the same output as before those fields existed.

Occluders (trees, cars) are already BACKGROUND in the clean labels of the reality render, so they stay
background here unless noise moves a boundary over them.

Presets (``SEG_PRESETS``) were tuned on 100 simulated queries each of Berlin (LoD2), the generated city
with an LoD2 and with an LoD3 reality: "trained" 87.4 / 88.8 / 87.8 % mIoU, "medium" 77.7 / 78.5 / 78.7 %,
"zero-shot" 35.0 / 35.0 / 34.2 %, "perfect" 100 %.

Depth (``simulate_depth``): ``a * d + b`` with ``a`` log-uniform in [0.5, 2] and ``b`` uniform in
[-0.2, 0.5] x ``a`` x median depth (raised where needed so that ``a * d + b`` stays at least 5 % of
``a`` x median depth: always positive), times a smooth low-frequency distortion ``1 + 0.03 f`` (``f`` a
smooth field scaled to max |f| = 1), times per-pixel noise ``1 + s n`` (``s`` uniform in 1-2 %, ``n``
standard normal), with depth edges blurred across class boundaries (MoGe's "flying pixels": pixels on a
class boundary take the mean of their valid 3x3 neighbours). The occluders' own depth is in the input
(the reality render sees trees). NaN exactly where the clean depth is not finite (sky / nothing).

``miou``: mean IoU (%) over the classes present in the ground truth among ground, wall, roof, window,
door (background is not a class of the mean, but a predicted background pixel is a miss of its gt class).
Every random draw comes from the ``numpy.random.Generator`` passed in: same generator state -> same output.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from semcityloc.classes import NUM_CLASSES, SemanticClass
from semcityloc.errors import PerceptionSimError, ShapeError, unknown_choice
from semcityloc.perception.metrics import confusion, mean_iou

MIOU_CLASSES = (
    int(SemanticClass.GROUND),
    int(SemanticClass.WALL),
    int(SemanticClass.ROOF),
    int(SemanticClass.WINDOW),
    int(SemanticClass.DOOR),
)
# A class takes part in a query's mIoU when it covers at least this many ground-truth pixels: a class
# seen on a handful of pixels (a door corner at the image edge) would otherwise swing the mean by 20
# points on its own.
MIN_PRESENT_PIXELS = 50

DEPTH_SCALE_RANGE = (0.5, 2.0)
DEPTH_SHIFT_RANGE = (-0.2, 0.5)  # times scale x median depth
DEPTH_MIN_SHARE = 0.05  # every simulated depth stays at least this share of the (scaled) median
DEPTH_DISTORTION = 0.03  # amplitude of the smooth multiplicative distortion
DEPTH_DISTORTION_CELL = 0.35  # its correlation length, share of the image's longer side
DEPTH_NOISE_RANGE = (0.01, 0.02)  # per-pixel multiplicative noise, standard deviation

_W, _R, _G, _B = int(SemanticClass.WALL), int(SemanticClass.ROOF), int(SemanticClass.GROUND), 0


@dataclass(frozen=True)
class SegPreset:
    """Noise parameters of one simulated segmentation quality (module docstring, steps 1-6)."""

    name: str
    opening_to_wall: float = 0.0
    opening_erode_px: int = 0
    opening_warp: float = 1.0  # share of the boundary displacement the openings follow (0: exact place)
    confusions: tuple[tuple[int, int, float, int], ...] = ()  # (from, to, area share, blob size px)
    blobs: float = 0.0
    blob_radius: tuple[float, float] = (0.02, 0.06)
    blob_classes: tuple[int, ...] = (_B, _G, _W, _R)
    boundary_px: float = 0.0
    boundary_cell_px: int = 24
    dilate_px: int = 0
    patch_px: int = 16
    patch_detail: float = 1.0
    noise: bool = True  # False: the labels are returned unchanged ("perfect")
    # Structured errors (``seg_errors`` module docstring, steps 1-8), applied only when
    # ``simulate_segmentation`` is given a ``ViewTruth``; all off by default.
    occluder_to_behind: float = 0.0  # P(a tree / car is labelled as what lies behind it)
    steep_roof_nz: float = 0.0  # roofs with |n_z| below this are "steep" ...
    steep_roof_to_wall: float = 0.0  # ... and each steep roof component is called wall with this P
    low_wall_m: float = 0.0  # facade segments lower than this are "low" ...
    low_wall_to_roof: float = 0.0  # ... and each low-wall component is called roof with this P
    courtyard_share: float = 0.0  # enclosed non-building components below this image share ...
    courtyard_fill: float = 0.0  # ... are filled as roof with this P
    small_building_share: float = 0.0  # building components below this image share ...
    small_building_miss: float = 0.0  # ... are missed (labelled as their surroundings) with this P
    building_miss: float = 0.0  # P(a visible building is missed whole: labelled ground)
    segment_swaps: tuple[tuple[int, int, float], ...] = ()  # (from, to, P) per SAM-like segment
    segment_cell_px: int = 96  # size of the segments' warped grid cells
    shadow_error: float = 0.0  # share of the shadowed pixels that are mislabelled ...
    shadow_cell_px: int = 24  # ... in smooth regions of this size ...
    shadow_to_background: float = 0.5  # ... as background with this P, else as a neighbouring class
    bleed_px: int = 0  # the nearer surface grows 1..bleed_px px over the farther at depth jumps


SEG_PRESETS: dict[str, SegPreset] = {
    "perfect": SegPreset("perfect", noise=False),
    # A DINOv3 head trained on the city (paper: 88 % mIoU on SemCityLockeD): boundaries off by about a
    # pixel, a few small wall/roof and roof/ground confusions, 8 % of the openings missed.
    "trained": SegPreset(
        "trained",
        opening_to_wall=0.08,
        opening_warp=0.0,
        confusions=((_W, _R, 0.03, 40), (_R, _W, 0.02, 40), (_R, _G, 0.01, 48), (_G, _R, 0.01, 48)),
        blobs=1.0,
        blob_radius=(0.015, 0.04),
        boundary_px=1.0,
        dilate_px=1,
        patch_px=16,
        patch_detail=0.45,
    ),
    # A weaker trained head (paper: 78 % on Swiss-EPFL): wobblier boundaries, more confusions.
    "medium": SegPreset(
        "medium",
        opening_to_wall=0.12,
        opening_warp=0.0,
        confusions=((_W, _R, 0.07, 48), (_R, _W, 0.05, 48), (_R, _G, 0.035, 56), (_G, _R, 0.035, 56)),
        blobs=2.5,
        blob_radius=(0.02, 0.06),
        boundary_px=1.5,
        dilate_px=1,
        patch_px=16,
        patch_detail=0.25,
    ),
    # Zero-shot CLIP + Semantic-SAM / Grounded-SAM2 (paper: 32-37 %): ground and roof swapped over large
    # regions, facades lost to background or called roof, big wrong blobs, patch-level masks.
    "zero-shot": SegPreset(
        "zero-shot",
        opening_to_wall=0.4,
        opening_warp=0.0,
        confusions=(
            (_R, _G, 0.30, 96),
            (_G, _R, 0.25, 96),
            (_W, _B, 0.30, 80),
            (_W, _R, 0.25, 80),
            (_R, _W, 0.20, 80),
            (_G, _B, 0.15, 96),
        ),
        blobs=5.0,
        blob_radius=(0.05, 0.15),
        boundary_px=6.0,
        dilate_px=4,
        patch_px=16,
        patch_detail=0.0,
    ),
}


def get_preset(preset: str | SegPreset) -> SegPreset:
    """A preset by name (or the preset itself)."""
    if isinstance(preset, SegPreset):
        return preset
    try:
        return SEG_PRESETS[preset]
    except (KeyError, TypeError) as exc:
        raise unknown_choice("segmentation preset", preset, SEG_PRESETS, PerceptionSimError) from exc


# ------------------------------------------------------------------------------------------ helpers
def _check_labels(labels: np.ndarray, what: str = "labels") -> np.ndarray:
    labels = np.asarray(labels)
    if labels.ndim != 2 or labels.size == 0:
        raise ShapeError(f"{what} must be a non-empty (H, W) array, got shape {labels.shape}")
    if not np.issubdtype(labels.dtype, np.integer):
        raise ShapeError(f"{what} must hold integer class ids, got dtype {labels.dtype}")
    if labels.min() < 0 or labels.max() >= NUM_CLASSES:
        raise ShapeError(f"{what} must hold class ids 0..{NUM_CLASSES - 1}")
    return labels.astype(np.uint8, copy=False)


def _lerp_index(n_out: int, n_in: int, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear sampling of a grid with one node per ``step`` output pixels at the output pixel centres:
    (k0, w1) such that value = (1 - w1) g[k0] + w1 g[k0 + 1]. Node k sits at the centre of block k
    (output coordinate (k + 0.5) step); pixels beyond the first / last node take that node's value."""
    pos = np.clip((np.arange(n_out) + 0.5) / step - 0.5, 0.0, n_in - 1.0)
    k0 = np.minimum(np.floor(pos).astype(np.intp), max(n_in - 2, 0))
    return k0, pos - k0


def upsample_bilinear(grid: np.ndarray, height: int, width: int, step: float) -> np.ndarray:
    """(..., gh, gw) grid -> (..., height, width) by bilinear interpolation (``_lerp_index``). Elementwise
    only (no BLAS), so results are bit-identical on every machine."""
    gh, gw = grid.shape[-2:]
    ky, wy = _lerp_index(height, gh, step)
    kx, wx = _lerp_index(width, gw, step)
    ky1, kx1 = np.minimum(ky + 1, gh - 1), np.minimum(kx + 1, gw - 1)
    wy = wy.astype(grid.dtype)[:, None]
    wx = wx.astype(grid.dtype)
    rows = grid[..., ky, :] * (1 - wy) + grid[..., ky1, :] * wy
    return rows[..., kx] * (1 - wx) + rows[..., kx1] * wx


def smooth_field(rng: np.random.Generator, height: int, width: int, cell_px: float) -> np.ndarray:
    """(H, W) float32 smooth random field: standard normal values on a grid of ``cell_px`` spacing,
    bilinearly interpolated (values near a grid node are ~N(0, 1), between nodes smaller)."""
    cell = max(float(cell_px), 1.0)
    gh = int(np.ceil(height / cell)) + 1
    gw = int(np.ceil(width / cell)) + 1
    return upsample_bilinear(rng.standard_normal((gh, gw)).astype(np.float32), height, width, cell)


def _region(rng: np.random.Generator, shape: tuple[int, int], area: float, cell_px: float) -> np.ndarray:
    """Boolean mask of smooth random blobs covering about ``area`` of the image."""
    if area <= 0:
        return np.zeros(shape, dtype=bool)
    if area >= 1:
        return np.ones(shape, dtype=bool)
    h, w = shape
    # Threshold a quarter-resolution field (cheap quantile), then repeat it up to full size.
    hq, wq = -(-h // 4), -(-w // 4)
    field = smooth_field(rng, hq, wq, cell_px / 4.0)
    thr = np.quantile(field, 1.0 - area)
    small = field > thr
    return np.repeat(np.repeat(small, 4, axis=0), 4, axis=1)[:h, :w]


def _opening_layer(clean: np.ndarray, preset: SegPreset, rng: np.random.Generator) -> np.ndarray:
    """(H, W) uint8: the clean window / door pixels of the openings the network finds, 0 elsewhere.

    Each opening (connected component of one class) is missed with probability ``opening_to_wall``;
    the layer is then eroded by ``opening_erode_px`` (small openings vanish)."""
    layer = np.zeros_like(clean)
    for c in (SemanticClass.WINDOW, SemanticClass.DOOR):
        mask = clean == c
        if not mask.any():
            continue
        comp, n = ndimage.label(mask)
        keep = np.concatenate([[False], rng.random(n) >= preset.opening_to_wall])
        found = keep[comp]
        if preset.opening_erode_px > 0:
            found = ndimage.binary_erosion(found, iterations=int(preset.opening_erode_px))
        layer[found] = c
    return layer


def _paint_blobs(labels: np.ndarray, preset: SegPreset, rng: np.random.Generator) -> None:
    n = int(rng.poisson(preset.blobs)) if preset.blobs > 0 else 0
    if n == 0:
        return
    h, w = labels.shape
    side = min(h, w)
    cy = rng.uniform(0, h, n)
    cx = rng.uniform(0, w, n)
    ry = rng.uniform(*preset.blob_radius, n) * side
    rx = rng.uniform(*preset.blob_radius, n) * side
    angle = rng.uniform(0, np.pi, n)
    cls = rng.choice(np.asarray(preset.blob_classes, dtype=np.uint8), n)
    for k in range(n):
        r = max(rx[k], ry[k])
        i0, i1 = max(int(cy[k] - r), 0), min(int(cy[k] + r) + 1, h)
        j0, j1 = max(int(cx[k] - r), 0), min(int(cx[k] + r) + 1, w)
        if i0 >= i1 or j0 >= j1:
            continue
        yy = np.arange(i0, i1)[:, None] + 0.5 - cy[k]
        xx = np.arange(j0, j1)[None, :] + 0.5 - cx[k]
        c, s = math.cos(angle[k]), math.sin(angle[k])
        u, v = c * xx + s * yy, -s * xx + c * yy
        inside = (u / rx[k]) ** 2 + (v / ry[k]) ** 2 <= 1.0
        labels[i0:i1, j0:j1][inside] = cls[k]


def _displacement(shape: tuple[int, int], amplitude: float, cell_px: int, rng: np.random.Generator):
    """A smooth random displacement field (dy, dx) of ``amplitude`` pixels (both drawn even if 0)."""
    h, w = shape
    dy = smooth_field(rng, h, w, cell_px) * np.float32(amplitude)
    dx = smooth_field(rng, h, w, cell_px) * np.float32(amplitude)
    return dy, dx


def _warp(labels: np.ndarray, dy: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """``labels`` sampled at (row + dy, col + dx), nearest pixel, clamped at the image border."""
    h, w = labels.shape
    if not (dy.any() or dx.any()):
        return labels
    rows = np.rint(dy).astype(np.intp)
    rows += np.arange(h)[:, None]
    np.clip(rows, 0, h - 1, out=rows)
    cols = np.rint(dx).astype(np.intp)
    cols += np.arange(w)[None, :]
    np.clip(cols, 0, w - 1, out=cols)
    return labels[rows, cols]


def _dilate_classes(labels: np.ndarray, max_px: int, rng: np.random.Generator) -> None:
    if max_px <= 0:
        return
    classes = np.array([_G, _W, _R, SemanticClass.BACKGROUND], dtype=np.uint8)
    order = rng.permutation(len(classes))
    grow = rng.random(len(classes)) < 0.5
    radius = rng.integers(1, max_px + 1, len(classes))
    for k in order:
        if not grow[k]:
            continue
        mask = labels == classes[k]
        if not mask.any():
            continue
        grown = ndimage.binary_dilation(mask, iterations=int(radius[k]))
        labels[grown & ~mask] = classes[k]


def _patch_blur(labels: np.ndarray, patch_px: int, detail: float) -> np.ndarray:
    if detail >= 1.0 or patch_px <= 1:
        return labels
    h, w = labels.shape
    p = int(patch_px)
    hb, wb = -(-h // p), -(-w // p)
    # Class shares per patch (edge patches count only their pixels inside the image).
    block = (np.arange(h) // p)[:, None] * wb + (np.arange(w) // p)[None, :]
    counts = np.bincount((block * NUM_CLASSES + labels).reshape(-1), minlength=hb * wb * NUM_CLASSES)
    counts = counts.reshape(hb, wb, NUM_CLASSES)
    present = np.flatnonzero(counts.sum(axis=(0, 1))).astype(np.uint8)
    prob = counts[:, :, present].transpose(2, 0, 1).astype(np.float32)
    prob /= np.maximum(prob.sum(axis=0, keepdims=True), 1.0)
    score = upsample_bilinear(prob, h, w, p)  # (C, H, W)
    lut = np.full(NUM_CLASSES, -1, dtype=np.intp)
    lut[present] = np.arange(len(present))
    score[lut[labels], np.arange(h)[:, None], np.arange(w)[None, :]] += np.float32(detail)
    return present[np.argmax(score, axis=0)]


# ------------------------------------------------------------------------------------------ public
def simulate_segmentation(
    clean_labels: np.ndarray, preset: str | SegPreset, rng: np.random.Generator, truth=None
) -> np.ndarray:
    """A noisy (H, W) uint8 segmentation of ``clean_labels`` at the quality of ``preset``.

    ``truth``: a ``seg_errors.ViewTruth`` of the view; when given, the preset's structured errors are
    applied first (``truth.structured_errors``) from a generator seeded by one draw of ``rng``
    (taken only then: without ``truth`` the output is what it always was)."""
    clean = _check_labels(clean_labels, "clean_labels")
    p = get_preset(preset)
    if not p.noise:
        return clean.copy()
    base = clean
    if truth is not None:
        # ``ViewTruth.structured_errors`` (seg_errors builds on this module: no import back).
        base = truth.structured_errors(clean, p, np.random.default_rng(int(rng.integers(2**63))))
    openings = _opening_layer(clean, p, rng)
    labels = base.copy()
    labels[(base == SemanticClass.WINDOW) | (base == SemanticClass.DOOR)] = SemanticClass.WALL
    for src, dst, area, cell in p.confusions:
        region = _region(rng, labels.shape, area, cell)
        labels[region & (labels == src)] = dst
    _paint_blobs(labels, p, rng)
    # Openings are found on the facade the network sees: dropped where a confusion or blob took the wall.
    openings[labels != SemanticClass.WALL] = 0
    dy, dx = _displacement(labels.shape, p.boundary_px, p.boundary_cell_px, rng)
    labels = _warp(labels, dy, dx)
    openings = _warp(openings, p.opening_warp * dy, p.opening_warp * dx)
    _dilate_classes(labels, p.dilate_px, rng)
    labels = _patch_blur(labels, p.patch_px, p.patch_detail)
    # Openings are sharp "things" (the decoder's high-resolution path): pasted over the blurred result.
    found = openings > 0
    labels[found] = openings[found]
    return labels


def miou(pred: np.ndarray, gt: np.ndarray, min_pixels: int = MIN_PRESENT_PIXELS) -> float:
    """Mean IoU in % of ``pred`` against ``gt`` over the classes of ``MIOU_CLASSES`` present in ``gt``
    (at least ``min_pixels`` pixels). NaN when ``gt`` has none of them."""
    pred = _check_labels(pred, "pred")
    gt = _check_labels(gt, "gt")
    if pred.shape != gt.shape:
        raise ShapeError(f"pred {pred.shape} and gt {gt.shape} differ in shape")
    conf = confusion(pred, gt, NUM_CLASSES)  # [gt, pred]
    return mean_iou(conf, classes=MIOU_CLASSES, min_pixels=min_pixels, percent_of_mean=True)


def clean_depth_input(clean_depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(float64 depth, bool mask of valid pixels) of a rendered z-depth (ShapeError unless (H, W))."""
    d = np.asarray(clean_depth, dtype=np.float64)
    if d.ndim != 2 or d.size == 0:
        raise ShapeError(f"clean_depth must be a non-empty (H, W) array, got shape {d.shape}")
    return d, np.isfinite(d) & (d > 0)


def simulate_depth(clean_depth: np.ndarray, labels_clean: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(H, W) float32 relative depth from the rendered z-depth (module docstring); NaN where not finite."""
    d, valid = clean_depth_input(clean_depth)
    labels = _check_labels(labels_clean, "labels_clean")
    if labels.shape != d.shape:
        raise ShapeError(f"labels_clean {labels.shape} and clean_depth {d.shape} differ in shape")
    out = np.full(d.shape, np.nan, dtype=np.float32)
    if not valid.any():
        return out
    h, w = d.shape
    med = float(np.median(d[valid]))
    dmin = float(d[valid].min())

    a = math.exp(rng.uniform(math.log(DEPTH_SCALE_RANGE[0]), math.log(DEPTH_SCALE_RANGE[1])))
    b = float(rng.uniform(*DEPTH_SHIFT_RANGE)) * a * med
    b = max(b, DEPTH_MIN_SHARE * a * med - a * dmin)  # keep a * dmin + b >= 5 % of a * median
    field = smooth_field(rng, h, w, DEPTH_DISTORTION_CELL * max(h, w))
    field /= max(float(np.abs(field).max()), 1e-12)
    sigma = float(rng.uniform(*DEPTH_NOISE_RANGE))
    noise = rng.standard_normal(d.shape, dtype=np.float32)

    # Flying pixels: on class boundaries, depth is the mean of the valid 3x3 neighbourhood.
    blurred = d.copy()
    edge = (ndimage.maximum_filter(labels, size=3) != ndimage.minimum_filter(labels, size=3)) & valid
    ei, ej = np.nonzero(edge)
    if len(ei):
        dz = np.pad(np.where(valid, d, 0.0), 1, mode="edge")
        ok = np.pad(valid, 1, mode="edge")
        num = np.zeros(len(ei))
        den = np.zeros(len(ei))
        for di in (0, 1, 2):
            for dj in (0, 1, 2):
                num += dz[ei + di, ej + dj]
                den += ok[ei + di, ej + dj]
        blurred[ei, ej] = num / np.maximum(den, 1.0)

    rel = (a * blurred + b) * (1.0 + DEPTH_DISTORTION * field) * np.clip(1.0 + sigma * noise, 0.5, 1.5)
    out[valid] = rel[valid].astype(np.float32)
    return out

"""Query-side edge maps: the benchmark's simulated wireframe extractor, and image gradients for real photos.

Why: LoD-Loc's query side is a wireframe probability map predicted by a network trained on the city. The
benchmark has no such network, so ``simulate_edge_map`` makes that map from the true view, with the error
types such a network shows, at a quality preset (``EDGE_PRESETS``: ``clean``, ``trained``, ``noisy``):

1. the model's feature edges (``edges.extract_edges``: outlines, ridges, eaves, wall corners) visible at
   the true pose are drawn 1 px wide (dense samples along each edge, visibility by the rendered depth:
   ``edge_visibility``);
2. missed edges: every edge is cut into pieces of ``piece_px`` pixels, each piece is dropped with
   probability ``miss``; the kept ones get a confidence uniform in [``min_confidence``, 1];
3. position error: a smooth random displacement field of amplitude ``jitter_px`` moves the lines;
4. occluders (the query's tree / car pixels, ``occluder_mask``): model edges under them vanish and their
   outlines appear as spurious edges of strength ``occluder_edges``;
5. spurious edges: a Poisson(``lines``) number of long straight lines (road markings, shadows, kerbs) and
   Poisson(``clutter_blobs``) patches of short random strokes (texture: vegetation, roof tiles, cars);
6. blur: Gaussian of ``blur_px``, scaled so that a full-confidence 1 px line keeps a peak of 1;
7. background noise: half-normal of scale ``noise`` added to every pixel; clipped to [0, 1].

``image_edge_map`` is the real-image fallback: normalised Sobel gradient magnitude (no learning).
Every random draw comes from the ``numpy.random.Generator`` passed in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from semcityloc.baselines.edges import ModelEdges, extract_edges
from semcityloc.citymodel.model import CityModel
from semcityloc.errors import ShapeError, unknown_choice
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.render.engine import Renderer
from semcityloc.render.raster_numba import NumbaEngine
from semcityloc.render.scene import RenderScene, build_scene

# LoD-Loc's visibility tolerance: a point is visible when it is at most this much behind the rendered
# surface (z-depth, metres).
VISIBILITY_TOL_M = 0.3
NEAR_CLIP_M = 0.5
SAMPLES_PER_PX = 2.0  # dense sampling of the drawn edges
MAX_SAMPLES_PER_EDGE = 8192


@dataclass(frozen=True)
class EdgePreset:
    """Error parameters of one simulated wireframe-extractor quality (module docstring, steps 2-7)."""

    name: str
    miss: float = 0.0
    piece_px: float = 30.0
    min_confidence: float = 1.0
    jitter_px: float = 0.0
    jitter_cell_px: float = 24.0
    occluder_edges: float = 0.0
    lines: float = 0.0
    clutter_blobs: float = 0.0
    clutter_strokes_per_kpx: float = 6.0  # strokes per 1000 px of blob area
    blur_px: float = 1.0
    noise: float = 0.0


EDGE_PRESETS: dict[str, EdgePreset] = {
    # The projected wireframe itself, lightly blurred: the upper bound of any extractor.
    "clean": EdgePreset("clean", blur_px=1.0),
    # A network trained on the city (LoD-Loc's UNet): most edges found, about a pixel off, some clutter.
    "trained": EdgePreset(
        "trained",
        miss=0.15,
        piece_px=30.0,
        min_confidence=0.5,
        jitter_px=1.0,
        occluder_edges=0.5,
        lines=4.0,
        clutter_blobs=2.0,
        blur_px=1.5,
        noise=0.02,
    ),
    # A weak or out-of-domain extractor: many edges lost, lines off by a few pixels, lots of clutter.
    "noisy": EdgePreset(
        "noisy",
        miss=0.4,
        piece_px=20.0,
        min_confidence=0.3,
        jitter_px=2.5,
        occluder_edges=1.0,
        lines=15.0,
        clutter_blobs=6.0,
        blur_px=2.0,
        noise=0.05,
    ),
}


def edge_preset(quality: str | EdgePreset) -> EdgePreset:
    """The ``EdgePreset`` of a quality name (``EDGE_PRESETS``) or the preset itself; an unknown name is a
    ``ParameterError`` naming the known ones, so ``--edge-quality`` and library callers fail alike.
    """
    if isinstance(quality, EdgePreset):
        return quality
    try:
        return EDGE_PRESETS[quality]
    except (KeyError, TypeError) as exc:
        raise unknown_choice("edge-map quality", quality, EDGE_PRESETS) from exc


# ------------------------------------------------------------------------------------------ geometry
def max_depth_3x3(depth: np.ndarray) -> np.ndarray:
    """Largest z-depth in each pixel's 3x3 neighbourhood (+inf stays +inf): a visibility test against it
    forgives the one-pixel ambiguity at depth edges, where an edge point sits on the boundary."""
    return ndimage.maximum_filter(np.asarray(depth, dtype=np.float64), size=3, mode="nearest")


def edge_visibility(
    points_cam: np.ndarray, uv: np.ndarray, depth_max: np.ndarray, tol_m: float = VISIBILITY_TOL_M
) -> np.ndarray:
    """(P,) bool: in front, inside the image and at most ``tol_m`` behind ``depth_max`` at its pixel.

    ``points_cam`` (P, 3) camera-frame points, ``uv`` (P, 2) their image coordinates, ``depth_max``
    (H, W) from ``max_depth_3x3`` of a z-depth render at the same camera and pose.
    """
    h, w = depth_max.shape
    col = np.floor(uv[:, 0]).astype(np.int64)
    row = np.floor(uv[:, 1]).astype(np.int64)
    ok = (points_cam[:, 2] > NEAR_CLIP_M) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
    vis = np.zeros(len(uv), dtype=bool)
    idx = np.flatnonzero(ok)
    vis[idx] = points_cam[idx, 2] <= depth_max[row[idx], col[idx]] + tol_m
    return vis


def render_depth(scene: RenderScene, camera: Camera, pose_local: Pose) -> np.ndarray:
    """(H, W) float64 z-depth of one view (+inf where nothing is hit)."""
    out = NumbaEngine(scene).render(camera, pose_local.R[None], pose_local.t[None], depth=True)
    return out.depth[0].astype(np.float64)


def dense_edge_samples(
    edges: ModelEdges, camera: Camera, pose_local: Pose
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Samples every 1/``SAMPLES_PER_PX`` pixel along every edge in front of the camera.

    Returns camera-frame points (M, 3), image coordinates (M, 2), edge index (M,) and arc length in
    pixels from the edge's first end (M,). Edges are clipped to ``z >= NEAR_CLIP_M``.
    """
    seg = edges.segments
    cam = np.einsum("ij,esj->esi", pose_local.R, seg) + pose_local.t  # (E, 2, 3)
    z0, z1 = cam[:, 0, 2], cam[:, 1, 2]
    front = (z0 > NEAR_CLIP_M) | (z1 > NEAR_CLIP_M)
    cam, index = cam[front], np.flatnonzero(front)
    z0, z1 = cam[:, 0, 2], cam[:, 1, 2]
    # Clip to the near plane: parameter range [t0, t1] of the part in front.
    with np.errstate(divide="ignore", invalid="ignore"):
        tc = (NEAR_CLIP_M - z0) / (z1 - z0)
    t0 = np.where(z0 > NEAR_CLIP_M, 0.0, tc)
    t1 = np.where(z1 > NEAR_CLIP_M, 1.0, tc)
    a = cam[:, 0] + (cam[:, 1] - cam[:, 0]) * t0[:, None]
    b = cam[:, 0] + (cam[:, 1] - cam[:, 0]) * t1[:, None]
    ua, _ = camera.project(a)
    ub, _ = camera.project(b)
    length_px = np.linalg.norm(ub - ua, axis=1)
    # Cull edges entirely on one side outside the image.
    lo, hi = np.minimum(ua, ub), np.maximum(ua, ub)
    onscreen = (hi[:, 0] >= 0) & (lo[:, 0] <= camera.width) & (hi[:, 1] >= 0) & (lo[:, 1] <= camera.height)
    n = np.clip(np.ceil(length_px * SAMPLES_PER_PX), 2, MAX_SAMPLES_PER_EDGE).astype(np.int64)
    n[~onscreen] = 0
    e = np.repeat(np.arange(len(cam)), n)
    if len(e) == 0:
        return np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0, dtype=np.int64), np.zeros(0)
    k = np.arange(len(e)) - np.repeat(np.cumsum(n) - n, n)
    s = k / (n[e] - 1.0)
    pts = a[e] + (b[e] - a[e]) * s[:, None]
    uv, _ = camera.project(pts)
    return pts, uv, index[e], s * length_px[e]


# ------------------------------------------------------------------------------------------ drawing
def _splat_max(img: np.ndarray, uv: np.ndarray, values: np.ndarray) -> None:
    """img[pixel of uv] = max(img, value) for every sample inside the image (in place)."""
    h, w = img.shape
    col = np.floor(uv[:, 0]).astype(np.int64)
    row = np.floor(uv[:, 1]).astype(np.int64)
    ok = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    np.maximum.at(img, (row[ok], col[ok]), values[ok])


def _line_samples(p0: np.ndarray, p1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Dense samples of 2D segments p0 -> p1 (K, 2): ((M, 2) points, (M,) segment index)."""
    length = np.linalg.norm(p1 - p0, axis=1)
    n = np.maximum(2, np.ceil(length * SAMPLES_PER_PX)).astype(np.int64)
    seg = np.repeat(np.arange(len(p0)), n)
    k = np.arange(len(seg)) - np.repeat(np.cumsum(n) - n, n)
    s = (k / (n[seg] - 1.0))[:, None]
    return p0[seg] + (p1[seg] - p0[seg]) * s, seg


def _smooth_field(shape: tuple[int, int], cell_px: float, rng: np.random.Generator) -> np.ndarray:
    """Smooth random field of unit standard deviation (Gaussian-filtered white noise)."""
    f = ndimage.gaussian_filter(rng.standard_normal(shape), cell_px / 2.0, mode="wrap")
    sd = float(f.std())
    return f / sd if sd > 0 else f


def line_peak(blur_px: float) -> float:
    """Peak of a 1 px wide line of value 1 after ``gaussian_filter(sigma=blur_px)`` (normalisation)."""
    if blur_px <= 0:
        return 1.0
    delta = np.zeros(64)
    delta[32] = 1.0
    return float(ndimage.gaussian_filter1d(delta, blur_px, mode="constant").max())


def blur_normalised(img: np.ndarray, blur_px: float) -> np.ndarray:
    """Gaussian blur scaled so a value-1 line of 1 px keeps peak 1, clipped to [0, 1]."""
    if blur_px <= 0:
        return np.clip(img, 0.0, 1.0)
    out = ndimage.gaussian_filter(img, blur_px, mode="constant") / line_peak(blur_px)
    return np.clip(out, 0.0, 1.0)


# ------------------------------------------------------------------------------------------ simulator
class EdgeMapSimulator:
    """Simulated wireframe-extractor output for views of one city model (module docstring).

    Build once per model (extracting the feature edges and the render scene costs more than a view).
    """

    def __init__(self, model: CityModel, scene: RenderScene | None = None, edges: ModelEdges | None = None):
        if not isinstance(model, CityModel):
            raise TypeError(f"EdgeMapSimulator needs a CityModel, got {type(model).__name__}")
        self.model = model
        self.scene = scene if scene is not None else build_scene(model)
        self.edges = edges if edges is not None else extract_edges(model)

    def visible_edges(self, camera: Camera, pose_local: Pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Dense samples of the edges visible at ``pose_local``: (uv (M, 2), edge index (M,), arc px (M,))."""
        pts, uv, edge, arc = dense_edge_samples(self.edges, camera, pose_local)
        depth_max = max_depth_3x3(render_depth(self.scene, camera, pose_local))
        vis = edge_visibility(pts, uv, depth_max)
        return uv[vis], edge[vis], arc[vis]

    def simulate(
        self,
        camera: Camera,
        true_pose_local: Pose,
        quality: str | EdgePreset = "trained",
        rng: np.random.Generator | None = None,
        occluder_mask: np.ndarray | None = None,
    ) -> np.ndarray:
        """(H, W) float32 edge probability in [0, 1] at the camera's resolution (module docstring)."""
        preset = edge_preset(quality)
        if not isinstance(camera, Camera):
            raise TypeError(f"camera must be a semcityloc Camera, got {type(camera).__name__}")
        if not isinstance(true_pose_local, Pose) or true_pose_local.batch_shape:
            raise TypeError("true_pose_local must be a single Pose (cam_from_world, local frame)")
        h, w = camera.height, camera.width
        occ = None
        if occluder_mask is not None:
            occ = np.asarray(occluder_mask)
            if occ.shape != (h, w):
                raise ShapeError(f"occluder_mask must have shape {(h, w)} (the camera's), got {occ.shape}")
            occ = occ.astype(bool)
        rng = rng if rng is not None else np.random.default_rng(0)

        uv, edge, arc = self.visible_edges(camera, true_pose_local)
        # 2. missed pieces and per-piece confidence.
        offset = rng.random(len(self.edges))
        piece_of = np.floor(arc / max(preset.piece_px, 1e-6) + offset[edge]).astype(np.int64)
        pieces, piece = np.unique(np.stack([edge, piece_of], 1), axis=0, return_inverse=True)
        piece = piece.reshape(-1)
        kept = rng.random(len(pieces)) >= preset.miss
        confidence = rng.uniform(preset.min_confidence, 1.0, len(pieces))
        keep = kept[piece]
        uv, value = uv[keep], confidence[piece[keep]]
        # 3. smooth displacement.
        if preset.jitter_px > 0 and len(uv):
            fx = _smooth_field((h, w), preset.jitter_cell_px, rng)
            fy = _smooth_field((h, w), preset.jitter_cell_px, rng)
            col = np.clip(np.floor(uv[:, 0]).astype(np.int64), 0, w - 1)
            row = np.clip(np.floor(uv[:, 1]).astype(np.int64), 0, h - 1)
            uv = uv + preset.jitter_px * np.stack([fx[row, col], fy[row, col]], 1)
        img = np.zeros((h, w))
        _splat_max(img, uv, value)
        # 4. occluders hide model edges and bring their own outlines.
        if occ is not None and occ.any():
            img[ndimage.binary_dilation(occ)] = 0.0
            if preset.occluder_edges > 0:
                outline = occ & ~ndimage.binary_erosion(occ, border_value=1)
                strength = preset.occluder_edges * rng.uniform(0.5, 1.0, int(outline.sum()))
                img[outline] = np.maximum(img[outline], strength)
        # 5. spurious lines and texture clutter.
        self._spurious(img, preset, rng)
        # 6-7. blur and background noise.
        img = blur_normalised(img, preset.blur_px)
        if preset.noise > 0:
            img = img + preset.noise * np.abs(rng.standard_normal(img.shape))
        return np.clip(img, 0.0, 1.0).astype(np.float32)

    @staticmethod
    def _spurious(img: np.ndarray, preset: EdgePreset, rng: np.random.Generator) -> None:
        h, w = img.shape
        diag = float(np.hypot(h, w))
        n_lines = int(rng.poisson(preset.lines)) if preset.lines > 0 else 0
        if n_lines:
            centre = rng.uniform([0, 0], [w, h], (n_lines, 2))
            angle = rng.uniform(0, np.pi, n_lines)
            half = 0.5 * rng.uniform(0.05, 0.35, n_lines) * diag
            d = np.stack([np.cos(angle), np.sin(angle)], 1) * half[:, None]
            pts, seg = _line_samples(centre - d, centre + d)
            _splat_max(img, pts, rng.uniform(0.3, 0.9, n_lines)[seg])
        n_blobs = int(rng.poisson(preset.clutter_blobs)) if preset.clutter_blobs > 0 else 0
        for _ in range(n_blobs):
            centre = rng.uniform([0, 0], [w, h])
            radius = rng.uniform(0.03, 0.1) * min(h, w)
            n = max(1, int(preset.clutter_strokes_per_kpx * np.pi * radius**2 / 1000.0))
            r = radius * np.sqrt(rng.random(n))
            phi = rng.uniform(0, 2 * np.pi, n)
            mid = centre + np.stack([r * np.cos(phi), r * np.sin(phi)], 1)
            angle = rng.uniform(0, np.pi, n)
            half = 0.5 * rng.uniform(3.0, 12.0, n)
            d = np.stack([np.cos(angle), np.sin(angle)], 1) * half[:, None]
            pts, seg = _line_samples(mid - d, mid + d)
            _splat_max(img, pts, rng.uniform(0.2, 0.8, n)[seg])


def simulate_edge_map(
    source: CityModel | Renderer | EdgeMapSimulator,
    camera: Camera,
    true_pose_local: Pose,
    quality: str | EdgePreset = "trained",
    rng: np.random.Generator | None = None,
    occluder_mask: np.ndarray | None = None,
) -> np.ndarray:
    """The benchmark's simulated wireframe map of the view ``true_pose_local`` (module docstring).

    ``source``: the city model, a ``Renderer`` of it (its scene is reused) or an ``EdgeMapSimulator``
    (reuses the extracted edges too: use it for many views). Returns (H, W) float32 in [0, 1].
    """
    if isinstance(source, EdgeMapSimulator):
        sim = source
    elif isinstance(source, Renderer):
        sim = EdgeMapSimulator(source.model, source.scene)
    elif isinstance(source, CityModel):
        sim = EdgeMapSimulator(source)
    else:
        raise TypeError(
            f"source must be a CityModel, Renderer or EdgeMapSimulator, got {type(source).__name__}"
        )
    return sim.simulate(camera, true_pose_local, quality, rng, occluder_mask)


# ------------------------------------------------------------------------------------------ real images
def image_edge_map(image: np.ndarray, blur_px: float = 1.0, percentile: float = 99.0) -> np.ndarray:
    """Edge probability from image gradients: Sobel magnitude of the (grey) image, divided by its
    ``percentile``-th percentile and clipped to [0, 1]. (H, W) or (H, W, C) input; float32 output."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (1, 3, 4):
        img = img[..., :3].astype(np.float64).mean(axis=2) if img.shape[2] >= 3 else img[..., 0]
    if img.ndim != 2 or min(img.shape) < 3:
        raise ShapeError(f"image must be (H, W) or (H, W, C) with H, W >= 3, got shape {np.shape(image)}")
    if not np.issubdtype(img.dtype, np.number):
        raise ShapeError(f"image must be numeric, got dtype {img.dtype}")
    g = np.where(np.isfinite(img), img, 0.0).astype(np.float64)
    if blur_px > 0:
        g = ndimage.gaussian_filter(g, blur_px)
    mag = np.hypot(ndimage.sobel(g, axis=1), ndimage.sobel(g, axis=0))
    scale = float(np.percentile(mag, percentile))
    if scale <= 0:
        return np.zeros(mag.shape, dtype=np.float32)
    return np.clip(mag / scale, 0.0, 1.0).astype(np.float32)

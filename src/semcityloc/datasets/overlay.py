"""The model's visible edges seen from a pose, drawn over a real image, and how well they meet its edges.

Why: the first thing to check with a real data set is whether the model lands on the buildings at the
ground-truth pose (every frame convention in the chain right) and how far off the prior is. A person
looks at the PNG (``gt_vs_prior_figure`` + ``save_png``); a test reads the numbers (``edge_score``).

Visible model edges come from one render's face ids and depth (``render.overlay.visible_edges``: class
changes, creases and silhouettes of building faces, so occlusion is exact and the triangulation's
diagonals never show). Image edges (``gradient_magnitude``): Sobel gradient magnitude of the grey image
after a Gaussian blur of ``GRADIENT_SIGMA_PX``. ``edge_score`` is the mean of that magnitude under the
model's edges divided by its mean over the whole image: about 1 for edges unrelated to the image, higher
when they lie on its edges. It is the stand-in for the wireframe baseline's score
(``semcityloc.baselines.wireframe``) where that module is not installed.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw
from scipy import ndimage

from semcityloc.citymodel.model import CityModel
from semcityloc.errors import InputFileError, ShapeError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.io.images import load_image, save_rgb
from semcityloc.render import Renderer
from semcityloc.render.overlay import draw_edges, visible_edges

GRADIENT_SIGMA_PX = 1.0
GT_COLOR = (40, 230, 60)
PRIOR_COLOR = (255, 60, 40)
HEADER_PX = 22


def read_image(path: str | os.PathLike) -> np.ndarray:
    """(H, W, 3) uint8 RGB of an image file (``io.images.load_image``)."""
    if not Path(path).is_file():
        raise InputFileError(f"{path}: no such image")
    return load_image(path)


def _renderer(model: CityModel, renderer=None):
    if renderer is not None:
        return renderer

    return Renderer(model, engine="numba")


def gradient_magnitude(image: np.ndarray) -> np.ndarray:
    """(H, W) float64 Sobel gradient magnitude of the (blurred) grey image."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = img[..., :3].astype(np.float64) @ np.array([0.299, 0.587, 0.114])
    if img.ndim != 2:
        raise ShapeError(f"image must be (H, W) or (H, W, 3), got shape {np.shape(image)}")
    grey = ndimage.gaussian_filter(img.astype(np.float64), GRADIENT_SIGMA_PX)
    return np.hypot(ndimage.sobel(grey, axis=1), ndimage.sobel(grey, axis=0))


def edge_score(gradient: np.ndarray, edges: np.ndarray) -> float:
    """Mean gradient under ``edges`` over the image's mean gradient (module docstring); NaN without edges."""
    gradient, edges = np.asarray(gradient), np.asarray(edges, dtype=bool)
    if gradient.shape != edges.shape:
        raise ShapeError(f"gradient {gradient.shape} and edge mask {edges.shape} differ in shape")
    mean = float(gradient.mean())
    if not edges.any() or mean <= 0:
        return float("nan")
    return float(gradient[edges].mean() / mean)


def _panel(image: np.ndarray, title: str) -> np.ndarray:
    h, w = image.shape[:2]
    canvas = Image.new("RGB", (w, h + HEADER_PX), (255, 255, 255))
    canvas.paste(Image.fromarray(image), (0, HEADER_PX))
    ImageDraw.Draw(canvas).text((6, 5), title, fill=(0, 0, 0))
    return np.asarray(canvas)


def edges_figure(
    image: np.ndarray,
    model: CityModel,
    camera: Camera,
    panels: list[tuple[Pose, tuple[int, int, int], str]],
    renderer=None,
    renderers: list | None = None,
    cameras: list[Camera | None] | None = None,
) -> np.ndarray:
    """(H + header, n W + gaps, 3) uint8: one panel per ``(pose_world, colour, title)``, the image with the
    model's visible edges at that pose drawn in that colour, side by side.

    Poses are in the model's world frame (``model.origin`` + local). ``camera`` must have the image's size.
    ``renderers``: one per panel (None in it: ``renderer``'s), for a panel drawn on another map of the
    model (an estimate's, on the map it was found on: ``benchmark.found_map``). ``cameras``: one per panel
    (None in it: ``camera``), each of the image's size, for a pose that holds with another camera (one the
    focal check's correction re-found with the focal lengths scaled: ``focal_check.found_camera``).
    """
    cameras = cameras or [None] * len(panels)
    if renderers is not None and len(renderers) != len(panels):
        raise ShapeError(f"{len(renderers)} renderers for {len(panels)} panels: give one per panel")
    if len(cameras) != len(panels):
        raise ShapeError(f"{len(cameras)} cameras for {len(panels)} panels: give one per panel")
    cameras = [camera if c is None else c for c in cameras]
    for c in cameras:
        if image.shape[:2] != (c.height, c.width):
            raise ShapeError(
                f"image {image.shape[1]}x{image.shape[0]} is not the camera's {c.width}x{c.height}"
            )
    base = _renderer(model, renderer)
    out = []
    for (pose, color, title), own, cam in zip(
        panels, renderers or [None] * len(panels), cameras, strict=True
    ):
        r = own or base
        view = r.render(cam, model.pose_to_local(pose), depth=True, face_ids=True)
        edges = visible_edges(view.face_ids[0], view.depth[0], r.scene)
        out.append(_panel(draw_edges(image, edges, color), title))
    gap = np.full((out[0].shape[0], 6, 3), 255, dtype=np.uint8)
    joined = [out[0]]
    for panel in out[1:]:
        joined += [gap, panel]
    return np.concatenate(joined, axis=1)


def gt_vs_prior_figure(
    image: np.ndarray,
    model: CityModel,
    camera: Camera,
    gt_world: Pose,
    prior_world: Pose,
    renderer=None,
    titles: tuple[str, str] = ("model edges at the ground-truth pose", "model edges at the prior pose"),
) -> np.ndarray:
    """(H + header, 2 W, 3) uint8: the image with the model's visible edges at GT (left) and prior (right)
    (``edges_figure``)."""
    panels = [(gt_world, GT_COLOR, titles[0]), (prior_world, PRIOR_COLOR, titles[1])]
    return edges_figure(image, model, camera, panels, renderer)


def save_png(array: np.ndarray, path: str | os.PathLike) -> Path:
    """An RGB uint8 figure as an optimised PNG (``io.images.save_rgb``); ``InputFileError`` when it
    cannot be written."""
    target = Path(path)
    try:
        save_rgb(array, target, optimize=True)
    except OSError as exc:
        raise InputFileError(f"{target}: cannot write PNG: {exc.strerror or exc}") from exc
    return target

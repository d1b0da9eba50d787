"""Visible model edges in image space, and overlays of them (or of label masks) on photos.

An edge pixel is where the rendered surface changes in a way a photo shows as a line: a different class
(roof/wall/ground), or, where a building face takes part, a crease (face normals more than ``crease_deg``
apart) or a depth jump (silhouette). Creases between terrain triangles are not edges.
Computed from a render's face ids and depth, so occlusion is exact.
"""

from __future__ import annotations

import numpy as np

from semcityloc.classes import PALETTE
from semcityloc.io.images import resize_nearest
from semcityloc.render.scene import RenderScene


def class_boundaries(labels: np.ndarray, width_px: int = 1) -> np.ndarray:
    """(H, W) bool: pixels within ``width_px`` (4-neighbour steps) of a pixel of another class."""
    edge = np.zeros(labels.shape, dtype=bool)
    if width_px <= 0:
        return edge
    dx = labels[:, 1:] != labels[:, :-1]
    dy = labels[1:, :] != labels[:-1, :]
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    edge[1:, :] |= dy
    edge[:-1, :] |= dy
    for _ in range(width_px - 1):
        grown = edge.copy()
        grown[1:] |= edge[:-1]
        grown[:-1] |= edge[1:]
        grown[:, 1:] |= edge[:, :-1]
        grown[:, :-1] |= edge[:, 1:]
        edge = grown
    return edge


def face_normals(scene: RenderScene) -> np.ndarray:
    """(T, 3) unit normals of the scene's triangles."""
    c = scene.corners.astype(np.float64)
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def visible_edges(
    face_ids: np.ndarray,
    depth: np.ndarray,
    scene: RenderScene,
    crease_deg: float = 20.0,
    depth_jump: float = 0.05,
) -> np.ndarray:
    """(H, W) bool: pixels on a visible model edge, from one view's face ids and z-depth."""
    ids = np.asarray(face_ids)
    normals = np.vstack([face_normals(scene), np.zeros((1, 3))])  # index -1 -> zero normal
    cls = np.append(scene.classes, 0)
    building = np.append(scene.source_triangle >= 0, False)[ids]  # terrain creases are not model edges
    n = normals[ids]
    c = cls[ids]
    d = np.where(np.isfinite(depth), depth, 0.0)
    cos_limit = np.cos(np.radians(crease_deg))
    edge = np.zeros(ids.shape, dtype=bool)
    for axis in (0, 1):
        a = [slice(None)] * 2
        b = [slice(None)] * 2
        a[axis], b[axis] = slice(1, None), slice(None, -1)
        a, b = tuple(a), tuple(b)
        differs = ids[a] != ids[b]
        crease = np.sum(n[a] * n[b], axis=-1) < cos_limit
        jump = np.abs(d[a] - d[b]) > depth_jump * np.maximum(np.minimum(d[a], d[b]), 1e-6)
        either_building = building[a] | building[b]
        e = differs & ((c[a] != c[b]) | (either_building & (crease | jump)))
        edge[a] |= e
        edge[b] |= e
    return edge


def draw_edges(image: np.ndarray, edges: np.ndarray, color=(255, 0, 0)) -> np.ndarray:
    """Copy of an RGB (or grey) image with edge pixels painted; edges resampled to the image size."""
    img = np.asarray(image)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    out = img.astype(np.uint8).copy()
    e = resize_nearest(edges, out.shape[1], out.shape[0])
    out[e] = color
    return out


def label_colors(labels: np.ndarray, unknown=(255, 255, 255)) -> np.ndarray:
    """(H, W, 3) uint8 palette colour of each class id; IGNORE (255) and any id without a colour get
    ``unknown`` (white, as in label PNGs)."""
    lab = np.asarray(labels)
    out = np.empty(lab.shape + (3,), dtype=np.uint8)
    out[:] = unknown
    known = (lab >= 0) & (lab < len(PALETTE))
    out[known] = PALETTE[lab[known]]
    return out


def blend_labels(image: np.ndarray, labels: np.ndarray, alpha: float = 0.45) -> np.ndarray:
    """RGB image with the label palette blended on top (label 0 and 255 left as they are)."""
    img = np.asarray(image)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    lab = resize_nearest(labels, img.shape[1], img.shape[0])
    colour = np.zeros(img.shape, dtype=np.float64)
    known = (lab > 0) & (lab < len(PALETTE))
    colour[known] = PALETTE[lab[known]]
    out = img.astype(np.float64)
    out[known] = (1 - alpha) * out[known] + alpha * colour[known]
    return out.astype(np.uint8)

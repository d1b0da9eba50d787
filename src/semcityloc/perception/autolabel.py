"""Automatic semantic labels: the city model's classes projected into a photo at its known pose.

Why (the paper's annotation pipeline): with a georeferenced model and accurate poses, every photo gets a
label map for free, which is what a segmentation head is trained on. The labels are only as good as the
model says, so pixels where the model says nothing reliable become ``IGNORE`` (255) instead of a guess:

- **too far**: the hit surface is more than ``max_range_m`` from the camera (range, not z-depth);
- **grazing**: the angle between the viewing ray and the surface is below ``min_incidence_deg`` (a wall
  seen edge-on, far terrain at a flat angle): a small pose or model error flips such pixels;
- **beyond the model**: the renderer's terrain (it adds a ground TIN around the buildings) hit outside
  the buildings' bounding box grown by ``extent_margin_m`` -- the model knows nothing there; rays that hit
  nothing and point below the horizon likewise. Rays that hit nothing above the horizon are sky:
  BACKGROUND;
- **class boundaries**: every pixel with a 4-neighbour of another class (``boundary_px`` = 1: one pixel on
  each side of a boundary; 0 turns this off), since a boundary is where small errors land.

Occlusion is exact: labels come from the z-buffer renderer's face ids and depth (``semcityloc.render``).
The pose is in the model's WORLD/CRS frame (as pose files give it); it is shifted by ``model.origin``
inside, in float64.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semcityloc.citymodel.model import CityModel
from semcityloc.classes import IGNORE, PALETTE, SemanticClass
from semcityloc.errors import ParameterError, PoseError, RenderError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose, local_frame_problem
from semcityloc.render import Renderer, RenderOutput
from semcityloc.render.overlay import class_boundaries

DEFAULT_EXTENT_MARGIN_M = 25.0
IGNORE_REASONS = ("outside_model", "too_far", "grazing", "boundary")


@dataclass
class AutoLabelResult:
    """Labels (H, W) uint8 and the single-view render they came from (labels/depth/face_ids (1, H, W))."""

    labels: np.ndarray
    render: RenderOutput
    reasons: dict[str, int]  # pixels set to IGNORE per reason (a pixel counts for its first reason)


def _check(
    camera: Camera,
    pose_world: Pose,
    max_range_m: float,
    min_incidence_deg: float,
    boundary_px: int,
    extent_margin_m: float = DEFAULT_EXTENT_MARGIN_M,
):
    if not isinstance(camera, Camera):
        raise ParameterError(f"camera must be a semcityloc Camera, got {type(camera).__name__}")
    if not isinstance(pose_world, Pose):
        raise PoseError(f"pose must be a semcityloc Pose, got {type(pose_world).__name__}")
    if pose_world.batch_shape:
        raise PoseError(f"auto_label takes one pose, got a batch of shape {pose_world.batch_shape}")
    if not (np.isfinite(max_range_m) and max_range_m > 0):
        raise ParameterError(f"max_range_m must be a positive number of metres, got {max_range_m!r}")
    if not (np.isfinite(min_incidence_deg) and 0 <= min_incidence_deg < 90):
        raise ParameterError(f"min_incidence_deg must be in [0, 90), got {min_incidence_deg!r}")
    if not (isinstance(boundary_px, (int, np.integer)) and 0 <= boundary_px <= 50):
        raise ParameterError(f"boundary_px must be an integer in 0..50, got {boundary_px!r}")
    if not (np.isfinite(extent_margin_m) and extent_margin_m >= 0):  # -50, nan, inf were taken alike
        raise ParameterError(f"extent_margin_m must be a number of metres >= 0, got {extent_margin_m!r}")


def _unit_normals(corners: np.ndarray) -> np.ndarray:
    c = corners.astype(np.float64)
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def auto_label_render(
    model: CityModel,
    camera: Camera,
    pose_world: Pose,
    *,
    renderer: Renderer | None = None,
    max_range_m: float = 1500.0,
    min_incidence_deg: float = 10.0,
    extent_margin_m: float = DEFAULT_EXTENT_MARGIN_M,
    boundary_px: int = 1,
) -> AutoLabelResult:
    """``auto_label`` that also returns the render and how many pixels each rule ignored."""
    _check(camera, pose_world, max_range_m, min_incidence_deg, boundary_px, extent_margin_m)
    if renderer is None:
        renderer = Renderer(model, engine="auto")
    elif not np.array_equal(renderer.scene.origin, model.origin):
        raise RenderError("the renderer was built for another model (its origin differs from model.origin)")
    pose_local = model.pose_to_local(pose_world)
    if (problem := local_frame_problem(pose_local.center)) is not None and np.abs(model.origin).max() > 0:
        raise PoseError(
            "auto_label takes the pose in world (CRS) coordinates (model.pose_to_world(pose_local) for a "
            f"local one): this one, shifted to the local frame, is far from it ({problem.split(':')[0]})"
        )
    view = renderer.render(camera, pose_local, depth=True, face_ids=True)
    cls = view.labels[0]
    depth = view.depth[0].astype(np.float64)
    faces = view.face_ids[0]
    scene = renderer.scene

    rays_cam = camera.ray_directions()  # (H, W, 3), z = 1
    rays_world = pose_local.directions_to_world(rays_cam)
    ray_len = np.linalg.norm(rays_cam, axis=-1)
    hit = faces >= 0
    rng = np.where(hit, depth * ray_len, np.inf)

    out = cls.copy()
    reasons = dict.fromkeys(IGNORE_REASONS, 0)

    def ignore(mask: np.ndarray, reason: str) -> None:
        new = mask & (out != IGNORE)
        reasons[reason] += int(new.sum())
        out[new] = IGNORE

    # Nothing hit: sky above the horizon is background; below it the model has no surface there.
    out[~hit] = SemanticClass.BACKGROUND
    ignore(~hit & (rays_world[..., 2] <= 0), "outside_model")
    ignore(hit & (rng > max_range_m), "too_far")

    safe = np.where(hit, faces, 0)
    if min_incidence_deg > 0 and hit.any():
        normals = _unit_normals(scene.corners[safe[hit]])
        d = rays_world[hit] / ray_len[hit][:, None]
        sin_inc = np.abs(np.einsum("ij,ij->i", normals, d))
        grazing = np.zeros_like(hit)
        grazing[hit] = sin_inc < np.sin(np.radians(min_incidence_deg))
        ignore(grazing, "grazing")

    terrain = hit & (scene.source_triangle[safe] < 0)
    if terrain.any():
        lo, hi = _building_bbox_xy(scene)
        centre = pose_local.center
        pts = centre[None, :2] + (rays_world[terrain][:, :2] * depth[terrain][:, None])
        outside = np.any((pts < lo - extent_margin_m) | (pts > hi + extent_margin_m), axis=1)
        beyond = np.zeros_like(hit)
        beyond[terrain] = outside
        ignore(beyond, "outside_model")

    if boundary_px > 0:
        ignore(class_boundaries(cls, int(boundary_px)), "boundary")
    return AutoLabelResult(out, view, reasons)


def _building_bbox_xy(scene) -> tuple[np.ndarray, np.ndarray]:
    """xy min/max of the model's own (non-terrain) triangles in the local frame."""
    own = scene.source_triangle >= 0
    if not own.any():
        return np.full(2, np.inf), np.full(2, -np.inf)
    xy = scene.corners[own][:, :, :2].reshape(-1, 2).astype(np.float64)
    return xy.min(0), xy.max(0)


def auto_label(
    model: CityModel,
    camera: Camera,
    pose_world: Pose,
    *,
    renderer: Renderer | None = None,
    max_range_m: float = 1500.0,
    min_incidence_deg: float = 10.0,
    extent_margin_m: float = DEFAULT_EXTENT_MARGIN_M,
    boundary_px: int = 1,
) -> np.ndarray:
    """(H, W) uint8 class ids of ``model`` seen by ``camera`` at ``pose_world``, IGNORE (255) where the
    model says nothing reliable (module docstring). ``renderer``: a ``Renderer`` of this model to reuse."""
    return auto_label_render(
        model,
        camera,
        pose_world,
        renderer=renderer,
        max_range_m=max_range_m,
        min_incidence_deg=min_incidence_deg,
        extent_margin_m=extent_margin_m,
        boundary_px=boundary_px,
    ).labels


def label_overlay(image: np.ndarray, labels: np.ndarray, alpha: float = 0.45) -> np.ndarray:
    """RGB uint8 for a person: the photo with class colours blended in (palette), IGNORE pixels left as
    the photo under a white diagonal hatch, and class boundaries as thin white lines."""
    img = np.asarray(image)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    img = img[..., :3].astype(np.float64)
    lab = np.asarray(labels)
    if lab.shape != img.shape[:2]:
        raise ParameterError(f"labels {lab.shape} and image {img.shape[:2]} differ in size")
    out = img.copy()
    known = lab < len(PALETTE)
    out[known] = (1 - alpha) * img[known] + alpha * PALETTE[lab[known]].astype(np.float64)
    rows, cols = np.indices(lab.shape)
    hatch = (lab == IGNORE) & ((rows + cols) % 8 < 2)
    out[hatch] = 0.5 * out[hatch] + 0.5 * 255.0
    thin = np.zeros(lab.shape, dtype=bool)  # one side of each boundary only: 1-px lines
    thin[:, :-1] |= lab[:, 1:] != lab[:, :-1]
    thin[:-1, :] |= lab[1:, :] != lab[:-1, :]
    out[thin & known] = 255.0
    return np.clip(out, 0, 255).astype(np.uint8)

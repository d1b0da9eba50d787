"""A localization's inputs checked before any search, each fault a typed error naming what was given.

Why before: what is wrong shows up late and far from its cause otherwise. The search renders a wide view
sized by the camera's intrinsics (``coarse.rotation_lookup``), so intrinsics off by orders of magnitude
exhaust the memory instead of failing; a mask of another aspect than the camera is stretched to its shape
without a word; another numbering's class ids (a segmentation head's own) count as nothing, and the query
is refused for having no building pixels; complex depth loses its imaginary part.
``check_camera_and_prior`` is shared with the baselines, ``check_query_inputs`` adds this localizer's
arrays (the semantic mask and the optional depth map).
"""

from __future__ import annotations

import numpy as np

from semcityloc.classes import invalid_class_ids
from semcityloc.errors import CameraError, PoseError, ShapeError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose, local_frame_problem

# A query camera's field of view, per axis (``check_query_camera``): a 200x zoom sees about 1 deg, a
# rectified fisheye is cut to well under 150 deg.
MIN_FOV_DEG = 1.0
MAX_FOV_DEG = 150.0


def check_camera_and_prior(camera: Camera, prior_local: Pose) -> None:
    """Typed errors for the inputs every localizer shares (this one and the baselines); a prior in world
    (CRS) coordinates is refused as ``Renderer.render`` refuses such a pose (``pose.local_frame_problem``),
    where it searched an empty volume and reported a miss."""
    if not isinstance(camera, Camera):
        raise CameraError(f"camera must be a semcityloc Camera, got {type(camera).__name__}")
    check_query_camera(camera)
    if not isinstance(prior_local, Pose) or prior_local.batch_shape:
        raise PoseError("prior must be a single Pose (cam_from_world)")
    if (problem := local_frame_problem(prior_local.center)) is not None:
        raise PoseError(f"the prior must be in the model's local frame: {problem}")


def check_query_camera(camera: Camera) -> None:
    """A query camera's intrinsics must describe a photo: the principal point inside the image and a field
    of view between ``MIN_FOV_DEG`` and ``MAX_FOV_DEG`` on both axes. Why: the search renders a wide view
    covering every rotation it tries (``coarse.rotation_lookup``); intrinsics off by orders of magnitude
    (a focal length in mm given as pixels, a principal point in another image's pixels) would make that
    view millions of pixels wide and exhaust the memory instead of failing."""
    if not (0.0 <= camera.cx <= camera.width and 0.0 <= camera.cy <= camera.height):
        raise CameraError(
            f"principal point ({camera.cx:g}, {camera.cy:g}) lies outside the {camera.width}x{camera.height} "
            "image: are the intrinsics for this image size?"
        )
    for axis, fov in (("horizontal", camera.hfov_deg), ("vertical", camera.vfov_deg)):
        if not MIN_FOV_DEG <= fov <= MAX_FOV_DEG:
            raise CameraError(
                f"{axis} field of view {fov:.3g} deg (fx={camera.fx:g}, fy={camera.fy:g} px for a "
                f"{camera.width}x{camera.height} image) is outside [{MIN_FOV_DEG:g}, {MAX_FOV_DEG:g}] deg: "
                "focal lengths must be in pixels of this image"
            )


def check_query_inputs(camera: Camera, prior_local: Pose, semantic, depth) -> None:
    """``check_camera_and_prior``, then the query's arrays: ``semantic`` a non-empty (H, W) array of known
    integer class ids in the camera's aspect, ``depth`` (optional) a non-empty (H', W') array of real
    numbers in the mask's aspect (2 % either way)."""
    check_camera_and_prior(camera, prior_local)
    shape = np.shape(semantic)
    if len(shape) != 2 or 0 in shape:
        raise ShapeError(f"semantic mask must be a non-empty (H, W) array, got shape {shape}")
    labels = np.asarray(semantic)
    if not np.issubdtype(labels.dtype, np.integer):
        raise ShapeError(f"semantic mask must hold integer class ids, got dtype {labels.dtype}")
    problem = invalid_class_ids(labels)
    if problem is not None:
        raise ShapeError(f"semantic mask: {problem}")
    aspect_mask, aspect_cam = shape[1] / shape[0], camera.width / camera.height
    if abs(aspect_mask / aspect_cam - 1) > 0.02:
        raise ShapeError(
            f"semantic mask {shape[1]}x{shape[0]} does not have the camera's aspect "
            f"({camera.width}x{camera.height})"
        )
    if depth is not None:
        dshape = np.shape(depth)
        if len(dshape) != 2 or 0 in dshape:
            raise ShapeError(f"depth must be a non-empty (H, W) array, got shape {dshape}")
        dtype = np.asarray(depth).dtype
        if not (np.issubdtype(dtype, np.floating) or np.issubdtype(dtype, np.integer)):
            raise ShapeError(f"depth must hold real numbers, got dtype {dtype}")
        if abs((dshape[1] / dshape[0]) / aspect_mask - 1) > 0.02:
            raise ShapeError(
                f"depth map {dshape[1]}x{dshape[0]} does not have the semantic mask's aspect "
                f"({shape[1]}x{shape[0]})"
            )

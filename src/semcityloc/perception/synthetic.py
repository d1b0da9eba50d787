"""Synthetic training photos: rendered views of the generated city with procedural textures.

Why: a segmenter's training loop needs a set with known truth that runs anywhere (no ../shared, no
downloads). The generated district (``citymodel.generator``) is rendered from drone-like poses; each
pixel gets a colour from its class, its surface and the light, so that appearance -- not the label
itself -- carries the class, and the labels are this view's ``auto_label`` (IGNORE where unreliable):

- ground: asphalt grey with smooth large-scale (lots, streets) and fine (grain) value noise;
- walls: one pale facade colour per building, darker storey bands every 3 m and window-like dark cells;
- roofs: one roofing colour per building (terracotta, slate, brown, gravel grey) with tile stripes;
- windows / doors (LoD3): dark glass / wood; sky: a blue gradient;
- light: a random sun per view (Lambert on the face normal plus ambient), per-view exposure and tint,
  Gaussian sensor noise.

Everything is drawn from the ``numpy.random.Generator`` passed in: same seed, same images.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from semcityloc.citymodel.generator import footprints_to_model
from semcityloc.citymodel.generator_footprints import generate_footprints
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import IGNORE, SemanticClass
from semcityloc.errors import ParameterError
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.perception.autolabel import auto_label_render
from semcityloc.render import Renderer

ROOF_COLOURS = np.array([[0.62, 0.27, 0.20], [0.30, 0.31, 0.34], [0.45, 0.32, 0.22], [0.58, 0.57, 0.55]])
WALL_COLOURS = np.array([[0.86, 0.80, 0.68], [0.92, 0.90, 0.86], [0.80, 0.66, 0.48], [0.74, 0.76, 0.78]])
WINDOW_COLOUR = np.array([0.14, 0.18, 0.26])
DOOR_COLOUR = np.array([0.34, 0.21, 0.12])
SKY_TOP, SKY_HORIZON = np.array([0.45, 0.62, 0.90]), np.array([0.80, 0.86, 0.95])


@dataclass
class SyntheticView:
    """One synthetic training photo: its name, the textured RGB image, its labels (255 = ignore), the world
    pose and the camera it was rendered with.
    """

    name: str
    image: np.ndarray  # (H, W, 3) uint8
    labels: np.ndarray  # (H, W) uint8 class ids, 255 = ignore
    pose_world: Pose
    camera: Camera


def generated_model(seed: int = 0, blocks: tuple[int, int] = (2, 2), lod: int = 2) -> CityModel:
    """The generator's district as a ``CityModel`` (same footprints as ``generate_city`` writes)."""
    return footprints_to_model(generate_footprints(seed=seed, blocks=blocks), lod=lod)


def _hash_noise(ix: np.ndarray, iy: np.ndarray, seed: int) -> np.ndarray:
    """Deterministic pseudo-random values in [0, 1) for integer lattice points."""
    h = (ix.astype(np.int64) * 73856093) ^ (iy.astype(np.int64) * 19349663) ^ (int(seed) * 83492791)
    h = (h ^ (h >> 13)) * 1274126177
    h = h ^ (h >> 16)
    return (h & 0xFFFF).astype(np.float64) / 65536.0


def value_noise(x: np.ndarray, y: np.ndarray, cell: float, seed: int) -> np.ndarray:
    """Smooth noise in [0, 1) over world coordinates (bilinear between lattice values ``cell`` apart)."""
    gx, gy = x / cell, y / cell
    x0, y0 = np.floor(gx), np.floor(gy)
    fx, fy = gx - x0, gy - y0
    fx, fy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
    v00, v10 = _hash_noise(x0, y0, seed), _hash_noise(x0 + 1, y0, seed)
    v01, v11 = _hash_noise(x0, y0 + 1, seed), _hash_noise(x0 + 1, y0 + 1, seed)
    return (v00 * (1 - fx) + v10 * fx) * (1 - fy) + (v01 * (1 - fx) + v11 * fx) * fy


def sample_poses(
    model: CityModel, n: int, rng: np.random.Generator, altitude=(60.0, 150.0), pitch=(0.0, 40.0)
):
    """``n`` drone poses in the model's WORLD frame over its buildings: altitude above the lowest model
    point, pitch from nadir, any yaw, roll within +-3 degrees."""
    if n < 1:
        raise ParameterError(f"need at least one view, got {n}")
    lo, hi = model.bounds_local
    span = hi[:2] - lo[:2]
    xy = lo[:2] + span * 0.15 + rng.random((n, 2)) * span * 0.7
    z = lo[2] + rng.uniform(*altitude, size=n)
    centres = model.to_world(np.column_stack([xy, z]))
    return Pose.from_xyz_rpy(
        centres, rng.uniform(-3, 3, n), rng.uniform(*pitch, size=n), rng.uniform(-180, 180, n)
    )


def texture_view(
    renderer: Renderer, camera: Camera, pose_local: Pose, view, rng: np.random.Generator
) -> np.ndarray:
    """(H, W, 3) uint8 photo-like image of one rendered view (module docstring)."""
    cls = view.labels[0]
    depth = view.depth[0].astype(np.float64)
    faces = view.face_ids[0]
    scene = renderer.scene
    model = renderer.model
    hit = faces >= 0
    safe = np.where(hit, faces, 0)
    rays_cam = camera.ray_directions()
    rays_world = pose_local.directions_to_world(rays_cam)
    pts = pose_local.points_to_world(rays_cam * np.where(hit, depth, 0.0)[..., None])
    x, y, z = pts[..., 0], pts[..., 1], pts[..., 2]
    c = scene.corners[safe].astype(np.float64)
    normals = np.cross(c[..., 1, :] - c[..., 0, :], c[..., 2, :] - c[..., 0, :])
    normals /= np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
    normals *= np.where(
        np.sum(normals * rays_world, axis=-1, keepdims=True) > 0, -1.0, 1.0
    )  # face the camera
    source = scene.source_triangle[safe]
    building = np.where(source >= 0, model.building_index[np.maximum(source, 0)], -1)

    seed = int(rng.integers(0, 2**31 - 1))
    nb = len(model.building_ids) + 1
    roof_pick = ROOF_COLOURS[rng.integers(0, len(ROOF_COLOURS), nb)] * rng.uniform(0.85, 1.15, (nb, 1))
    wall_pick = WALL_COLOURS[rng.integers(0, len(WALL_COLOURS), nb)] * rng.uniform(0.85, 1.1, (nb, 1))
    stripe_axis = rng.integers(0, 2, nb)
    img = np.zeros(cls.shape + (3,))

    g = cls == SemanticClass.GROUND
    base = rng.uniform(0.38, 0.52)
    lots = value_noise(x[g], y[g], 18.0, seed) - 0.5
    grain = value_noise(x[g], y[g], 0.8, seed + 1) - 0.5
    tone = base + 0.16 * lots + 0.06 * grain
    img[g] = tone[:, None] * np.array([1.0, 1.0, 0.96]) + np.clip(lots, 0, None)[:, None] * np.array(
        [-0.05, 0.06, -0.05]
    )

    w = cls == SemanticClass.WALL
    b = building[w]
    zz, along = z[w], x[w] + y[w]
    band = (np.mod(zz, 3.0) < 0.35).astype(np.float64)
    cell = ((np.mod(zz, 3.0) > 0.9) & (np.mod(zz, 3.0) < 2.3) & (np.mod(along, 2.5) < 1.2)).astype(np.float64)
    img[w] = wall_pick[b] * (1.0 - 0.25 * band - 0.45 * cell)[:, None]

    r = cls == SemanticClass.ROOF
    b = building[r]
    coord = np.where(stripe_axis[b] == 0, x[r], y[r])
    stripes = 0.5 + 0.5 * np.sin(2 * math.pi * coord / 0.7)
    img[r] = (
        roof_pick[b] * (0.9 + 0.12 * stripes + 0.1 * (value_noise(x[r], y[r], 3.0, seed + 2) - 0.5))[:, None]
    )

    img[cls == SemanticClass.WINDOW] = WINDOW_COLOUR
    img[cls == SemanticClass.DOOR] = DOOR_COLOUR

    azimuth, elevation = rng.uniform(0, 2 * math.pi), math.radians(rng.uniform(30, 70))
    sun = np.array(
        [
            math.cos(azimuth) * math.cos(elevation),
            math.sin(azimuth) * math.cos(elevation),
            math.sin(elevation),
        ]
    )
    lambert = np.clip(normals @ sun, 0.0, None)
    shade = np.where(hit, 0.45 + 0.65 * lambert, 1.0)
    img *= shade[..., None]

    sky = ~hit
    up = np.clip(rays_world[..., 2] / np.linalg.norm(rays_world, axis=-1), 0, 1)[sky]
    img[sky] = SKY_HORIZON * (1 - up[:, None]) + SKY_TOP * up[:, None]

    img *= rng.uniform(0.85, 1.15) * rng.uniform(0.94, 1.06, 3)
    img += rng.normal(0.0, 0.02, img.shape)
    return (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def synthetic_views(
    model: CityModel,
    n: int,
    seed: int = 0,
    camera: Camera | None = None,
    renderer: Renderer | None = None,
    altitude=(60.0, 150.0),
    pitch=(0.0, 40.0),
    min_labelled: float = 0.2,
) -> list[SyntheticView]:
    """``n`` textured views with their automatic labels (views with fewer than ``min_labelled`` non-ignored
    pixels are redrawn)."""
    camera = camera or Camera.from_fov(256, 192, 65.0)
    renderer = renderer or Renderer(model, engine="numba")
    rng = np.random.default_rng(seed)
    out: list[SyntheticView] = []
    attempts = 0
    while len(out) < n:
        attempts += 1
        if attempts > 20 * n:
            raise ParameterError("could not draw views that show the model: is it empty or tiny?")
        pose = sample_poses(model, 1, rng, altitude, pitch)[0]
        res = auto_label_render(model, camera, pose, renderer=renderer)
        if np.mean(res.labels != IGNORE) < min_labelled:
            continue
        image = texture_view(renderer, camera, model.pose_to_local(pose), res.render, rng)
        out.append(SyntheticView(f"synthetic_{len(out):04d}", image, res.labels, pose, camera))
    return out

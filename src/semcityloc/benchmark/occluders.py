"""The simulated reality's occluders: trees and cars on the open ground between the buildings (item 3 of
the ``reality`` module docstring).

Why: no LoD model has them, yet they hide parts of the buildings and the ground in every real UAV image.
Both are BACKGROUND (class 0): a perfect segmentation labels them background, while their depth still
comes from the render. They are placed on the open cells of the footprint raster (``footprints``) by
their distance to the nearest facade and stand on the reality's ground (``terrain_relief``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from semcityloc.benchmark.footprints import FootprintGrid, open_ground_samples
from semcityloc.benchmark.meshes import box_mesh, instances, unit_cone, unit_ellipsoid
from semcityloc.benchmark.terrain_relief import TerrainHeight

if TYPE_CHECKING:
    # for annotations only: ``reality`` imports this module, so importing it back would be a cycle
    from semcityloc.benchmark.reality import RealityParams


def trees(
    dist: np.ndarray,
    grid: FootprintGrid,
    terrain: TerrainHeight,
    params: RealityParams,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Tree meshes on open ground (``reality`` docstring, item 3): vertices, triangles, number of trees."""
    open_cells = dist > 0
    n = int(round(open_cells.sum() * grid.cell**2 / params.tree_m2)) if params.tree_m2 > 0 else 0
    if n == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), 0
    xy, d = open_ground_samples(dist, open_cells, grid, 3 * n, rng)
    h = rng.uniform(*params.tree_height_m, len(xy))
    conifer = rng.random(len(xy)) < 0.3
    radius = np.clip(h * rng.uniform(0.25, 0.45, len(xy)), 1.2, 5.0)
    radius = np.where(conifer, np.clip(h * rng.uniform(0.18, 0.28, len(xy)), 1.0, 3.5), radius)
    angle = rng.uniform(0, 2 * np.pi, len(xy))
    keep = np.flatnonzero(d >= params.tree_facade_clearance * radius)[:n]
    xy, h, conifer, radius, angle = xy[keep], h[keep], conifer[keep], radius[keep], angle[keep]
    z = terrain(xy)
    crown_half = np.where(conifer, 0.0, h * rng.uniform(0.3, 0.4, len(keep)))
    trunk_top = np.where(conifer, z + 0.25 * h, z + h - crown_half)
    trunk_r = np.full(len(keep), 0.2)
    parts_v, parts_f, count = [], [], 0

    def add(v, f):
        nonlocal count
        parts_v.append(v)
        parts_f.append(f + count)
        count += len(v)

    tv, tt, _ = box_mesh(xy, np.stack([trunk_r, trunk_r], 1), angle, z - 0.2, trunk_top + 0.3)
    add(tv, tt)
    dec = ~conifer
    if dec.any():
        uv, uf = unit_ellipsoid()
        scale = np.stack([radius[dec], radius[dec], crown_half[dec]], 1)
        centre = np.column_stack([xy[dec], (z + h - crown_half)[dec]])
        add(*instances(uv, uf, scale, centre, angle[dec]))
    if conifer.any():
        uv, uf = unit_cone()
        scale = np.stack([radius[conifer], radius[conifer], 0.75 * h[conifer]], 1)
        base = np.column_stack([xy[conifer], (z + 0.25 * h)[conifer]])
        add(*instances(uv, uf, scale, base, angle[conifer]))
    return np.concatenate(parts_v), np.concatenate(parts_f), len(keep)


def cars(
    dist: np.ndarray,
    grid: FootprintGrid,
    terrain: TerrainHeight,
    params: RealityParams,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Car boxes near facades, parallel to them (``reality`` docstring, item 3)."""
    lo, hi = params.car_band_m
    band = (dist >= lo) & (dist <= hi)
    n = int(round(band.sum() * grid.cell**2 / params.car_m2)) if params.car_m2 > 0 else 0
    if n == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), 0
    xy, _ = open_ground_samples(dist, band, grid, n, rng)
    gy, gx = np.gradient(dist)
    rows, cols, _ = grid.cells(xy)
    facing = np.arctan2(gy[rows, cols], gx[rows, cols])  # away from the nearest facade
    angle = facing + np.pi / 2 + rng.normal(0.0, 0.05, n)
    size = np.stack([rng.uniform(3.8, 5.0, n), rng.uniform(1.7, 2.0, n)], 1)
    z = terrain(xy)
    v, t, _ = box_mesh(xy, size / 2, angle, z - 0.1, z + rng.uniform(1.4, 1.9, n))
    return v, t, n

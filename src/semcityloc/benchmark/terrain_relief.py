"""The simulated reality's ground: its height at any x, y (``TerrainHeight``) and the smooth relief the
map's terrain lacks (``relief_points``, item 7 of the ``reality`` module docstring).

Why a module of its own: the map's ground is only interpolated between building bases, while the real
one rises and falls by metres over hundreds of metres. ``relief_points`` gives the extra terrain
vertices that make the reality's TIN differ, and ``TerrainHeight`` reads any TIN back, so that trees,
cars, new buildings and the queries' cameras stand on the reality's ground.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import Delaunay, cKDTree

from semcityloc.benchmark.footprints import FootprintGrid
from semcityloc.errors import EmptyModelError

if TYPE_CHECKING:
    # for annotations only: ``reality`` imports this module, so importing it back would be a cycle
    from semcityloc.benchmark.reality import RealityParams

RELIEF_ZERO_M = 3.0  # no terrain relief within this distance of a footprint (the fade runs from here)
RELIEF_WAVES = 8  # plane waves summed into the relief field
RELIEF_BORDER_M = 50.0  # the relief also fades to 0 over this much at the terrain's outer border


class TerrainHeight:
    """Ground height (local z) at x, y: linear on a Delaunay triangulation of the terrain TIN's vertices
    (the TIN is itself a Delaunay triangulation of them), nearest vertex outside it.

    Points are located by a vectorised walk from a triangle at their nearest vertex (no LAPACK: scipy's
    ``find_simplex`` builds its barycentric transforms with one LAPACK call per triangle, which takes
    seconds on a busy multi-threaded BLAS)."""

    MAX_WALK = 500

    def __init__(self, vertices: np.ndarray):
        v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        if len(v) < 3:
            raise EmptyModelError("no terrain: the model has no building footprints to lay a ground under")
        self._xy = v[:, :2]
        self._z = v[:, 2]
        tri = Delaunay(self._xy)
        self._simplices = tri.simplices
        self._neighbors = tri.neighbors  # [i, k]: the triangle opposite vertex k of triangle i (-1: none)
        self._tree = cKDTree(self._xy)
        start = np.zeros(len(v), dtype=np.int64)
        start[self._simplices.reshape(-1)] = np.repeat(np.arange(len(self._simplices)), 3)
        self._start = start

    def _barycentric(self, t: np.ndarray, p: np.ndarray) -> np.ndarray:
        c = self._xy[self._simplices[t]]  # (n, 3, 2)
        e1, e2, q = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0], p - c[:, 0]
        den = e1[:, 0] * e2[:, 1] - e2[:, 0] * e1[:, 1]
        l1 = (q[:, 0] * e2[:, 1] - e2[:, 0] * q[:, 1]) / den
        l2 = (e1[:, 0] * q[:, 1] - q[:, 0] * e1[:, 1]) / den
        return np.column_stack([1.0 - l1 - l2, l1, l2])

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64)
        flat = xy.reshape(-1, 2)
        _, nearest = self._tree.query(flat)
        z = self._z[nearest].astype(np.float64)
        t = self._start[nearest]
        todo = np.arange(len(flat))
        for _ in range(self.MAX_WALK):
            if len(todo) == 0:
                break
            bary = self._barycentric(t[todo], flat[todo])
            k = np.argmin(bary, axis=1)
            inside = bary[np.arange(len(todo)), k] >= -1e-12
            hit = todo[inside]
            z[hit] = (bary[inside] * self._z[self._simplices[t[hit]]]).sum(1)
            nxt = self._neighbors[t[todo[~inside]], k[~inside]]
            walking = todo[~inside]
            t[walking] = np.maximum(nxt, 0)
            todo = walking[nxt >= 0]  # a step out of the hull: keep the nearest vertex's height
        return z.reshape(xy.shape[:-1])


def relief_points(
    terrain_vertices: np.ndarray,
    terrain: TerrainHeight,
    grid: FootprintGrid,
    dist: np.ndarray,
    params: RealityParams,
    rng: np.random.Generator,
) -> np.ndarray:
    """Terrain points with a smooth relief (``reality`` docstring, item 7): (K, 3).

    A ``terrain_grid_m`` grid over the terrain's extent (inset by half a step) at the footprint TIN's
    height plus ``terrain_relief_m`` x f(x, y) x w, where f is a sum of ``RELIEF_WAVES`` plane waves
    (random directions and phases, wavelengths 0.7-1.4 x ``terrain_wavelength_m``) scaled so that max |f|
    over the grid is 1, and w a smoothstep of the distance to the nearest footprint cell over
    ``terrain_fade_m`` (times one over the outer ``RELIEF_BORDER_M``, where the TIN's border ring keeps
    the footprint heights). Points within 1 m of a footprint are left out."""
    lo, hi = terrain_vertices[:, :2].min(0), terrain_vertices[:, :2].max(0)
    s = params.terrain_grid_m
    xs = np.arange(lo[0] + s / 2, hi[0] - s / 4, s)
    ys = np.arange(lo[1] + s / 2, hi[1] - s / 4, s)
    gx, gy = np.meshgrid(xs, ys)
    p = np.column_stack([gx.reshape(-1), gy.reshape(-1)])
    rows, cols, inside = grid.cells(p)
    d = np.where(inside, dist[rows, cols], np.inf)  # outside the grid: >= margin_m >= terrain_fade_m
    p, d = p[d >= 1.0], d[d >= 1.0]
    if len(p) == 0:
        return np.zeros((0, 3))
    theta = rng.uniform(0, 2 * np.pi, RELIEF_WAVES)
    k = 2 * np.pi / (params.terrain_wavelength_m * rng.uniform(0.7, 1.4, RELIEF_WAVES))
    phase = rng.uniform(0, 2 * np.pi, RELIEF_WAVES)
    amp = rng.uniform(0.5, 1.0, RELIEF_WAVES)
    wave = np.stack([np.cos(theta), np.sin(theta)], 1) * k[:, None]  # (W, 2)
    f = (amp[None] * np.cos(p @ wave.T + phase[None])).sum(1)
    f /= max(float(np.abs(f).max()), 1e-12)

    def smooth(x):
        x = np.clip(x, 0.0, 1.0)
        return x * x * (3 - 2 * x)

    edge = np.minimum(p - lo, hi - p).min(1)
    fade = max(params.terrain_fade_m - RELIEF_ZERO_M, 1e-9)
    w = smooth((d - RELIEF_ZERO_M) / fade) * smooth(edge / RELIEF_BORDER_M)
    return np.column_stack([p, terrain(p) + params.terrain_relief_m * f * w])

"""The footprint raster of the simulated reality: which building covers each cell of a grid over the
city, and random points on chosen cells of it.

Why a module of its own: every piece the reality places is checked against this raster. Roof structures
and dormers are kept only where their corners lie on their host building's cells, trees, cars and new
buildings are placed on open cells by their distance to the nearest facade (a distance transform of the
raster, ``reality.build_reality``), and the terrain relief fades in with that distance
(``terrain_relief``). See the ``reality`` module docstring for the whole reality.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_MAX_RASTER_PAIRS = 4_000_000  # (triangle, cell) pairs per vectorised rasterisation chunk


@dataclass
class FootprintGrid:
    """Building index per ``cell`` x ``cell`` m cell (-1 = open), cell (i, j) centred at
    ``lo + ((j + 0.5) cell, (i + 0.5) cell)``."""

    ids: np.ndarray  # (ny, nx) int32
    lo: np.ndarray  # (2,) float64
    cell: float

    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(row, col, inside-grid mask) of points (N, 2)."""
        ij = np.floor((np.asarray(xy) - self.lo) / self.cell).astype(np.int64)
        ny, nx = self.ids.shape
        ok = (ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)
        return np.clip(ij[:, 1], 0, ny - 1), np.clip(ij[:, 0], 0, nx - 1), ok

    def centres(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(N, 2) world x, y of the centres of cells (rows, cols), the inverse of ``cells``."""
        return self.lo + (np.stack([cols, rows], -1) + 0.5) * self.cell


def footprint_grid(corners: np.ndarray, values: np.ndarray, lo: np.ndarray, hi: np.ndarray, cell: float):
    """Rasterise triangles (T, 3, 3) projected to x, y: each cell whose centre is in a triangle gets that
    triangle's value (later triangles win). Steep triangles (walls: |n_z| < 0.2) are skipped: they add
    slivers along the roof outlines at the cost of many cells."""
    lo = np.asarray(lo, dtype=np.float64)
    nx = max(int(np.ceil((hi[0] - lo[0]) / cell)), 1)
    ny = max(int(np.ceil((hi[1] - lo[1]) / cell)), 1)
    ids = np.full((ny, nx), -1, dtype=np.int32)
    p = (corners[:, :, :2] - lo) / cell - 0.5  # cell-centre units: centre of cell j at j
    area2 = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 1, 1] - p[:, 0, 1]) * (
        p[:, 2, 0] - p[:, 0, 0]
    )
    n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    steep = np.abs(n[:, 2]) < 0.2 * np.linalg.norm(n, axis=1)
    keep = (np.abs(area2) > 1e-9) & ~steep
    p, vals, sign = p[keep], np.asarray(values)[keep], np.sign(area2[keep])
    j0 = np.clip(np.ceil(p[:, :, 0].min(1)), 0, nx).astype(np.int64)
    j1 = np.clip(np.floor(p[:, :, 0].max(1)), -1, nx - 1).astype(np.int64)
    i0 = np.clip(np.ceil(p[:, :, 1].min(1)), 0, ny).astype(np.int64)
    i1 = np.clip(np.floor(p[:, :, 1].max(1)), -1, ny - 1).astype(np.int64)
    nj, ni = np.maximum(j1 - j0 + 1, 0), np.maximum(i1 - i0 + 1, 0)
    counts = nj * ni
    start = 0
    while start < len(p):
        cum = np.cumsum(counts[start:])
        stop = start + max(int(np.searchsorted(cum, _MAX_RASTER_PAIRS)), 1)
        sl = slice(start, stop)
        rep = np.repeat(np.arange(start, stop), counts[sl])
        if len(rep):
            first = np.repeat(np.cumsum(counts[sl]) - counts[sl], counts[sl])
            k = np.arange(len(rep)) - first
            jj = j0[rep] + k % nj[rep]
            ii = i0[rep] + k // nj[rep]
            inside = np.ones(len(rep), dtype=bool)
            for e in range(3):
                a, b = p[rep, e], p[rep, (e + 1) % 3]
                edge = (b[:, 0] - a[:, 0]) * (ii - a[:, 1]) - (b[:, 1] - a[:, 1]) * (jj - a[:, 0])
                inside &= edge * sign[rep] >= -1e-9
            ids[ii[inside], jj[inside]] = vals[rep[inside]]
        start = stop
    return FootprintGrid(ids, lo, float(cell))


def open_ground_samples(
    dist: np.ndarray, eligible: np.ndarray, grid: FootprintGrid, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """n candidate points uniformly on the eligible cells: (xy (n, 2), distance to a facade (n,))."""
    cells = np.flatnonzero(eligible.reshape(-1))
    if len(cells) == 0 or n == 0:
        return np.zeros((0, 2)), np.zeros(0)
    pick = cells[rng.integers(0, len(cells), n)]
    rows, cols = np.divmod(pick, eligible.shape[1])
    xy = grid.centres(rows, cols) + rng.uniform(-0.5, 0.5, (n, 2)) * grid.cell
    return xy, dist.reshape(-1)[pick]

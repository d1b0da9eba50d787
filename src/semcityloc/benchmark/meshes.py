"""Mesh primitives of the simulated reality: oriented boxes without bottoms (roof structures, dormers,
tree trunks, cars), a unit UV ellipsoid and a unit cone (tree crowns), and copies of a unit mesh.

Why a module of its own: the same boxes serve the building parts (``building_changes``) and the
occluders (``occluders``); the primitives are plain geometry and know nothing of where they are put.
"""

from __future__ import annotations

import numpy as np


def box_corners(centre: np.ndarray, half: np.ndarray, angle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x, y (N, 4) of the corners of N rectangles centred at ``centre`` (N, 2+), half sizes ``half`` (N, 2),
    turned counter-clockwise by ``angle`` (N,) radians; counter-clockwise from the (-x, -y) corner."""
    sx = np.array([-1, 1, 1, -1], dtype=np.float64)
    sy = np.array([-1, -1, 1, 1], dtype=np.float64)
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    lx, ly = sx[None] * half[:, :1], sy[None] * half[:, 1:2]
    return centre[:, :1] + c * lx - s * ly, centre[:, 1:2] + s * lx + c * ly


def box_mesh(centre: np.ndarray, half: np.ndarray, angle: np.ndarray, z0: np.ndarray, z1: np.ndarray):
    """N oriented boxes without bottoms (corners: ``box_corners``): vertices (8N, 3), triangles (10N, 3),
    is_top (10N,) bool."""
    n = len(centre)
    ring = np.stack(box_corners(centre, half, angle), -1)  # (N, 4, 2)
    bottom = np.concatenate([ring, np.broadcast_to(z0[:, None, None], (n, 4, 1))], -1)
    top = np.concatenate([ring, np.broadcast_to(z1[:, None, None], (n, 4, 1))], -1)
    verts = np.concatenate([bottom, top], 1)  # (N, 8, 3): 0-3 bottom, 4-7 top (counter-clockwise)
    faces = [(4, 5, 6), (4, 6, 7)]
    for k in range(4):
        a, b = k, (k + 1) % 4
        faces += [(a, b, b + 4), (a, b + 4, a + 4)]
    f = np.array(faces, dtype=np.int64)
    tris = (f[None] + 8 * np.arange(n)[:, None, None]).reshape(-1, 3)
    is_top = np.tile(np.array([True, True] + [False] * 8), n)
    return verts.reshape(-1, 3), tris, is_top


def unit_ellipsoid(n_az: int = 8, n_lat: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """A closed UV sphere of radius 1: poles plus ``n_lat`` rings of ``n_az`` vertices."""
    lat = np.linspace(-np.pi / 2, np.pi / 2, n_lat + 2)[1:-1]
    az = np.arange(n_az) * 2 * np.pi / n_az
    ring = np.stack(
        [
            np.cos(lat)[:, None] * np.cos(az)[None],
            np.cos(lat)[:, None] * np.sin(az)[None],
            np.sin(lat)[:, None] * np.ones(n_az)[None],
        ],
        -1,
    ).reshape(-1, 3)
    verts = np.concatenate([[[0, 0, -1.0]], ring, [[0, 0, 1.0]]])
    top = len(verts) - 1
    faces = []
    for j in range(n_az):
        k = (j + 1) % n_az
        faces.append((0, 1 + k, 1 + j))
        faces.append((top, 1 + (n_lat - 1) * n_az + j, 1 + (n_lat - 1) * n_az + k))
        for r in range(n_lat - 1):
            a, b = 1 + r * n_az + j, 1 + r * n_az + k
            faces += [(a, b, b + n_az), (a, b + n_az, a + n_az)]
    return verts, np.array(faces, dtype=np.int64)


def unit_cone(n_az: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Cone of base radius 1 from z = 0 to apex z = 1 (side only: its base is never seen from above)."""
    az = np.arange(n_az) * 2 * np.pi / n_az
    verts = np.concatenate([np.stack([np.cos(az), np.sin(az), np.zeros(n_az)], 1), [[0, 0, 1.0]]])
    faces = [(j, (j + 1) % n_az, n_az) for j in range(n_az)]
    return verts, np.array(faces, dtype=np.int64)


def instances(
    unit_v: np.ndarray, unit_f: np.ndarray, scale: np.ndarray, offset: np.ndarray, angle: np.ndarray
):
    """N copies of a unit mesh: scaled (N, 3), turned about z by ``angle``, moved by ``offset`` (N, 3)."""
    n = len(scale)
    v = unit_v[None] * scale[:, None, :]
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    x = c * v[..., 0] - s * v[..., 1]
    y = s * v[..., 0] + c * v[..., 1]
    v = np.stack([x, y, v[..., 2]], -1) + offset[:, None, :]
    f = unit_f[None] + len(unit_v) * np.arange(n)[:, None, None]
    return v.reshape(-1, 3), f.reshape(-1, 3)

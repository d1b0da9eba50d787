"""Feature edges of a city model: the 3D line segments a wireframe extractor sees in an aerial image.

Why: the LoD-Loc baseline aligns a predicted wireframe (building outlines, roof ridges, eaves) with the
model's wireframe. Its map side is a set of 3D points sampled along those lines; the benchmark's simulated
wireframe extractor draws the same lines. Both come from here.

An edge of the triangle mesh is a feature edge when, among the triangles that share it,

- two meet at an angle of more than ``crease_deg`` (ridges, eaves, wall corners, wall bottoms where the
  wall meets its GroundSurface), or
- two have different classes (window or door frames on a wall), or
- only one triangle has it (an open mesh border: a wall without a GroundSurface below it),

and at least one of them is a building surface (wall, roof, window, door). Triangulation diagonals
inside a flat polygon and the seams between coplanar polygons are not feature edges.

Polygons of CityGML files rarely share vertex indices and often meet at T-junctions (one polygon's
vertex lies inside the neighbour's edge). So vertices are first welded by position (``weld_m``), and
every edge is split at the welded vertices lying on it before edges are matched. Normals are compared up
to sign (``|n1 . n2|``) because the orientation of source polygons is not reliable.

Everything is in the model's local frame, float64.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from semcityloc.citymodel.model import CityModel
from semcityloc.classes import BUILDING_CLASSES
from semcityloc.errors import EmptyModelError, ParameterError

EDGE_BORDER = 0  # only one triangle has the edge
EDGE_CREASE = 1  # two triangles meet at more than crease_deg
EDGE_CLASS = 2  # coplanar triangles of different classes (openings on a wall)

DEFAULT_CREASE_DEG = 20.0
DEFAULT_WELD_M = 0.01


@dataclass(frozen=True)
class ModelEdges:
    """Feature edges of a model (module docstring).

    Attributes:
        segments: float64 (E, 2, 3) end points in the model's local frame.
        kind: uint8 (E,) ``EDGE_BORDER`` / ``EDGE_CREASE`` / ``EDGE_CLASS``.
        building: int32 (E,) index into the model's ``building_ids`` of one building the edge belongs to.
    """

    segments: np.ndarray
    kind: np.ndarray
    building: np.ndarray

    def __len__(self) -> int:
        return int(len(self.segments))

    @property
    def lengths(self) -> np.ndarray:
        """(E,) length of each edge in metres, by which edge points are spread along them."""
        return np.linalg.norm(self.segments[:, 1] - self.segments[:, 0], axis=1)

    def subset(self, mask: np.ndarray) -> ModelEdges:
        """The edges where ``mask`` (E,) is true."""
        keep = np.asarray(mask, dtype=bool)
        return ModelEdges(self.segments[keep], self.kind[keep], self.building[keep])

    def physical(self) -> ModelEdges:
        """Only geometric edges (borders and creases): without window / door frames on flat walls."""
        return self.subset(self.kind != EDGE_CLASS)

    def sample(self, spacing_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Points every ``spacing_m`` along every edge: ((P, 3) float64 points, (P,) int edge index).

        An edge of length L gets ``n = max(1, round(L / spacing_m))`` points at the centres of n equal
        pieces, so neighbouring edges never contribute the same corner twice.
        """
        if not (np.isfinite(spacing_m) and spacing_m > 0):
            raise ParameterError(f"edge sampling spacing must be a positive number of metres: {spacing_m}")
        lengths = self.lengths
        n = np.maximum(1, np.rint(lengths / spacing_m)).astype(np.int64)
        return _points_along(self.segments, n)


def _points_along(segments: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``n[e]`` points at the piece centres of segment e: ((sum n, 3) points, (sum n,) segment index)."""
    edge = np.repeat(np.arange(len(segments)), n)
    if len(edge) == 0:
        return np.zeros((0, 3)), edge
    start = np.cumsum(n) - n
    k = np.arange(len(edge)) - np.repeat(start, n)
    t = (k + 0.5) / n[edge]
    a, b = segments[edge, 0], segments[edge, 1]
    return a + (b - a) * t[:, None], edge


def extract_edges(
    model: CityModel, crease_deg: float = DEFAULT_CREASE_DEG, weld_m: float = DEFAULT_WELD_M
) -> ModelEdges:
    """Feature edges of ``model`` (module docstring). ``EmptyModelError`` when it has no building faces."""
    if not isinstance(model, CityModel):
        raise TypeError(f"extract_edges needs a CityModel, got {type(model).__name__}")
    if not (0.0 < crease_deg < 90.0):
        raise ParameterError(f"crease_deg must be in (0, 90) degrees, got {crease_deg}")
    if not (weld_m > 0.0):
        raise ParameterError(f"weld_m must be positive, got {weld_m}")
    corners = model.triangle_corners()  # (T, 3, 3) float64
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    norm = np.linalg.norm(normals, axis=1)
    ok = norm > 1e-9
    if not np.isin(model.classes[ok], BUILDING_CLASSES).any():
        raise EmptyModelError("the city model has no wall or roof triangles: it has no building edges")
    corners, normals = corners[ok], normals[ok] / norm[ok, None]
    classes, buildings = model.classes[ok], model.building_index[ok]

    # Weld vertices by position.
    key = np.round(corners.reshape(-1, 3) / weld_m).astype(np.int64)
    _, first, vid = np.unique(key, axis=0, return_index=True, return_inverse=True)
    vid = vid.reshape(-1, 3)
    positions = corners.reshape(-1, 3)[first]

    # Triangle edges (face-local index j -> edge (v_j, v_{j+1})), collapsed ones dropped.
    a = vid.reshape(-1)
    b = vid[:, [1, 2, 0]].reshape(-1)
    face = np.repeat(np.arange(len(vid)), 3)
    keep = a != b
    a, b, face = a[keep], b[keep], face[keep]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    pairs, inverse = np.unique(np.stack([lo, hi], 1), axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)

    sub_lo, sub_hi, sub_face = _split_at_t_junctions(positions, pairs, inverse, face, weld_m)

    # Group the (sub-edge, face) incidences by sub-edge.
    order = np.lexsort((sub_face, sub_hi, sub_lo))
    sub_lo, sub_hi, sub_face = sub_lo[order], sub_hi[order], sub_face[order]
    new = np.ones(len(sub_lo), dtype=bool)
    new[1:] = (sub_lo[1:] != sub_lo[:-1]) | (sub_hi[1:] != sub_hi[:-1])
    group = np.cumsum(new) - 1
    starts = np.flatnonzero(new)
    n_groups = len(starts)
    count = np.bincount(group, minlength=n_groups)
    ref_face = sub_face[starts][group]  # first face of each group, per incidence
    dots = np.abs(np.einsum("ij,ij->i", normals[sub_face], normals[ref_face]))
    min_dot = np.full(n_groups, 1.0)
    np.minimum.at(min_dot, group, dots)
    class_diff = np.zeros(n_groups, dtype=bool)
    np.logical_or.at(class_diff, group, classes[sub_face] != classes[ref_face])
    is_building = np.isin(classes[sub_face], BUILDING_CLASSES)
    any_building = np.zeros(n_groups, dtype=bool)
    np.logical_or.at(any_building, group, is_building)
    # The building of an edge: that of its first building face.
    owner = np.full(n_groups, -1, dtype=np.int64)
    bfaces = np.flatnonzero(is_building)[::-1]  # reversed so that the first incidence wins
    owner[group[bfaces]] = buildings[sub_face[bfaces]]

    crease = min_dot < np.cos(np.radians(crease_deg))
    border = count == 1
    kind = np.where(border, EDGE_BORDER, np.where(crease, EDGE_CREASE, EDGE_CLASS)).astype(np.uint8)
    feature = any_building & (border | crease | class_diff)
    seg = np.stack([positions[sub_lo[starts]], positions[sub_hi[starts]]], 1)[feature]
    return ModelEdges(
        segments=np.ascontiguousarray(seg, dtype=np.float64),
        kind=kind[feature],
        building=owner[feature].astype(np.int32),
    )


def _split_at_t_junctions(
    positions: np.ndarray, pairs: np.ndarray, inverse: np.ndarray, face: np.ndarray, tol: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split every unique edge at the welded vertices lying inside it.

    ``pairs`` (U, 2) unique edges, ``inverse`` (I,) the unique edge of each (edge, face) incidence.
    Returns the incidences of the sub-edges: (lo, hi, face) arrays.
    """
    A, B = positions[pairs[:, 0]], positions[pairs[:, 1]]
    d = B - A
    length = np.linalg.norm(d, axis=1)
    tree = cKDTree(positions)
    mid = 0.5 * (A + B)
    lists = tree.query_ball_point(mid, 0.5 * length + tol)
    sizes = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
    cand_edge = np.repeat(np.arange(len(pairs)), sizes)
    cand = np.fromiter((v for x in lists for v in x), dtype=np.int64, count=int(sizes.sum()))
    rel = positions[cand] - A[cand_edge]
    t = np.einsum("ij,ij->i", rel, d[cand_edge]) / np.maximum(length[cand_edge] ** 2, 1e-300)
    off = np.linalg.norm(rel - t[:, None] * d[cand_edge], axis=1)
    along = t * length[cand_edge]
    inside = (
        (cand != pairs[cand_edge, 0])
        & (cand != pairs[cand_edge, 1])
        & (off <= tol)
        & (along > tol)
        & (along < length[cand_edge] - tol)
    )
    if not inside.any():
        return pairs[inverse, 0], pairs[inverse, 1], face
    cand_edge, cand, t = cand_edge[inside], cand[inside], t[inside]
    # Chains a -> interior vertices by t -> b for the split edges.
    split = np.unique(cand_edge)
    node_edge = np.concatenate([split, cand_edge, split])
    node_t = np.concatenate([np.zeros(len(split)), t, np.ones(len(split))])
    node_v = np.concatenate([pairs[split, 0], cand, pairs[split, 1]])
    order = np.lexsort((node_t, node_edge))
    node_edge, node_v = node_edge[order], node_v[order]
    same = node_edge[1:] == node_edge[:-1]
    s_edge = node_edge[:-1][same]
    s_a, s_b = node_v[:-1][same], node_v[1:][same]
    # Incidences of unsplit edges stay; those of split edges are repeated for each of their pieces.
    is_split = np.zeros(len(pairs), dtype=bool)
    is_split[split] = True
    plain = ~is_split[inverse]
    out_lo = [pairs[inverse[plain], 0]]
    out_hi = [pairs[inverse[plain], 1]]
    out_face = [face[plain]]
    pieces_per_edge = np.bincount(s_edge, minlength=len(pairs))
    piece_start = np.cumsum(pieces_per_edge) - pieces_per_edge
    inc = np.flatnonzero(~plain)
    e = inverse[inc]
    reps = pieces_per_edge[e]
    inc_rep = np.repeat(inc, reps)
    k = np.arange(len(inc_rep)) - np.repeat(np.cumsum(reps) - reps, reps)
    piece = piece_start[inverse[inc_rep]] + k
    out_lo.append(np.minimum(s_a[piece], s_b[piece]))
    out_hi.append(np.maximum(s_a[piece], s_b[piece]))
    out_face.append(face[inc_rep])
    return np.concatenate(out_lo), np.concatenate(out_hi), np.concatenate(out_face)

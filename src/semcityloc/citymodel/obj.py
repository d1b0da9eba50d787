"""Read a Wavefront OBJ city mesh (no semantics) into a semantic ``CityModel``.

Why: LoD-Loc's UAVD4L model and many Blender exports are plain OBJ. They carry no classes and no
building ids, so we derive both:

- Parsing: ``v`` (x y z, extra colour/w values ignored), ``f`` with ``i``, ``i/t``, ``i//n``, ``i/t/n``
  tokens and negative (relative) indices, ``o``/``g`` groups. ``vt``/``vn``/``vp``/``l``/``p``/``s``/
  ``mtllib`` are ignored, other keywords counted in a warning. A line we cannot read raises
  ``InputFileError`` naming the line number.
- Faces: triangles as they are; a polygon of more vertices is fanned when it is planar (within
  ``NONPLANAR_TOLERANCE_M``) and strictly convex, otherwise triangulated with earcut
  (``triangulate.triangulate_polygon``). Zero-area faces are dropped and counted as degenerate.
- Buildings: connected components of faces that share a vertex, within one ``o``/``g`` group. Vertices
  closer than ``WELD_TOLERANCE_M`` are one vertex for this (Blender exports duplicate them per face);
  the mesh keeps the original coordinates. Ids are ``obj_<n>``, numbered in file order.
- Winding: OBJ has no outside. Per building we take the signed volume against a reference point at the
  building's lowest height (a missing bottom face then adds nothing): a negative volume means the
  component winds clockwise seen from outside and its triangles are flipped (counted in a warning).
  Components of zero volume (a single flat face) are left as written. Measured on LoD-Loc's
  ``UAVD4L-LoD1.obj``: 692 of 693 judged components already wind outward (1 is flipped); its LoD1 blocks
  have no floor faces, so almost no triangle is ground.
- Classes: a face under a material named like a class (``usemtl roof``: what ``export.write_obj`` writes,
  and Blender exports whose materials are so named) has that class; the others come from the (fixed)
  normals by ``builder.classify_by_normals``: walls, roofs facing up, downward faces at the building's foot
  as ground.
- semcityloc's own export: its header comment (``FRAME_HEADER``) gives the float64 origin its coordinates
  are relative to, kept as the model's, and its CRS (``crs`` overrides it), and each building is an ``o``
  object named by its id (the buildings, ids and all), so that ``city convert`` to OBJ and back keeps the
  model in place and its buildings whole.
- Frame: the coordinates are a local metric frame (``crs`` optional, must be projected/metric). With
  ``z_up=False`` (Y-up exports such as Blender's default) the axes map as
  ``(x, y, z)_world = (x, -z, y)_obj``: a +90 deg rotation about x, so the winding is kept.
- LoD: OBJ names none; every triangle is stored as ``OBJ_LOD``.
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from semcityloc.citymodel.builder import MAX_ABS_COORDINATE_M, UNLABELLED, MeshBuilder, usable_points
from semcityloc.citymodel.crs import metric_crs, overridden_warning
from semcityloc.citymodel.limits import check_file_size
from semcityloc.citymodel.model import CityModel, ParseStats
from semcityloc.citymodel.triangulate import DUPLICATE_TOLERANCE_M, NONPLANAR_TOLERANCE_M, triangulate_polygon
from semcityloc.classes import CLASS_NAMES
from semcityloc.errors import EmptyModelError, InputFileError, counted

# Vertices closer than this are the same vertex when finding connected buildings (metres).
WELD_TOLERANCE_M = 1e-3
# The LoD stored for OBJ triangles (the format names none; LoD-Loc's block models are LoD1).
OBJ_LOD = 1
# Keywords that carry nothing we use: ignored without a warning.
IGNORED_KEYWORDS = frozenset({"vt", "vn", "vp", "s", "mtllib", "l", "p", "cstype", "deg"})
# Materials named like a class (``usemtl roof``, as ``citymodel.export.write_obj`` writes them, and Blender
# exports whose materials are named so) give their faces that class; other faces are classified by normals.
MATERIAL_CLASSES = {name: i for i, name in enumerate(CLASS_NAMES)}
# ``export``'s header comment: the local frame's float64 origin and the CRS, read back so that a converted
# model keeps its place (``# semcityloc local frame: world = origin + vertex; origin X Y Z; crs EPSG:n``).
FRAME_HEADER = re.compile(
    r"#\s*semcityloc local frame: world = origin \+ vertex; origin (\S+) (\S+) (\S+); crs (\S+)"
)
# A component's |signed volume| below this (m^3) says nothing about its winding.
MIN_WINDING_VOLUME_M3 = 1e-9
# Z-up world from Y-up OBJ: world = M @ obj, i.e. (x, -z, y); det = +1 keeps the winding.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def read_obj(path: str | Path, crs: str | None = None, z_up: bool = True) -> CityModel:
    """Read an OBJ mesh as a semantic city model (classes from normals, buildings from connectivity).

    Args:
        path: the ``.obj`` file.
        crs: the metric CRS of the OBJ coordinates, if known (e.g. ``"EPSG:25832"``).
        z_up: False for Y-up exports: world ``(x, y, z) = (x, -z, y)`` of the file.

    Raises:
        InputFileError: unreadable file, or a line that is not valid OBJ (the message names the line).
        CRSError: a CRS that cannot be parsed or is not projected (geographic, Earth-centred, ...).
        EmptyModelError: no face with area.
    """
    path = Path(path)
    stats = ParseStats()
    mesh = _parse(_read_text(path), path)
    crs_name = crs if crs is not None else mesh.header_crs
    if crs is not None and mesh.header_crs is not None:  # as the CityGML reader says an srsName overridden
        if (said := overridden_warning(crs, mesh.header_crs)) is not None:
            stats.warnings.append(said)
    source_crs = None if crs_name is None else metric_crs(crs_name, f"the OBJ's CRS {crs_name!r}")
    verts = mesh.vertices if z_up else mesh.vertices @ Y_UP_TO_Z_UP.T
    if not len(mesh.face_len):
        raise EmptyModelError(f"{path}: the OBJ has no faces")

    stats.polygons = len(mesh.face_len)
    tris, tri_face = _triangulate(verts, mesh, stats)
    if not len(tris):
        raise EmptyModelError(f"{path}: no face of the OBJ has an area")

    named = mesh.origin is not None and all(mesh.group_objects[g] for g in np.unique(mesh.face_group))
    own = named and not mesh.objects_repeat
    if named and mesh.objects_repeat:  # hand-edited: two objects of one name would be one building
        stats.warnings.append("object names repeat in the file: its buildings are taken by connectivity")
    # semcityloc's own export names each building's object: those are the buildings (touching ones, a
    # block's shared walls, would merge by connectivity)
    component = mesh.face_group if own else _components(verts, mesh)
    order, building = np.unique(component, return_inverse=True)
    first_face = np.full(len(order), len(component))
    np.minimum.at(first_face, building, np.arange(len(component)))
    in_file_order = np.argsort(first_face, kind="stable")  # component (index into ``order``) of each rank
    rank = np.empty(len(order), dtype=np.int64)
    rank[in_file_order] = np.arange(len(order))
    face_building = rank[building]  # numbered in file order
    tri_building = face_building[tri_face]

    flipped, n_oriented = _fix_winding(verts, tris, tri_building, len(order))
    if flipped:
        stats.warnings.append(
            f"flipped the winding of {flipped} of the {counted(n_oriented, 'building')} with a volume to "
            f"judge by (of {len(order)}): "
            f"{'it' if flipped == 1 else 'they'} wound clockwise seen from "
            "outside (negative signed volume)"
        )
    if mesh.unknown:
        stats.warnings.append(
            "ignored OBJ keywords: " + ", ".join(f"{k} ({n} lines)" for k, n in mesh.unknown.most_common())
        )
    if not z_up:
        stats.warnings.append("Y-up OBJ: world (x, y, z) = file (x, -z, y)")

    used, compact = np.unique(tris, return_inverse=True)
    # Renumber over the buildings that kept a triangle; np.unique keeps the file order of the ranks.
    present, tri_index = np.unique(tri_building, return_inverse=True)
    builder = MeshBuilder(stats)
    for n in range(len(present)):
        group = int(order[in_file_order[present[n]]])  # with ``own``, a component is an ``o`` group
        builder.building(mesh.group_objects[group] if own else f"obj_{n}")
    tri_class = mesh.face_class[tri_face]
    stats.classified_by_normal = int(len(np.unique(tri_face[tri_class < 0])))
    classes = np.where(tri_class >= 0, tri_class, UNLABELLED)
    if mesh.origin is None:
        builder.add_mesh(verts[used], compact.reshape(-1, 3), classes, tri_index, OBJ_LOD)
        return builder.build(crs=source_crs, source_crs=source_crs, source=str(path))
    # An exported model: its coordinates are relative to the header's float64 origin, kept as the frame's
    builder.add_mesh(verts[used] + mesh.origin, compact.reshape(-1, 3), classes, tri_index, OBJ_LOD)
    return builder.build(crs=source_crs, source_crs=source_crs, source=str(path), origin=mesh.origin)


# ---------------------------------------------------------------------------------------------- parsing


@dataclass
class _ObjMesh:
    vertices: np.ndarray  # (V, 3) float64 as in the file
    face_index: np.ndarray  # (sum of face lengths,) int64 0-based vertex indices
    face_len: np.ndarray  # (F,) int64
    face_group: np.ndarray  # (F,) int64 id of the o/g group
    face_line: np.ndarray  # (F,) int64 line number, for messages
    unknown: Counter
    face_class: np.ndarray  # (F,) int64 class of the face's material (MATERIAL_CLASSES), -1 for none
    origin: np.ndarray | None = None  # FRAME_HEADER's origin, the file's coordinates being relative to it
    header_crs: str | None = None  # FRAME_HEADER's CRS
    group_objects: tuple[str, ...] = ()  # the ``o`` name of each group id
    objects_repeat: bool = False  # an ``o`` name given to two objects (their faces joined in one group)


def _read_text(path: Path) -> str:
    check_file_size(path, "OBJ")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    if b"\x00" in raw[:4096]:
        raise InputFileError(f"{path}: binary data, not a text OBJ file")
    return raw.decode("utf-8", errors="replace")


def _logical_lines(text: str):
    """(line number, stripped line) with backslash continuations joined (number of the first line)."""
    pending, start = "", 0
    for lineno, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if stripped.endswith("\\"):
            if not pending:
                start = lineno
            pending += stripped[:-1] + " "
            continue
        if pending:
            yield start, (pending + stripped).strip()
            pending = ""
        else:
            yield lineno, stripped
    if pending:  # a continuation at the end of the file (or a lone backslash): what came before it
        yield start, pending.strip()


def _frame_header(match: re.Match) -> tuple[np.ndarray | None, str | None]:
    """(origin, CRS name) of ``FRAME_HEADER``; (None, None) when its numbers are none (a hand-edited file)."""
    try:
        origin = np.array([float(match.group(i)) for i in (1, 2, 3)], dtype=np.float64)
    except ValueError:
        return None, None
    if not usable_points(origin[None]).all():
        return None, None
    crs = match.group(4)
    return origin, (None if crs == "None" else crs)


def _parse(text: str, path: Path) -> _ObjMesh:
    verts: list[tuple[float, float, float]] = []
    vert_lines: list[int] = []
    face_index: list[int] = []
    face_len: list[int] = []
    face_group: list[int] = []
    face_line: list[int] = []
    groups: dict[tuple[str, str], int] = {}
    obj_name, group_name = "", ""
    group_id = groups.setdefault((obj_name, group_name), 0)
    object_names: set[str] = set()
    objects_repeat = False
    unknown: Counter = Counter()
    face_class: list[int] = []
    material = -1
    origin, header_crs = None, None

    def fail(lineno: int, line: str, why: str) -> InputFileError:
        return InputFileError(f"{path}: line {lineno}: {why}: {line[:80]!r}")

    for lineno, line in _logical_lines(text):
        if line.startswith("#") and origin is None and (frame := FRAME_HEADER.match(line)):
            origin, header_crs = _frame_header(frame)
            continue
        if not line or line[0] == "#":
            continue
        parts = line.split()
        kw = parts[0]
        if kw == "v":
            if len(parts) < 4:
                raise fail(lineno, line, "a vertex needs x y z")
            try:
                xyz = (float(parts[1]), float(parts[2]), float(parts[3]))
            except ValueError:
                raise fail(lineno, line, "vertex coordinates are not numbers") from None
            verts.append(xyz)
            vert_lines.append(lineno)
        elif kw == "f":
            if len(parts) < 4:
                raise fail(lineno, line, "a face needs at least 3 vertices")
            n_verts = len(verts)
            for token in parts[1:]:
                try:
                    i = int(token.split("/", 1)[0])
                except ValueError:
                    raise fail(lineno, line, f"face vertex {token!r} is not an index") from None
                if 0 < i <= 2**62:
                    face_index.append(i - 1)  # range checked once the whole file is read
                elif i < 0 and n_verts + i >= 0:
                    face_index.append(n_verts + i)
                else:
                    raise fail(lineno, line, f"face vertex index {i} refers to no vertex")
            face_len.append(len(parts) - 1)
            face_group.append(group_id)
            face_line.append(lineno)
            face_class.append(material)
        elif kw == "usemtl":
            material = MATERIAL_CLASSES.get(" ".join(parts[1:]).strip().lower(), -1)
        elif kw in ("o", "g"):
            name = " ".join(parts[1:])
            if kw == "o":
                objects_repeat = objects_repeat or name in object_names
                object_names.add(name)
                obj_name, group_name = name, ""
            else:
                group_name = name
            group_id = groups.setdefault((obj_name, group_name), len(groups))
        elif kw not in IGNORED_KEYWORDS:
            unknown[kw] += 1

    vertices = np.array(verts, dtype=np.float64).reshape(-1, 3)
    bad_vertex = ~usable_points(vertices)
    if bad_vertex.any():
        lineno = vert_lines[int(np.argmax(bad_vertex))]
        raise InputFileError(
            f"{path}: line {lineno}: vertex coordinates are not finite or beyond {MAX_ABS_COORDINATE_M:g} m"
        )
    mesh = _ObjMesh(
        vertices,
        np.array(face_index, dtype=np.int64),
        np.array(face_len, dtype=np.int64),
        np.array(face_group, dtype=np.int64),
        np.array(face_line, dtype=np.int64),
        unknown,
        np.array(face_class, dtype=np.int64),
        origin,
        header_crs,
        tuple(name for (name, _), _ in sorted(groups.items(), key=lambda kv: kv[1])),
        objects_repeat,
    )
    out_of_range = mesh.face_index >= len(vertices)
    if out_of_range.any():
        corner = int(np.argmax(out_of_range))
        face = np.repeat(np.arange(len(mesh.face_len)), mesh.face_len)[corner]
        raise InputFileError(
            f"{path}: line {mesh.face_line[face]}: face vertex index {mesh.face_index[corner] + 1} "
            f"refers to no vertex (the file has {len(vertices)})"
        )
    return mesh


# ---------------------------------------------------------------------------------------------- faces


def _batch_normals(p: np.ndarray) -> np.ndarray:
    """Newell normals (m, 3) of m polygons (m, n, 3) (centred first for precision)."""
    a = p - p.mean(axis=1, keepdims=True)
    b = np.roll(a, -1, axis=1)
    return np.stack(
        [
            np.sum((a[..., 1] - b[..., 1]) * (a[..., 2] + b[..., 2]), axis=1),
            np.sum((a[..., 2] - b[..., 2]) * (a[..., 0] + b[..., 0]), axis=1),
            np.sum((a[..., 0] - b[..., 0]) * (a[..., 1] + b[..., 1]), axis=1),
        ],
        axis=1,
    )


def _triangulate(verts: np.ndarray, mesh: _ObjMesh, stats: ParseStats) -> tuple[np.ndarray, np.ndarray]:
    """Triangles (T, 3) of vertex indices and the face (T,) each came from, in face order."""
    starts = np.concatenate([[0], np.cumsum(mesh.face_len)[:-1]])
    tri_chunks: list[np.ndarray] = []
    face_chunks: list[np.ndarray] = []
    for n in np.unique(mesh.face_len):
        faces = np.flatnonzero(mesh.face_len == n)
        idx = mesh.face_index[starts[faces, None] + np.arange(n)]  # (m, n)
        p = verts[idx]
        normal = _batch_normals(p)
        norm = np.linalg.norm(normal, axis=1)
        size = np.ptp(p, axis=1).max(axis=1)
        ok = (norm > 1e-12 * size * size) & (norm > 1e-10)
        if n == 3:
            stats.degenerate_polygons += int((~ok).sum())
            tri_chunks.append(idx[ok])
            face_chunks.append(faces[ok])
            continue
        unit = normal / np.maximum(norm, 1e-300)[:, None]
        planarity = np.abs(np.einsum("mnk,mk->mn", p - p.mean(axis=1, keepdims=True), unit)).max(axis=1)
        edges = np.roll(p, -1, axis=1) - p
        turn = np.einsum("mnk,mk->mn", np.cross(edges, np.roll(edges, -1, axis=1)), unit)
        edge2 = np.einsum("mnk,mnk->mn", edges, edges)
        convex = (turn > 1e-9 * np.maximum(edge2, np.roll(edge2, -1, axis=1))).all(axis=1)
        fan = ok & convex & (planarity <= NONPLANAR_TOLERANCE_M)
        if fan.any():
            k = np.arange(1, n - 1)
            fan_idx = idx[fan]
            tris = np.stack(
                [np.repeat(fan_idx[:, :1], n - 2, axis=1), fan_idx[:, k], fan_idx[:, k + 1]], axis=2
            )
            tri_chunks.append(tris.reshape(-1, 3))
            face_chunks.append(np.repeat(faces[fan], n - 2))
        for row in np.flatnonzero(~fan):
            tris = _earcut_face(verts, idx[row])
            if planarity[row] > NONPLANAR_TOLERANCE_M:
                stats.nonplanar_polygons += 1
            if tris is None:
                stats.degenerate_polygons += 1
                continue
            tri_chunks.append(tris)
            face_chunks.append(np.full(len(tris), faces[row]))
    tris = np.concatenate(tri_chunks) if tri_chunks else np.zeros((0, 3), dtype=np.int64)
    tri_face = np.concatenate(face_chunks) if face_chunks else np.zeros(0, dtype=np.int64)
    order = np.argsort(tri_face, kind="stable")
    return tris[order], tri_face[order]


def _earcut_face(verts: np.ndarray, idx: np.ndarray) -> np.ndarray | None:
    """Triangles (k, 3) in vertex indices of one polygon, or None when it is degenerate."""
    ring = verts[idx]
    step = np.linalg.norm(np.diff(ring, axis=0, append=ring[:1]), axis=1)
    kept = idx[step > DUPLICATE_TOLERANCE_M]  # the points triangulate_polygon keeps (clean_ring)
    tri = triangulate_polygon(ring)
    if tri is None or len(tri.points) != len(kept):
        return None
    return kept[tri.triangles]


# ---------------------------------------------------------------------------------------------- buildings


def _components(verts: np.ndarray, mesh: _ObjMesh) -> np.ndarray:
    """Component label per face: faces sharing a (welded) vertex within one o/g group."""
    n_vert = len(verts)
    pairs = cKDTree(verts).query_pairs(WELD_TOLERANCE_M, output_type="ndarray")
    weld_graph = sparse.coo_matrix(
        (np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n_vert, n_vert)
    )
    _, weld = connected_components(weld_graph, directed=False)

    n_face = len(mesh.face_len)
    corner_face = np.repeat(np.arange(n_face), mesh.face_len)
    key = mesh.face_group[corner_face] * (int(weld.max()) + 1) + weld[mesh.face_index]
    _, node = np.unique(key, return_inverse=True)
    n_nodes = n_face + int(node.max()) + 1
    graph = sparse.coo_matrix(
        (np.ones(len(corner_face), dtype=np.int8), (corner_face, n_face + node)), shape=(n_nodes, n_nodes)
    )
    _, labels = connected_components(graph, directed=False)
    return labels[:n_face]


def _fix_winding(
    verts: np.ndarray, tris: np.ndarray, tri_building: np.ndarray, n_buildings: int
) -> tuple[int, int]:
    """Flip (in place) the triangles of buildings with negative signed volume.

    Returns (flipped, oriented): how many buildings were flipped, how many had a volume to judge by.
    """
    corners = verts[tris]  # (T, 3, 3)
    lo = np.full((n_buildings, 3), np.inf)
    np.minimum.at(lo, tri_building, corners.min(axis=1))
    hi = np.full((n_buildings, 3), -np.inf)
    np.maximum.at(hi, tri_building, corners.max(axis=1))
    lo[~np.isfinite(lo)], hi[~np.isfinite(hi)] = 0.0, 0.0  # components left without a triangle
    ref = np.column_stack([0.5 * (lo[:, :2] + hi[:, :2]), lo[:, 2]])  # centre of the foot
    rel = corners - ref[tri_building][:, None, :]
    det = np.einsum("ij,ij->i", rel[:, 0], np.cross(rel[:, 1], rel[:, 2]))
    volume = np.bincount(tri_building, weights=det / 6.0, minlength=n_buildings)
    judged = np.abs(volume) > MIN_WINDING_VOLUME_M3
    flip = judged & (volume < 0)
    rows = flip[tri_building]
    tris[rows] = tris[rows][:, [0, 2, 1]]
    return int(flip.sum()), int(judged.sum())

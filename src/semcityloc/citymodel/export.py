"""Write a ``CityModel`` as a semantic mesh other tools open: PLY, OBJ (+MTL) or our npz.

PLY (binary little-endian) carries per-face ``class`` and ``building`` properties and per-vertex
colours from the class palette; OBJ carries one material per class (``usemtl roof`` ...) and a ``.mtl``
with the palette. Both write world coordinates *relative to the model origin* (float32-safe) and record
the origin and CRS in a header comment, so a viewer shows the model without precision loss.

Every file is written whole or not at all (``io.files.write_atomic``; stop 55): a full disk or a Ctrl-C
left a truncated PLY under its final name, which a viewer opens as a model missing its last faces.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from semcityloc.citymodel.model import CityModel, crs_label
from semcityloc.classes import CLASS_NAMES, PALETTE
from semcityloc.errors import UnsupportedFormatError
from semcityloc.io.files import write_atomic


def export_paths(path: str | Path) -> list[Path]:
    """The files ``export_model`` writes for ``path``: it, and an OBJ's ``.mtl`` beside it."""
    path = Path(path)
    return [path, path.with_suffix(".mtl")] if path.suffix.lower() == ".obj" else [path]


def export_model(model: CityModel, path: str | Path) -> Path:
    """Write ``model`` as ``.npz``, ``.ply`` or ``.obj`` (chosen by the suffix; the folder made) and return
    the path; ``semcityloc city convert`` and library callers share it.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".npz":
        return model.save_npz(path)
    if suffix == ".ply":
        return write_ply(model, path)
    if suffix == ".obj":
        return write_obj(model, path)
    raise UnsupportedFormatError(f"{path}: cannot write '{suffix}' (use .ply, .obj or .npz)")


def _header_comment(model: CityModel) -> str:
    o = model.origin
    origin = " ".join(repr(float(v)) for v in o)  # float64 exactly (the shortest round-trip form)
    return f"semcityloc local frame: world = origin + vertex; origin {origin}; crs {crs_label(model.crs)}"


def write_ply(model: CityModel, path: str | Path) -> Path:
    """Binary PLY with face properties ``class`` (uchar) and ``building`` (int). Vertices are unshared per
    face so each carries its face's class colour."""
    tris = model.triangles
    n = len(tris)
    verts = model.vertices[tris.reshape(-1)]
    colors = np.repeat(PALETTE[model.classes], 3, axis=0)
    vertex = np.empty(
        3 * n,
        dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")],
    )
    vertex["x"], vertex["y"], vertex["z"] = verts[:, 0], verts[:, 1], verts[:, 2]
    vertex["red"], vertex["green"], vertex["blue"] = colors[:, 0], colors[:, 1], colors[:, 2]
    face = np.empty(n, dtype=[("n", "u1"), ("v", "<i4", (3,)), ("class", "u1"), ("building", "<i4")])
    face["n"] = 3
    face["v"] = np.arange(3 * n, dtype=np.int32).reshape(-1, 3)
    face["class"] = model.classes
    face["building"] = model.building_index
    classes_comment = " ".join(f"{i}={name}" for i, name in enumerate(CLASS_NAMES))
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"comment {_header_comment(model)}\n"
        f"comment classes {classes_comment}\n"
        f"element vertex {3 * n}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        f"element face {n}\n"
        "property list uchar int vertex_indices\nproperty uchar class\nproperty int building\n"
        "end_header\n"
    )
    path = Path(path)
    write_atomic(path, header.encode("ascii") + vertex.tobytes() + face.tobytes())
    return path


def write_obj(model: CityModel, path: str | Path) -> Path:
    """OBJ with a material per class and an MTL file beside it; one ``o <building id>`` per building (what
    ``obj.read_obj`` reads back as the buildings), its faces grouped by class."""
    path = Path(path)
    mtl = export_paths(path)[1]
    materials = []
    for i, name in enumerate(CLASS_NAMES):
        r, g, b = PALETTE[i] / 255.0
        materials.append(f"newmtl {name}\nKd {r:.4f} {g:.4f} {b:.4f}\n\n")
    write_atomic(mtl, "".join(materials).encode("ascii"))
    lines = [f"# {_header_comment(model)}", f"mtllib {mtl.name}"]
    lines.extend(f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in model.vertices)
    order = np.lexsort((model.classes, model.building_index))  # one sort, not a mask per building
    building, classes, faces = model.building_index[order], model.classes[order], model.triangles[order] + 1
    for i in range(len(order)):
        if i == 0 or building[i] != building[i - 1]:
            lines.append(f"o {model.building_ids[building[i]]}")
        if i == 0 or building[i] != building[i - 1] or classes[i] != classes[i - 1]:
            lines.append(f"usemtl {CLASS_NAMES[classes[i]]}")
        a, c, d = faces[i]
        lines.append(f"f {a} {c} {d}")
    write_atomic(path, ("\n".join(lines) + "\n").encode("ascii"))
    return path

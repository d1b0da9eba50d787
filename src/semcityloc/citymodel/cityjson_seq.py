"""Merge a CityJSONSeq stream (``.city.jsonl``) into one CityJSON document for ``read_cityjson``.

Why: 3DBAG's API and ``cjio ... export jsonl`` deliver buildings as CityJSONSeq (CityJSON 1.1 / 2.0): a
first line that is a CityJSON object holding the ``transform``, the CRS and any geometry templates (its
``CityObjects`` and ``vertices`` usually empty), then one ``CityJSONFeature`` per line, each with its own
vertex list (integers under the first line's transform) and the city objects of one building. The merge
appends the features' vertex lists to one array and shifts every geometry's indices by its feature's
offset, so the reader sees an ordinary CityJSON document.

An index outside its own feature's vertex list becomes -1, which the reader skips and counts as an invalid
polygon: shifted, it would silently name a vertex of another building. A line that is not JSON or not a
``CityJSONFeature`` (a truncated download's last line, a stray object), or a feature whose vertices are not
``[x, y, z]`` numbers, is left out and counted in one warning; the other buildings are read.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from semcityloc.errors import MalformedCityJSONError

FEATURE = "CityJSONFeature"
# Boundary nesting: a CompositeSolid's index sits 5 lists down (solids, shells, surfaces, rings, indices).
_MAX_BOUNDARY_DEPTH = 6


def looks_like_sequence(raw: bytes) -> bool:
    """Is ``raw`` a CityJSONSeq stream: a first line that is a whole JSON object of type CityJSON (or a
    feature: a stream that lost its first line), and more after it? A pretty-printed CityJSON file opens
    with a line that is no whole object, so it is never taken for one."""
    first, _, rest = raw.lstrip(b"\xef\xbb\xbf").lstrip().partition(b"\n")
    if not rest.strip() or not first.rstrip().endswith(b"}"):
        return False
    try:
        head = json.loads(first)
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError, ValueError):
        return False
    return isinstance(head, dict) and head.get("type") in ("CityJSON", FEATURE)


def merge_sequence(raw: bytes, where: str) -> tuple[dict, list[str]]:
    """One CityJSON document (vertices as a float64 (n, 3) array) from a CityJSONSeq stream, and the
    warnings about lines left out.

    Raises:
        MalformedCityJSONError: the first line is a feature (the stream lost its header, so the transform
            and the CRS are unknown) or no CityJSON object.
    """
    lines = raw.lstrip(b"\xef\xbb\xbf").lstrip().split(b"\n")
    header = json.loads(lines[0])
    if header.get("type") == FEATURE:
        raise MalformedCityJSONError(
            f"{where}: a CityJSONSeq stream without its first line (the CityJSON object with the transform "
            "and the CRS): its features' integer vertices cannot be placed"
        )
    objects = header.get("CityObjects")
    if not isinstance(objects, dict) or not isinstance(header.get("vertices"), list):
        raise MalformedCityJSONError(
            f"{where}: the first line of the CityJSONSeq stream needs 'CityObjects' (an object) and "
            "'vertices' (an array), empty as they usually are"
        )
    doc = dict(header)
    merged: dict[str, Any] = dict(objects)
    blocks = [_vertices(header["vertices"])]
    if blocks[0] is None:
        raise MalformedCityJSONError(f"{where}: the first line's 'vertices' are not [x, y, z] numbers")
    offset = len(blocks[0])
    left_out: list[str] = []
    duplicates = 0
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        feature, why = _feature(line)
        verts = _vertices(feature["vertices"]) if feature is not None else None
        if feature is not None and verts is None:
            why = "its 'vertices' are not [x, y, z] numbers"
        if verts is None:
            left_out.append(f"line {number}: {why}")
            continue
        for key, obj in feature["CityObjects"].items():
            if key in merged:
                duplicates += 1
                continue
            merged[key] = _shifted_object(obj, offset, len(verts))
        blocks.append(verts)
        offset += len(verts)
    doc["CityObjects"] = merged
    doc["vertices"] = np.concatenate(blocks) if offset else np.zeros((0, 3))
    warnings = []
    if left_out:
        shown = "; ".join(left_out[:3]) + (f"; and {len(left_out) - 3} more" if len(left_out) > 3 else "")
        warnings.append(
            f"left out {len(left_out)} lines of the CityJSONSeq stream that are no feature: {shown}"
        )
    if duplicates:
        warnings.append(f"ignored {duplicates} city objects of the CityJSONSeq stream whose id came before")
    return doc, warnings


def _feature(line: bytes) -> tuple[dict | None, str]:
    """The parsed feature of one line, or None and why it is none."""
    try:
        node = json.loads(line)
    except json.JSONDecodeError as exc:
        return None, f"not valid JSON (column {exc.colno}: {exc.msg})"
    except (UnicodeDecodeError, RecursionError, ValueError) as exc:
        return None, f"not valid JSON ({exc})"
    if not isinstance(node, dict) or node.get("type") != FEATURE:
        kind = node.get("type") if isinstance(node, dict) else type(node).__name__
        return None, f"a {str(kind)[:40]!r}, not a {FEATURE}"
    if not isinstance(node.get("CityObjects"), dict) or not isinstance(node.get("vertices"), list):
        return None, "a feature without 'CityObjects' (an object) and 'vertices' (an array)"
    return node, ""


def _vertices(values: list) -> np.ndarray | None:
    """(n, 3) float64 of one feature's vertex list, or None when it is not one."""
    if not values:
        return np.zeros((0, 3))
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        return None
    return arr if arr.ndim == 2 and arr.shape[1] == 3 else None


def _shifted_object(obj: Any, offset: int, count: int) -> Any:
    """A city object whose geometries index the merged vertex list (anything malformed passed on as it is,
    for the reader to count)."""
    if not isinstance(obj, dict) or not isinstance(obj.get("geometry"), list):
        return obj
    geometries = []
    for geom in obj["geometry"]:
        if isinstance(geom, dict) and "boundaries" in geom:
            geom = {**geom, "boundaries": _shifted(geom["boundaries"], offset, count, 0)}
        geometries.append(geom)
    return {**obj, "geometry": geometries}


def _shifted(node: Any, offset: int, count: int, depth: int) -> Any:
    """Indices in ``[0, count)`` moved by ``offset``, other integers made -1 (invalid for the reader)."""
    if not isinstance(node, list) or depth > _MAX_BOUNDARY_DEPTH:
        return node
    out = []
    for value in node:
        if isinstance(value, list):
            out.append(_shifted(value, offset, count, depth + 1))
        elif isinstance(value, int) and not isinstance(value, bool):
            out.append(value + offset if 0 <= value < count else -1)
        else:
            out.append(value)
    return out

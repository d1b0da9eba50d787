"""CityJSONSeq streams (``.city.jsonl``): read as the CityJSON they were cut from; broken lines left out and
counted; an index beyond its own feature never names another building's vertex."""

from __future__ import annotations

import copy
import gzip
import json
from pathlib import Path

import numpy as np
import pytest

from semcityloc.citymodel.cityjson import read_cityjson
from semcityloc.citymodel.io import load_city_model
from semcityloc.errors import MalformedCityJSONError
from test_cityjson import BOX_MM, box_doc


def _indices(node, out: list) -> None:
    for value in node:
        if isinstance(value, list):
            _indices(value, out)
        else:
            out.append(value)


def _reindexed(node, local: dict):
    return [_reindexed(v, local) if isinstance(v, list) else local[v] for v in node]


def to_sequence(doc: dict) -> list[dict]:
    """The CityJSONSeq lines of a CityJSON document, cut the way cjio and 3DBAG cut it: a header with the
    transform and metadata, then one feature per root object (its children with it), each with its own
    vertex list."""
    header = {k: v for k, v in doc.items() if k not in ("CityObjects", "vertices", "appearance")}
    lines = [{**header, "CityObjects": {}, "vertices": []}]
    objects = doc["CityObjects"]
    for key, obj in objects.items():
        if obj.get("parents"):
            continue
        members = {key: obj} | {c: objects[c] for c in obj.get("children", [])}
        used: list = []
        for member in members.values():
            for geom in member.get("geometry", []):
                _indices(geom["boundaries"], used)
        order = sorted(set(used))
        local = {v: i for i, v in enumerate(order)}
        shifted = {
            k: {
                **m,
                "geometry": [
                    {**g, "boundaries": _reindexed(g["boundaries"], local)} for g in m.get("geometry", [])
                ],
            }
            for k, m in members.items()
        }
        lines.append(
            {
                "type": "CityJSONFeature",
                "id": key,
                "CityObjects": shifted,
                "vertices": [doc["vertices"][v] for v in order],
            }
        )
    return lines


def write_lines(tmp_path: Path, lines: list, name: str = "c.city.jsonl") -> Path:
    path = tmp_path / name
    path.write_text("\n".join(line if isinstance(line, str) else json.dumps(line) for line in lines) + "\n")
    return path


def triangles_of(model) -> list:
    """Every triangle as (building id, class, world corners to the mm), sorted: two readings of the same
    buildings compare equal whatever order or local origin they were meshed in."""
    world = model.origin + model.vertices.astype(np.float64)
    corners = np.round(world[model.triangles] * 1000).astype(np.int64)
    ids = [model.building_ids[b] for b in model.building_index]
    return sorted(zip(ids, model.classes.tolist(), map(tuple, corners.reshape(-1, 9).tolist()), strict=True))


def two_boxes() -> dict:
    """Two buildings, the second 10 m east of the first, one shared vertex list."""
    doc = box_doc(metadata={"referenceSystem": "https://www.opengis.net/def/crs/EPSG/0/7415"})
    second = copy.deepcopy(doc["CityObjects"]["B1"])
    second["geometry"][0]["boundaries"] = [
        [[[v + 8 for v in ring] for ring in face] for face in second["geometry"][0]["boundaries"][0]]
    ]
    doc["CityObjects"]["B2"] = second
    doc["vertices"] = copy.deepcopy(BOX_MM) + [[x + 10000, y, z] for x, y, z in BOX_MM]
    return doc


def test_a_stream_reads_as_the_document_it_was_cut_from(tmp_path):
    doc = two_boxes()
    whole = read_cityjson(write_lines(tmp_path, [doc], "whole.json"))
    streamed = read_cityjson(write_lines(tmp_path, to_sequence(doc)))
    assert streamed.num_buildings == 2
    assert triangles_of(streamed) == triangles_of(whole)
    assert streamed.stats.warnings == whole.stats.warnings == []
    assert streamed.crs == whole.crs and streamed.crs is not None  # the header's CRS holds for every feature


def test_each_feature_keeps_its_own_vertices(tmp_path):
    """Both features index their vertices from 0: without the shift both buildings would sit at the
    first one's place."""
    lines = to_sequence(two_boxes())
    assert lines[1]["vertices"] != lines[2]["vertices"]
    assert lines[1]["CityObjects"]["B1"]["geometry"] == lines[2]["CityObjects"]["B2"]["geometry"]
    model = read_cityjson(write_lines(tmp_path, lines))
    world = model.origin + model.vertices.astype(np.float64)
    east = [world[model.triangles[model.building_index == b]][..., 0].mean() for b in range(2)]
    assert abs(abs(east[1] - east[0]) - 10.0) < 1e-6


def test_an_index_beyond_its_feature_is_an_invalid_polygon_not_another_buildings_vertex(tmp_path):
    lines = to_sequence(two_boxes())
    roof = lines[1]["CityObjects"]["B1"]["geometry"][0]["boundaries"][0][1][0]
    roof[0] = 9  # the first feature has 8 vertices: index 9 would be the second feature's vertex 1
    model = read_cityjson(write_lines(tmp_path, lines))
    assert model.stats.malformed_polygons == 1
    assert any("skipped 1 polygons with invalid vertex indices" in w for w in model.stats.warnings)
    whole = read_cityjson(write_lines(tmp_path, [two_boxes()], "whole.json"))
    assert model.num_triangles == whole.num_triangles - 2  # one quad (two triangles) left out


def test_broken_lines_are_left_out_and_counted_the_rest_is_read(tmp_path):
    lines = to_sequence(two_boxes())
    truncated = json.dumps(lines[2])[:57]  # a download cut off in its last line
    stray = {"type": "CityJSON", "version": "2.0"}
    bad_vertices = {**lines[1], "CityObjects": {"B9": lines[1]["CityObjects"]["B1"]}, "vertices": [[1, 2]]}
    model = read_cityjson(write_lines(tmp_path, [lines[0], lines[1], stray, bad_vertices, "", truncated]))
    assert model.building_ids == ["B1"]
    (note,) = [w for w in model.stats.warnings if "CityJSONSeq" in w]
    assert note.startswith("left out 3 lines of the CityJSONSeq stream")
    assert "line 3: a 'CityJSON', not a CityJSONFeature" in note
    assert "line 4: its 'vertices' are not [x, y, z] numbers" in note
    assert "line 6: not valid JSON" in note


def test_a_repeated_id_keeps_the_first_and_says_so(tmp_path):
    lines = to_sequence(two_boxes())
    again = {**lines[2], "CityObjects": {"B1": lines[2]["CityObjects"]["B2"]}}
    model = read_cityjson(write_lines(tmp_path, [*lines, again]))
    assert sorted(model.building_ids) == ["B1", "B2"]
    assert any("ignored 1 city objects of the CityJSONSeq stream" in w for w in model.stats.warnings)


def test_a_stream_without_its_first_line_is_refused_naming_it(tmp_path):
    lines = to_sequence(two_boxes())
    with pytest.raises(MalformedCityJSONError, match="without its first line"):
        read_cityjson(write_lines(tmp_path, lines[1:]))


def test_a_single_line_document_is_no_stream(tmp_path):
    path = tmp_path / "one.json"
    path.write_text(json.dumps(two_boxes()) + "\n\n")
    assert read_cityjson(path).num_buildings == 2


def test_load_city_model_takes_a_gzipped_stream(tmp_path):
    doc = two_boxes()
    path = tmp_path / "c.city.jsonl.gz"
    path.write_bytes(gzip.compress("\n".join(json.dumps(x) for x in to_sequence(doc)).encode()))
    model = load_city_model(path, cache=False)
    whole = read_cityjson(write_lines(tmp_path, [doc], "whole.json"))
    assert triangles_of(model) == triangles_of(whole)


@pytest.mark.parametrize("name", ["rotterdam_subset", "delft", "multi_lod"])
def test_real_files_read_the_same_as_streams(shared, tmp_path, name):
    doc = json.loads(shared(f"cityjson_nl/{name}.json").read_text())
    whole = read_cityjson(shared(f"cityjson_nl/{name}.json"))
    streamed = read_cityjson(write_lines(tmp_path, to_sequence(doc)))
    assert streamed.num_buildings == whole.num_buildings > 0
    assert triangles_of(streamed) == triangles_of(whole)

"""CityJSON reader: versions, transform, semantics, parts, LoD selection, CRS, bad input, real files."""

from __future__ import annotations

import copy
import functools
import gzip
import importlib.util
import json
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest

from semcityloc.citymodel.cityjson import lod_key, read_cityjson
from semcityloc.citymodel.model import crs_label
from semcityloc.classes import SemanticClass
from semcityloc.errors import (
    CRSError,
    EmptyModelError,
    InputFileError,
    MalformedCityJSONError,
    UnsupportedFormatError,
)

# A 4 x 3 x 5 m box; integer vertices in mm with a Dutch RD translate.
TRANSLATE = [85000.0, 447000.0, 1.5]
BOX_MM = [
    [0, 0, 0],
    [4000, 0, 0],
    [4000, 3000, 0],
    [0, 3000, 0],
    [0, 0, 5000],
    [4000, 0, 5000],
    [4000, 3000, 5000],
    [0, 3000, 5000],
]
# Solid shell, counter-clockwise seen from outside: ground, roof, 4 walls.
BOX_SHELL = [
    [[0, 3, 2, 1]],
    [[4, 5, 6, 7]],
    [[0, 1, 5, 4]],
    [[1, 2, 6, 5]],
    [[2, 3, 7, 6]],
    [[3, 0, 4, 7]],
]
BOX_SEMANTICS = {
    "surfaces": [{"type": "GroundSurface"}, {"type": "RoofSurface"}, {"type": "WallSurface"}],
    "values": [[0, 1, 2, 2, 2, 2]],
}


def box_doc(version: str = "2.0", lod="2", semantics: bool = True, **extra) -> dict:
    geom = {"type": "Solid", "lod": lod, "boundaries": [copy.deepcopy(BOX_SHELL)]}
    if semantics:
        geom["semantics"] = copy.deepcopy(BOX_SEMANTICS)
    doc = {
        "type": "CityJSON",
        "version": version,
        "transform": {"scale": [0.001, 0.001, 0.001], "translate": list(TRANSLATE)},
        "CityObjects": {"B1": {"type": "Building", "geometry": [geom]}},
        "vertices": copy.deepcopy(BOX_MM),
    }
    doc.update(extra)
    return doc


def write(tmp_path: Path, doc, name: str = "c.json") -> Path:
    path = tmp_path / name
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return path


def class_counts(model) -> tuple[int, int, int]:
    c = model.class_triangle_counts()
    return c["roof"], c["wall"], c["ground"]


# ---------------------------------------------------------------------------------------------- synthetic


def test_transform_semantics_and_world_coordinates(tmp_path):
    model = read_cityjson(write(tmp_path, box_doc()))
    assert class_counts(model) == (2, 8, 2)
    assert model.building_ids == ["B1"]
    assert model.lods_present() == [2]
    assert model.stats.classified_by_normal == 0
    world = model.to_world(model.bounds_local)
    np.testing.assert_allclose(world, [TRANSLATE, np.add(TRANSLATE, [4, 3, 5])], atol=1e-6)
    assert model.origin[2] == 0.0 and abs(model.origin[0] - 85002) <= 1  # float64 origin, small local
    assert np.abs(model.vertices).max() < 10
    areas = model.class_areas()
    assert np.isclose(areas["roof"], 12) and np.isclose(areas["ground"], 12) and np.isclose(areas["wall"], 70)


def test_no_transform_uses_vertices_as_they_are(tmp_path):
    doc = box_doc()
    del doc["transform"]
    doc["vertices"] = (np.asarray(BOX_MM) / 1000.0 + TRANSLATE).tolist()
    model = read_cityjson(write(tmp_path, doc))
    np.testing.assert_allclose(model.to_world(model.bounds_local)[0], TRANSLATE, atol=1e-6)


def test_semantics_absent_or_null_fall_back_to_normals(tmp_path):
    model = read_cityjson(write(tmp_path, box_doc(semantics=False)))
    assert class_counts(model) == (2, 8, 2)
    assert model.stats.classified_by_normal == 6
    doc = box_doc()
    # The roof has no value, one wall an unknown type: both classified from normals.
    doc["CityObjects"]["B1"]["geometry"][0]["semantics"] = {
        "surfaces": [{"type": "GroundSurface"}, {"type": "+FancySurface"}, {"type": "WallSurface"}],
        "values": [[0, None, 1, 2, 2, 2]],
    }
    mixed = read_cityjson(write(tmp_path, doc))
    assert class_counts(mixed) == (2, 8, 2)
    assert mixed.stats.classified_by_normal == 2
    assert any("+FancySurface 1" in w for w in mixed.stats.warnings)
    doc["CityObjects"]["B1"]["geometry"][0]["semantics"]["values"] = "abc"  # no list: said, not silent
    broken = read_cityjson(write(tmp_path, doc))
    assert class_counts(broken) == (2, 8, 2) and broken.stats.classified_by_normal == 6
    assert any("1 semantic values pointed to no surface" in w for w in broken.stats.warnings)


def test_semantic_class_wins_over_normal(tmp_path):
    """A roof polygon labelled WallSurface stays a wall: the file's semantics are not second-guessed."""
    doc = box_doc()
    doc["CityObjects"]["B1"]["geometry"][0]["semantics"]["values"] = [[0, 2, 2, 2, 2, 2]]
    assert class_counts(read_cityjson(write(tmp_path, doc))) == (0, 10, 2)


def test_multisurface_with_hole(tmp_path):
    # A 10 x 10 roof at z = 5 with a 2 x 3 courtyard hole.
    verts = [[0, 0, 5], [10, 0, 5], [10, 10, 5], [0, 10, 5], [2, 2, 5], [2, 5, 5], [4, 5, 5], [4, 2, 5]]
    doc = {
        "type": "CityJSON",
        "version": "1.1",
        "CityObjects": {
            "R": {
                "type": "Building",
                "geometry": [
                    {
                        "type": "MultiSurface",
                        "lod": "2",
                        "boundaries": [[[0, 1, 2, 3], [4, 5, 6, 7]]],
                        "semantics": {"surfaces": [{"type": "RoofSurface"}], "values": [0]},
                    }
                ],
            }
        },
        "vertices": verts,
    }
    model = read_cityjson(write(tmp_path, doc))
    assert np.isclose(model.class_areas()["roof"], 100 - 6)
    assert model.class_triangle_counts()["roof"] == model.num_triangles


def test_multisolid_nesting(tmp_path):
    doc = box_doc()
    geom = doc["CityObjects"]["B1"]["geometry"][0]
    geom["type"] = "MultiSolid"
    geom["boundaries"] = [geom["boundaries"], copy.deepcopy(geom["boundaries"])]
    geom["semantics"]["values"] = [[[0, 1, 2, 2, 2, 2]], [[2, 2, 2, 2, 2, 2]]]
    model = read_cityjson(write(tmp_path, doc))
    assert class_counts(model) == (2, 20, 2)  # the second solid is labelled all wall


def test_building_parts_and_installations_join_their_building(tmp_path):
    doc = box_doc()
    part = copy.deepcopy(doc["CityObjects"]["B1"])
    doc["CityObjects"] = {
        "B1": {"type": "Building", "geometry": [], "children": ["B1-p1", "B1-p2"]},
        "B1-p1": dict(part, type="BuildingPart", parents=["B1"]),
        "B1-p2": dict(part, type="BuildingPart", parent="B1"),  # CityJSON 0.8 spelling
        "B1-inst": dict(part, type="BuildingInstallation", parents=["B1-p1"]),
        "orphan": dict(part, type="BuildingPart"),
    }
    model = read_cityjson(write(tmp_path, doc))
    assert model.building_ids == ["B1", "orphan"]
    assert np.bincount(model.building_index).tolist() == [36, 12]


def test_non_buildings_and_extensions_are_skipped_and_counted(tmp_path):
    doc = box_doc()
    road = {"type": "Road", "geometry": [{"type": "MultiSurface", "lod": "1", "boundaries": [[[0, 1, 2]]]}]}
    doc["CityObjects"].update(
        {"r1": road, "r2": road, "t": {"type": "TINRelief", "geometry": []}, "x": dict(road, type="+Noise")}
    )
    model = read_cityjson(write(tmp_path, doc))
    assert model.building_ids == ["B1"] and model.num_triangles == 12
    warnings = " | ".join(model.stats.warnings)
    assert "skipped 3 non-building city objects: Road 2, TINRelief 1" in warnings
    assert "ignored 1 extension city objects: +Noise 1" in warnings


def test_bad_vertex_indices_skip_only_that_polygon(tmp_path):
    doc = box_doc()
    shell = doc["CityObjects"]["B1"]["geometry"][0]["boundaries"][0]
    shell[2] = [[0, 1, 999, 4]]  # out of range
    shell[3] = [[1, 2, 6, -3]]  # negative: must not wrap around to the end of the list
    shell[4] = [[2, 3, "7", 6]]  # not an integer
    shell[5] = [[3, 0, True, 7]]  # JSON true: numpy read it as vertex 1 (stop 45's audit)
    model = read_cityjson(write(tmp_path, doc))
    assert class_counts(model) == (2, 0, 2)  # roof, walls (the four gone), ground
    assert model.stats.polygons == 6
    assert any("skipped 4 polygons with invalid vertex indices" in w for w in model.stats.warnings)
    assert model.stats.malformed_polygons == 4 and model.summary()["skipped"]["malformed_polygons"] == 4


def test_only_bad_polygons_is_an_empty_model(tmp_path):
    doc = box_doc()
    doc["CityObjects"]["B1"]["geometry"][0]["boundaries"] = [[[[100, 101, 102]]]]
    with pytest.raises(EmptyModelError, match="invalid vertex indices"):
        read_cityjson(write(tmp_path, doc))


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf"), 1e300, 2e12])
def test_nan_infinite_and_absurd_vertices_drop_their_polygons_with_a_counted_warning(tmp_path, bad):
    """A NaN / infinite / absurd vertex (beyond 1e9 m) drops the 3 polygons that use it, counted apart
    from bad indices; a GeometryInstance whose matrix is corrupt likewise: no numpy warning escapes."""
    doc = box_doc()
    doc["vertices"][0] = [bad, 0, 0]
    template = copy.deepcopy(box_doc()["CityObjects"]["B1"]["geometry"][0])
    doc["geometry-templates"] = {"templates": [template], "vertices-templates": BOX_MM}
    matrix = [1, 0, 0, bad, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]  # moves x by ``bad``
    instance = {"type": "GeometryInstance", "template": 0, "boundaries": [1], "transformationMatrix": matrix}
    doc["CityObjects"]["B2"] = {"type": "Building", "geometry": [instance]}
    overflow = {**instance, "transformationMatrix": [1e308, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]}
    doc["CityObjects"]["B3"] = {"type": "Building", "geometry": [overflow]}  # x * 1e308: only x = 0 is left
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = read_cityjson(write(tmp_path, doc))
    assert model.stats.invalid_coordinate_polygons == 3 + 6 + 5
    assert any(
        "skipped 14 polygons with coordinates that are NaN, infinite" in w for w in model.stats.warnings
    )
    assert not any("invalid vertex indices" in w for w in model.stats.warnings)
    assert model.num_triangles == 6 + 2 and abs(model.origin[0] - 85002) <= 1
    doc = box_doc()
    doc["vertices"] = [[bad, bad, bad]] * len(BOX_MM)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(EmptyModelError, match="6 polygons with coordinates that are NaN, infinite"):
            read_cityjson(write(tmp_path, doc))


def test_lod_selection_synthetic(tmp_path):
    doc = box_doc()
    b1 = doc["CityObjects"]["B1"]
    lod1 = {"type": "Solid", "lod": "1.2", "boundaries": copy.deepcopy(b1["geometry"][0]["boundaries"])}
    lod1["boundaries"][0] = lod1["boundaries"][0][:5]  # 10 triangles instead of 12
    b1["geometry"].insert(0, lod1)
    path = write(tmp_path, doc)
    assert read_cityjson(path).num_triangles == 12
    assert read_cityjson(path, lod=2).num_triangles == 12
    assert read_cityjson(path, lod=1).num_triangles == 10
    assert read_cityjson(path, lod="1.2").lods_present() == [1]
    assert read_cityjson(path, lod=1.2).num_triangles == 10
    with pytest.raises(EmptyModelError, match=r"LoDs present: 1\.2, 2"):
        read_cityjson(path, lod="1.3")
    with pytest.raises(EmptyModelError, match="LoDs present"):
        read_cityjson(path, lod="high")


def test_numeric_lods_of_cityjson_1_0(tmp_path):
    doc = box_doc(version="1.0", lod=2.2)
    doc["CityObjects"]["B1"]["geometry"].append(dict(doc["CityObjects"]["B1"]["geometry"][0], lod=1))
    path = write(tmp_path, doc)
    assert read_cityjson(path, lod="2.2").num_triangles == 12
    assert read_cityjson(path, lod=1).lods_present() == [1]
    values = (2, 2.0, 2.2, "2.2", " 1.3 ", "2.0", "2.20", 0, True, "x", None, 1e300, 5, -1)
    assert [lod_key(v) for v in values] == ["2", "2", "2.2", "2.2", "1.3", "2", "2.2", "0"] + [None] * 6


def test_redundant_geometries_of_one_lod_are_meshed_once(tmp_path):
    doc = box_doc()
    geoms = doc["CityObjects"]["B1"]["geometry"]
    plain = {"type": "MultiSurface", "lod": "2", "boundaries": copy.deepcopy(BOX_SHELL)}
    geoms.insert(0, plain)  # the same surfaces again, without semantics
    model = read_cityjson(write(tmp_path, doc))
    assert model.num_triangles == 12 and model.stats.classified_by_normal == 0
    assert any("redundant" in w for w in model.stats.warnings)


def test_geometry_instance_is_placed_by_matrix_and_reference_point(tmp_path):
    doc = box_doc()
    doc["geometry-templates"] = {
        "templates": [{"type": "Solid", "lod": "2", "boundaries": [copy.deepcopy(BOX_SHELL)]}],
        "vertices-templates": (np.asarray(BOX_MM) / 1000.0).tolist(),
    }
    doc["vertices"].append([100000, 0, 0])  # reference point 100 m east of the box
    matrix = np.eye(4)
    matrix[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # 90 deg about z
    doc["CityObjects"]["T"] = {
        "type": "BuildingInstallation",
        "geometry": [
            {
                "type": "GeometryInstance",
                "template": 0,
                "boundaries": [8],
                "transformationMatrix": matrix.ravel().tolist(),
            }
        ],
    }
    model = read_cityjson(write(tmp_path, doc))
    inst = model.building_index == model.building_ids.index("T")
    world = model.to_world(model.triangle_corners()[inst]).reshape(-1, 3)
    np.testing.assert_allclose(world.min(0), np.add(TRANSLATE, [97, 0, 0]), atol=1e-6)
    np.testing.assert_allclose(world.max(0), np.add(TRANSLATE, [100, 4, 5]), atol=1e-6)
    assert class_counts(model) == (4, 16, 4)  # the template has no semantics: classified by normals


def test_crs_from_file_override_and_geographic(tmp_path):
    url = box_doc(metadata={"referenceSystem": "https://www.opengis.net/def/crs/EPSG/0/7415"})
    model = read_cityjson(write(tmp_path, url))
    assert crs_label(model.crs) == "EPSG:7415" and not any(
        "referenceSystem" in w for w in model.stats.warnings
    )
    urn = box_doc(version="1.0", metadata={"referenceSystem": "urn:ogc:def:crs:EPSG::28992"})
    assert read_cityjson(write(tmp_path, urn)).crs.to_epsg() == 28992
    old = box_doc(version="0.9", metadata={"crs": {"epsg": 28992}})
    assert read_cityjson(write(tmp_path, old)).crs.to_epsg() == 28992
    bare = box_doc(version="1.0", metadata={"referenceSystem": 28992})  # was "no referenceSystem"
    assert read_cityjson(write(tmp_path, bare)).crs.to_epsg() == 28992
    assert read_cityjson(write(tmp_path, url), crs_override="EPSG:28992").crs.to_epsg() == 28992

    none = read_cityjson(write(tmp_path, box_doc()))
    assert none.crs is None and any("no referenceSystem" in w for w in none.stats.warnings)
    with pytest.raises(CRSError, match="names no CRS"):
        read_cityjson(write(tmp_path, box_doc()), target_crs="EPSG:25832")
    with pytest.raises(CRSError):
        read_cityjson(write(tmp_path, box_doc(metadata={"referenceSystem": "EPSG:nonsense"})))

    # Geographic (EPSG:4326, latitude first): projected to its UTM zone, metric sizes.
    geo = box_doc(metadata={"referenceSystem": "https://www.opengis.net/def/crs/EPSG/0/4326"})
    geo["transform"] = {"scale": [1e-7, 1e-7, 0.001], "translate": [52.0, 4.35, 0.0]}
    geo["vertices"] = [[y, x, z] for x, y, z in BOX_MM]  # 0.0004 deg of longitude x 0.0003 deg of latitude
    model = read_cityjson(write(tmp_path, geo))
    assert model.crs.to_epsg() == 32631 and model.source_crs.to_epsg() == 4326
    dx, dy, dz = model.extent_m
    assert abs(dx - 0.0004 * 111320 * np.cos(np.radians(52))) < 1.0 and abs(dy - 0.0003 * 111250) < 1.0
    assert np.isclose(dz, 5.0) and class_counts(model) == (2, 8, 2)


@pytest.mark.parametrize(
    ("content", "error", "message"),
    [
        ("{not json", MalformedCityJSONError, "not valid JSON"),
        ("[1, 2]", MalformedCityJSONError, "top level is a JSON list"),
        ({"type": "FeatureCollection", "features": []}, UnsupportedFormatError, "not 'CityJSON'"),
        ({"type": "CityJSONFeature", "CityObjects": {}}, UnsupportedFormatError, "CityJSONSeq"),
        (dict(box_doc(), version="3.0"), UnsupportedFormatError, "version '3.0' is not supported"),
        (dict(box_doc(), version=None), UnsupportedFormatError, "version None"),
        (dict(box_doc(), CityObjects=[]), MalformedCityJSONError, "CityObjects"),
        (dict(box_doc(), vertices=[[1, 2], [3, 4]]), MalformedCityJSONError, "shape"),
        (dict(box_doc(), vertices=[[1, 2, "x"]]), MalformedCityJSONError, "vertices"),
        (dict(box_doc(), transform={"scale": [1, 1]}), MalformedCityJSONError, "transform"),
        (dict(box_doc(), CityObjects={}), EmptyModelError, "no building surfaces"),
    ],
)
def test_bad_input_raises_typed_errors(tmp_path, content, error, message):
    with pytest.raises(error, match=message):
        read_cityjson(write(tmp_path, content))


def test_a_geographic_crs_for_metre_coordinates_is_refused_naming_it(tmp_path):
    """``--crs EPSG:4326`` for a file in RD metres: the CRS is named as the fault, not the file's
    polygons (all dropped as absurd before)."""
    path = write(tmp_path, box_doc())
    with pytest.raises(
        CRSError, match=r"\(85000\.0, 447000\.0\) are no degrees.*\(given as crs='EPSG:4326'\)"
    ):
        read_cityjson(path, crs_override="EPSG:4326")
    meta = {"referenceSystem": "https://www.opengis.net/def/crs/EPSG/0/4326"}
    with pytest.raises(CRSError, match="the file's referenceSystem"):
        read_cityjson(write(tmp_path, box_doc(metadata=meta), "wrong.json"))


def test_a_crs_override_that_moves_the_files_coordinates_is_said(tmp_path):
    meta = {"referenceSystem": "https://www.opengis.net/def/crs/EPSG/0/7415"}
    path = write(tmp_path, box_doc(metadata=meta))
    moved = read_cityjson(path, crs_override="EPSG:32631")
    assert any("crs='EPSG:32631' overrides the CRS the file states" in w for w in moved.stats.warnings)
    assert not any("overrides" in w for w in read_cityjson(path, crs_override="EPSG:28992").stats.warnings)


def test_missing_file_and_gzip(tmp_path):
    with pytest.raises(InputFileError, match="cannot read"):
        read_cityjson(tmp_path / "missing.json")
    gz = tmp_path / "c.json.gz"
    gz.write_bytes(gzip.compress(json.dumps(box_doc()).encode()))
    assert read_cityjson(gz).num_triangles == 12
    broken = tmp_path / "b.json.gz"
    broken.write_bytes(gzip.compress(b"{}")[:-6])
    with pytest.raises(MalformedCityJSONError):
        read_cityjson(broken)


def test_malformed_geometry_parts_are_counted(tmp_path):
    doc = box_doc()
    b1 = doc["CityObjects"]["B1"]
    b1["geometry"].append("not a geometry")
    b1["geometry"][0]["boundaries"][0].append(17)  # a surface that is not a list of rings
    doc["CityObjects"]["junk"] = 5
    model = read_cityjson(write(tmp_path, doc))
    assert model.num_triangles == 12
    assert any("1 malformed city objects" in w for w in model.stats.warnings)


# ---------------------------------------------------------------------------------------------- real files


@functools.cache
def _read(path: str, lod=None):
    return read_cityjson(path, lod=lod)


def test_real_multi_lod(shared):
    path = str(shared("cityjson_nl/multi_lod.json"))
    counts = {lod: _read(path, lod).num_triangles for lod in ("1.2", "1.3", "2.2")}
    assert len(set(counts.values())) == 3, counts
    best = _read(path)
    assert best.num_triangles == counts["2.2"] and best.lods_present() == [2]
    assert _read(path, 2).num_triangles == counts["2.2"]
    assert _read(path, 1).num_triangles == counts["1.3"]  # the highest of the LoD 1 family
    for model in (best, _read(path, "1.2")):
        assert model.num_buildings == 10
        roof, wall, ground = class_counts(model)
        assert roof > 0 and wall > 0 and ground > 0
    assert best.stats.classified_by_normal == 0  # 2.2 has semantics; 1.2 / 1.3 do not
    assert _read(path, "1.2").stats.classified_by_normal > 0
    assert best.crs is None and any("no referenceSystem" in w for w in best.stats.warnings)
    with pytest.raises(EmptyModelError, match=r"LoDs present: 1\.2, 1\.3, 2\.2"):
        read_cityjson(path, lod=3)


def wall_footprint_area(model) -> np.ndarray:
    """Footprint per building from its walls alone (divergence theorem: the x-flux through the walls of
    a vertical prism with flat roof and base is footprint * height); independent of the roof faces."""
    c = model.triangle_corners()
    n = 0.5 * np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    b, nb = model.building_index, len(model.building_ids)
    wall = model.classes == SemanticClass.WALL
    x_lo = np.full(nb, np.inf)
    np.minimum.at(x_lo, b, c[:, :, 0].min(1))
    z_lo, z_hi = np.full(nb, np.inf), np.full(nb, -np.inf)
    np.minimum.at(z_lo, b, c[:, :, 2].min(1))
    np.maximum.at(z_hi, b, c[:, :, 2].max(1))
    flux = np.bincount(b[wall], weights=(c[wall][:, :, 0].mean(1) - x_lo[b[wall]]) * n[wall, 0], minlength=nb)
    return flux / (z_hi - z_lo)


def test_real_delft_without_semantics(shared):
    model = _read(str(shared("cityjson_nl/delft.json")))
    assert model.num_buildings == 160
    assert crs_label(model.crs) == "EPSG:7415"
    assert model.stats.classified_by_normal == model.stats.polygons > 0
    assert any("skipped 410 non-building city objects" in w and "Road 143" in w for w in model.stats.warnings)
    areas = model.class_areas()
    assert areas["roof"] > 1000 and areas["wall"] > 1000
    # The LoD1 solids of this file have no bottom surface, so there is no ground to compare with:
    # compare the roof area with the footprint measured from the walls (flat LoD1 blocks).
    assert areas["ground"] == 0
    footprint = wall_footprint_area(model).sum()
    assert abs(areas["roof"] - footprint) < 0.2 * footprint
    assert abs(areas["roof"] - footprint) < 0.01 * footprint  # in fact exact for these prisms


def test_real_rotterdam_subset(shared):
    model = _read(str(shared("cityjson_nl/rotterdam_subset.json")))
    assert model.num_buildings == 16
    assert model.stats.classified_by_normal == 0
    roof, wall, ground = class_counts(model)
    assert roof > 0 and wall > 0 and ground > 0
    assert model.lods_present() == [2]
    # Semantic roofs face up, semantic grounds face down.
    nz = model.triangle_normals()[:, 2]
    assert (nz[model.classes == SemanticClass.ROOF] > 0).mean() > 0.99
    assert (nz[model.classes == SemanticClass.GROUND] < 0).mean() > 0.99


@pytest.fixture(scope="module")
def denhaag_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("denhaag")


def _denhaag_file(shared, directory: Path, suffix: str) -> Path:
    archive = shared("denhaag_lod2/DenHaag_01.zip")
    with zipfile.ZipFile(archive) as zf:
        name = next(n for n in zf.namelist() if n.endswith(suffix) and "__MACOSX" not in n)
        target = directory / name
        if not target.exists():
            zf.extract(name, directory)
    return target


def test_real_denhaag_cityjson_0_8(shared, denhaag_dir):
    path = _denhaag_file(shared, denhaag_dir, ".json")
    model = _read(str(path))
    assert model.num_buildings == 844  # 1653 BuildingParts joined to their 844 Buildings
    assert not any(b.endswith(("_1", "_2")) for b in model.building_ids)
    assert any("TINRelief 1" in w for w in model.stats.warnings)
    areas = model.class_areas()
    assert areas["roof"] > 0 and areas["wall"] > 0 and areas["ground"] > 0
    assert model.stats.classified_by_normal == 0


@pytest.mark.skipif(
    importlib.util.find_spec("semcityloc.citymodel.citygml") is None,
    reason="semcityloc.citymodel.citygml (the CityGML reader) does not exist yet",
)
def test_real_denhaag_cityjson_matches_citygml(shared, denhaag_dir):
    from semcityloc.citymodel.citygml import read_citygml

    cj = _read(str(_denhaag_file(shared, denhaag_dir, ".json")))
    gml = read_citygml(_denhaag_file(shared, denhaag_dir, ".xml"))
    assert gml.num_buildings == cj.num_buildings
    roof_cj, roof_gml = cj.class_areas()["roof"], gml.class_areas()["roof"]
    assert abs(roof_cj - roof_gml) < 0.01 * roof_gml

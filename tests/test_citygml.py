"""CityGML reader: real city models (Berlin, Fürth, Den Haag, PLATEAU, Lyon, FZK-Haus) and small inline files
for each structural case (XLinks, holes, parts, orientation, coordinate encodings, CRS, errors)."""

from __future__ import annotations

import functools
import gzip
import re
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pyproj
import pytest

from semcityloc.citymodel.builder import MeshBuilder
from semcityloc.citymodel.citygml import CityGMLReader, iter_citygml_polygons, read_citygml
from semcityloc.citymodel.crs import (
    check_projected,
    horizontal_crs,
    metric_crs,
    parse_crs_name,
    same_crs,
    same_horizontal_crs,
    vertical_datum,
)
from semcityloc.citymodel.io import load_city_model
from semcityloc.citymodel.model import CityModel, crs_label
from semcityloc.citymodel.triangulate import polygon_area, triangulate_polygon
from semcityloc.classes import SemanticClass
from semcityloc.errors import (
    CRSError,
    EmptyModelError,
    InputFileError,
    MalformedXMLError,
    ParameterError,
    UnsupportedFormatError,
    as_flags,
)

BERLIN = "berlin_lod2_citygml2/3910_5817.gml"
FUERTH = "fuerth_lod2_citygml1/LOD2_4424_5482_solid.gml"
DENHAAG_ZIP = "denhaag_lod2/DenHaag_01.zip"
FZK = "lod3_fzk_haus/FZK-Haus-LoD3-KIT-IAI-KHH-B36-V1.gml"
PLATEAU2 = "citygml3/53394517_bldg_6697_2_op_CityGML2.gml"
PLATEAU3 = "citygml3/53394517_bldg_6697_2_op_CityGML3.gml"
LYON = "citygml3/Opera-Lyon_CityGML3.0_LOD2_with_xAL3_FreeText.gml"


@functools.cache
def _read(path: Path, lod: int | None = None) -> tuple[CityModel, CityGMLReader]:
    """Each real file is parsed once per test session (the models are not modified by the tests)."""
    reader = CityGMLReader(path, lod)
    builder = MeshBuilder(reader.stats)
    for p in reader.polygons():
        builder.add_polygon(p.exterior, p.interiors, p.semantic, p.building_id, p.lod)
    return builder.build(reader.crs, reader.source_crs, str(path)), reader


def _class_area(model: CityModel, cls: SemanticClass) -> float:
    return float(model.triangle_areas()[model.classes == cls].sum())


# ---------------------------------------------------------------------------------------------- real data
def test_berlin_buildings_classes_extent_crs(shared):
    model, reader = _read(shared(BERLIN))
    assert len(model.building_ids) == 166  # 15 BuildingParts are merged into their building
    assert model.num_buildings == 166
    assert reader.report.building_parts == 15
    assert reader.report.version == "2.0"
    counts = model.class_triangle_counts()
    assert counts["roof"] > 0 and counts["wall"] > 0 and counts["ground"] > 0
    assert counts["window"] == counts["door"] == 0
    np.testing.assert_allclose(model.extent_m, [984.0, 334.0, 74.0], rtol=0.01)
    assert crs_label(model.crs) == "EPSG:25833" and crs_label(model.source_crs) == "EPSG:25833"
    assert model.lods_present() == [2]
    # 3080 gml:Polygons in the file, 622 of them also referenced by lod2Solid members: each meshed once.
    assert reader.report.polygons == 3080
    assert reader.report.lod_polygons == {2: 3080}
    assert reader.report.duplicate_polygons == 622
    assert model.stats.unresolved_xlinks == 0
    assert model.stats.classified_by_normal == 0  # every polygon has a boundary-surface class
    # float64 origin near the data, float32 vertices small
    assert 380_000 < model.origin[0] < 400_000 and 5_810_000 < model.origin[1] < 5_820_000
    assert np.abs(model.vertices).max() < 1000


def test_berlin_every_polygon_triangulates_to_its_area(shared):
    # The triangles, projected on the polygon's plane, cover the polygon exactly once. (Their 3D area is
    # larger for the slightly non-planar polygons, up to 1.7 cm off-plane in Berlin, so it is not compared.)
    n = 0
    for p in iter_citygml_polygons(shared(BERLIN)):
        tri = triangulate_polygon(p.exterior, p.interiors)
        assert tri is not None
        c = tri.points[tri.triangles]
        projected = 0.5 * float((np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]) @ tri.normal).sum())
        assert projected == pytest.approx(polygon_area(p.exterior, p.interiors), rel=1e-6)
        n += 1
    assert n == 3080


def test_fuerth_citygml1(shared):
    model, reader = _read(shared(FUERTH))
    assert reader.report.version == "1.0"
    assert model.num_buildings == 111
    assert crs_label(model.crs) == "EPSG:31468+5783"  # the srsName's "*DE_DHN92_NH": DHHN92 heights
    assert reader.report.polygons == 1056 and reader.report.duplicate_polygons == 1056
    np.testing.assert_allclose(model.extent_m, [204.0, 199.0, 20.0], rtol=0.01)
    assert all(a > 0 for k, a in model.class_areas().items() if k in ("roof", "wall", "ground"))


def test_denhaag_citygml1(shared, tmp_path):
    with zipfile.ZipFile(shared(DENHAAG_ZIP)) as z:
        z.extract("DenHaag/DenHaag_01.xml", tmp_path)
    model, reader = _read(tmp_path / "DenHaag" / "DenHaag_01.xml")
    assert model.num_buildings == 844
    assert reader.report.building_parts == 1653
    assert reader.report.skipped_objects == {"ReliefFeature": 1}
    assert any("ReliefFeature" in w for w in model.stats.warnings)
    assert crs_label(model.crs) == "EPSG:28992"
    assert model.stats.unresolved_xlinks == 0
    # Cross-check numbers for the CityJSON twin of this file (measured: 94442.66 m2 of roof).
    assert _class_area(model, SemanticClass.ROOF) == pytest.approx(94442.66, rel=1e-3)
    assert reader.report.polygons == 16209


def test_plateau_citygml2_and_3_give_the_same_mesh(shared):
    m2, r2 = _read(shared(PLATEAU2))
    m3, r3 = _read(shared(PLATEAU3))
    assert (r2.report.version, r3.report.version) == ("2.0", "3.0")
    # lod0RoofEdge (2.0) / lod0MultiSurface (3.0), a lod1Solid and the LoD2 boundary surfaces, in both
    assert r2.report.lod_polygons == r3.report.lod_polygons == {0: 1, 1: 134, 2: 650}
    a2, a3 = m2.class_areas(), m3.class_areas()
    for cls in ("roof", "wall", "ground"):
        assert a2[cls] > 0
        assert a3[cls] == pytest.approx(a2[cls], rel=1e-3)
    for m in (m2, m3):
        # latitude-first EPSG:6697 projected to UTM 54N, its JGD2011 height system kept (since stop 52)
        assert crs_label(m.crs) == "EPSG:32654+6695"
        assert crs_label(m.source_crs) == "EPSG:6697"
        assert m.lods_present() == [2]
        ext = m.extent_m
        assert 50 < ext[0] < 500 and 30 < ext[1] < 500 and 10 < ext[2] < 100  # metres, not degrees
        # 139.7 E, 35.7 N in UTM 54N: easting ~ 383 km, northing ~ 3949 km
        assert 370_000 < m.origin[0] < 400_000 and 3_930_000 < m.origin[1] < 3_970_000
    np.testing.assert_allclose(m2.extent_m, m3.extent_m, rtol=1e-6)


def test_plateau_lod_selection(shared):
    path = shared(PLATEAU3)
    lod1, _ = _read(path, 1)
    assert lod1.lods_present() == [1]
    assert lod1.stats.classified_by_normal == 134  # the lod1Solid has no semantics: classified by normals
    counts = lod1.class_triangle_counts()
    assert counts["roof"] > 0 and counts["wall"] > 0 and counts["ground"] > 0
    lod0, _ = _read(path, 0)
    assert lod0.lods_present() == [0]
    best, _ = _read(path)
    assert best.lods_present() == [2]
    with pytest.raises(EmptyModelError, match="LoDs present: 0, 1, 2"):
        read_citygml(path, lod=3)


def test_opera_lyon_citygml3(shared):
    model, reader = _read(shared(LYON))
    assert reader.report.version == "3.0"
    assert crs_label(model.crs) == "EPSG:3946"
    counts = model.class_triangle_counts()
    assert counts["roof"] > 0 and counts["wall"] > 0 and counts["ground"] > 0
    assert model.num_buildings == 1


def test_fzk_haus_lod3_openings(shared):
    path = shared(FZK)
    model, reader = _read(path)
    assert reader.report.openings == {"Window": 11, "Door": 2}
    counts = model.class_triangle_counts()
    assert counts["window"] > 0 and counts["door"] > 0
    assert model.lods_present() == [3]
    assert crs_label(model.crs) == "EPSG:5555"  # ETRS89 / UTM 32N + DHHN92 height (AdV "*DE_DHHN92_NH")
    assert model.stats.unresolved_xlinks == 0
    # The lod3Solid points at wall composites and opening polygons: all already in boundary surfaces.
    assert reader.report.polygons == 210
    # The walls have holes where the openings are: filled walls - walls = openings.
    polys = list(iter_citygml_polygons(path))
    filled = sum(polygon_area(p.exterior) for p in polys if p.semantic == SemanticClass.WALL)
    walls = _class_area(model, SemanticClass.WALL)
    openings = _class_area(model, SemanticClass.WINDOW) + _class_area(model, SemanticClass.DOOR)
    assert walls < filled
    assert filled - walls == pytest.approx(openings, rel=0.01)
    # The file's 13 openings, polygon by polygon: 9 windows of 2.0 x 1.2 m (21.6 m2), 2 round gable windows
    # 1 m across (0.784 m2 each), a door of 1.01 x 2.01 m (2.030 m2) and one of 2.01 x 2.375 m (4.774 m2).
    written = [p for p in polys if p.semantic in (SemanticClass.WINDOW, SemanticClass.DOOR)]
    assert len(written) == 13
    by_polygon = sum(polygon_area(p.exterior, p.interiors) for p in written)
    assert openings == pytest.approx(by_polygon, rel=1e-5)  # triangles vs rings: float32 vertices
    assert openings == pytest.approx(9 * 2.0 * 1.2 + 2 * 0.7844 + 1.01 * 2.01 + 4.7738, abs=0.01)


def test_fzk_haus_has_no_lod2(shared):
    with pytest.raises(EmptyModelError, match="no LoD 2 .*LoDs present: 3"):
        read_citygml(shared(FZK), lod=2)


def test_every_srsname_in_the_data_parses(shared):
    expected = {
        BERLIN: "EPSG:25833",
        FUERTH: "EPSG:31468+5783",
        FZK: "EPSG:5555",
        PLATEAU2: "EPSG:6697",
        PLATEAU3: "EPSG:6697",
        LYON: "EPSG:3946",
    }
    for rel, label in expected.items():
        _, reader = _read(shared(rel))
        assert reader.report.srs_names, rel
        for name in reader.report.srs_names:
            assert crs_label(parse_crs_name(name)) == label, name


# ---------------------------------------------------------------------------------------------- CRS names
@pytest.mark.parametrize(
    ("name", "epsg"),
    [
        ("urn:ogc:def:crs:EPSG::25833", 25833),
        ("urn:adv:crs:ETRS89_UTM32*DE_DHHN92_NH", 25832),
        ("urn:adv:crs:DE_DHDN_3GK4*DE_DHN92_NH", 31468),
        ("http://www.opengis.net/def/crs/EPSG/0/6697", 6697),
        ("urn:ogc:def:crs:EPSG::28992", 28992),
        ("EPSG:3946", 3946),
    ],
)
def test_parse_crs_name_forms(name, epsg):
    crs = parse_crs_name(name)
    assert epsg in (crs.to_epsg(), horizontal_crs(crs).to_epsg())  # an AdV name's height: a compound


@pytest.mark.parametrize(
    ("name", "vertical"),
    [
        ("urn:adv:crs:ETRS89_UTM32*DE_DHHN92_NH", 5783),
        ("urn:adv:crs:DE_DHDN_3GK4*DE_DHN92_NH", 5783),  # Bavaria's spelling
        ("urn:adv:crs:ETRS89_UTM33*DE_DHHN2016_NH", 7837),
        ("urn:adv:crs:ETRS89_UTM33*DE_SOMETHING_ELSE", None),
        ("urn:adv:crs:ETRS89_UTM33", None),
    ],
)
def test_an_adv_height_system_is_kept_as_a_compound_crs(name, vertical):
    """The height system after an AdV name's "*" was dropped, so a DJI photo's GNSS height was taken for
    the model's without a geoid and the run said the model "names no vertical datum"; a known one makes a
    compound CRS now, an unknown one leaves the horizontal CRS."""
    crs = parse_crs_name(name)
    found = vertical_datum(crs)
    assert (found.to_epsg() if found is not None else None) == vertical


def test_parse_compound_crs_name():
    crs = parse_crs_name("urn:ogc:def:crs,crs:EPSG::25832,crs:EPSG::5783")
    assert crs.is_compound
    assert [c.to_epsg() for c in crs.sub_crs_list] == [25832, 5783]


def test_one_rule_for_same_crs_and_for_a_metric_crs():
    """``crs.same_crs`` / ``same_horizontal_crs`` / ``check_projected`` / ``metric_crs``: the one answer to
    "same CRS?" (a CityGML file's srsNames, a store's ``--crs``, a pose file's) and to "metric?" (OBJ, the
    generated city, a DJI prior's target)."""
    assert same_crs("EPSG:25833", "urn:ogc:def:crs:EPSG::25833")  # spellings differ
    assert not same_crs("EPSG:25833", "EPSG:25832")
    assert not same_crs("EPSG:4326", "OGC:CRS84")  # latitude first or not: the file's numbers differ
    assert same_crs("EPSG:4326", "OGC:CRS84", ignore_axis_order=True)
    assert not same_crs("EPSG:25832", "EPSG:25832+5783")  # the height system counts
    assert same_horizontal_crs("EPSG:25832", "urn:ogc:def:crs,crs:EPSG::25832,crs:EPSG::5783")
    assert check_projected("EPSG:25832+5783", "x").to_epsg() == 25832  # the horizontal part
    assert metric_crs("EPSG:25832+5783", "x").is_compound  # whole
    for name, kind in (("EPSG:4326", "geographic"), ("EPSG:4978", "geocentric")):
        message = rf"^the thing must be metric \(projected\), got .* \({kind}\); give"
        with pytest.raises(CRSError, match=message):
            check_projected(name, "the thing")
        with pytest.raises(CRSError, match=kind):
            metric_crs(name, "the thing")


@pytest.mark.parametrize(
    "name", ["urn:adv:crs:NOT_A_CRS", "totally-unknown-crs", "urn:ogc:def:crs:EPSG::999999"]
)
def test_parse_crs_name_unknown(name):
    with pytest.raises(CRSError, match=name.replace("*", r"\*")):
        parse_crs_name(name)


# ---------------------------------------------------------------------------------------------- inline files
NS = {
    "2.0": (
        'xmlns="http://www.opengis.net/citygml/2.0" xmlns:bldg="http://www.opengis.net/citygml/building/2.0" '
        'xmlns:gml="http://www.opengis.net/gml" xmlns:xlink="http://www.w3.org/1999/xlink"'
    ),
    "1.0": (
        'xmlns="http://www.opengis.net/citygml/1.0" xmlns:bldg="http://www.opengis.net/citygml/building/1.0" '
        'xmlns:gml="http://www.opengis.net/gml" xmlns:xlink="http://www.w3.org/1999/xlink"'
    ),
    "3.0": (
        'xmlns="http://www.opengis.net/citygml/3.0" xmlns:bldg="http://www.opengis.net/citygml/building/3.0" '
        'xmlns:con="http://www.opengis.net/citygml/construction/3.0" '
        'xmlns:gml="http://www.opengis.net/gml/3.2" xmlns:xlink="http://www.w3.org/1999/xlink"'
    ),
}
X0, Y0 = 391_000.0, 5_817_000.0  # Berlin-like UTM coordinates: the float64 origin matters


def _poslist(points) -> str:
    return " ".join(f"{x:.3f} {y:.3f} {z:.3f}" for x, y, z in [*points, points[0]])


def _polygon(points, pid=None, holes=(), encoding="posList") -> str:
    def ring(pts):
        if encoding == "posList":
            return f"<gml:LinearRing><gml:posList>{_poslist(pts)}</gml:posList></gml:LinearRing>"
        if encoding == "pos":
            closed = [*pts, pts[0]]
            return (
                "<gml:LinearRing>"
                + "".join(f"<gml:pos>{x} {y} {z}</gml:pos>" for x, y, z in closed)
                + ("</gml:LinearRing>")
            )
        closed = [*pts, pts[0]]
        return (
            "<gml:LinearRing><gml:coordinates>"
            + " ".join(f"{x},{y},{z}" for x, y, z in closed)
            + "</gml:coordinates></gml:LinearRing>"
        )

    ident = f' gml:id="{pid}"' if pid else ""
    inner = "".join(f"<gml:interior>{ring(h)}</gml:interior>" for h in holes)
    return f"<gml:Polygon{ident}><gml:exterior>{ring(points)}</gml:exterior>{inner}</gml:Polygon>"


def _box_faces(x0, y0, w, d, h, z0=0.0):
    """Outward-oriented faces of a box: (name, points)."""
    x1, y1, z1 = x0 + w, y0 + d, z0 + h
    return [
        ("GroundSurface", [(x0, y0, z0), (x0, y1, z0), (x1, y1, z0), (x1, y0, z0)]),
        ("RoofSurface", [(x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)]),
        ("WallSurface", [(x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1)]),
        ("WallSurface", [(x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1)]),
        ("WallSurface", [(x1, y1, z0), (x0, y1, z0), (x0, y1, z1), (x1, y1, z1)]),
        ("WallSurface", [(x0, y1, z0), (x0, y0, z0), (x0, y0, z1), (x0, y1, z1)]),
    ]


def _bounded_box(prefix, x0, y0, w=10.0, d=8.0, h=6.0, lod=2, encoding="posList", version="2.0") -> str:
    """Boundary surfaces of a box, polygon ids ``{prefix}_0`` .. ``{prefix}_5``."""
    prop, surf = ("boundary", "con:") if version == "3.0" else ("bldg:boundedBy", "bldg:")
    out = []
    for i, (name, pts) in enumerate(_box_faces(x0, y0, w, d, h)):
        ms = f"<gml:MultiSurface><gml:surfaceMember>{_polygon(pts, f'{prefix}_{i}', encoding=encoding)}"
        ms += "</gml:surfaceMember></gml:MultiSurface>"
        tag = f"{surf}{name}"
        lodprop = f"lod{lod}MultiSurface" if version == "3.0" else f"bldg:lod{lod}MultiSurface"
        out.append(f"<{prop}><{tag}><{lodprop}>{ms}</{lodprop}></{tag}></{prop}>")
    return "".join(out)


def _solid_refs(ids, lod=2, version="2.0") -> str:
    members = "".join(f'<gml:surfaceMember xlink:href="#{i}"/>' for i in ids)
    shell = "gml:Shell" if version == "3.0" else "gml:CompositeSurface"
    prop = f"lod{lod}Solid" if version == "3.0" else f"bldg:lod{lod}Solid"
    return (
        f"<{prop}><gml:Solid><gml:exterior><{shell}>{members}</{shell}></gml:exterior></gml:Solid></{prop}>"
    )


def _solid_inline(x0, y0, w=10.0, d=8.0, h=6.0, lod=1, orientation=None) -> str:
    members = []
    for _, pts in _box_faces(x0, y0, w, d, h):
        poly = _polygon(pts)
        if orientation:
            poly = (
                f'<gml:OrientableSurface orientation="{orientation}"><gml:baseSurface>{poly}'
                "</gml:baseSurface></gml:OrientableSurface>"
            )
        members.append(f"<gml:surfaceMember>{poly}</gml:surfaceMember>")
    return (
        f"<bldg:lod{lod}Solid><gml:Solid><gml:exterior><gml:CompositeSurface>{''.join(members)}"
        f"</gml:CompositeSurface></gml:exterior></gml:Solid></bldg:lod{lod}Solid>"
    )


def _building(bid, body, version="2.0") -> str:
    return f'<cityObjectMember><bldg:Building gml:id="{bid}">{body}</bldg:Building></cityObjectMember>'


def _city(members, version="2.0", srs="urn:ogc:def:crs:EPSG::25833", root="CityModel") -> str:
    env = ""
    if srs:
        env = (
            f'<gml:boundedBy><gml:Envelope srsName="{srs}" srsDimension="3">'
            f"<gml:lowerCorner>{X0} {Y0} 0</gml:lowerCorner><gml:upperCorner>{X0 + 100} {Y0 + 100} 50"
            "</gml:upperCorner></gml:Envelope></gml:boundedBy>"
        )
    return f'<?xml version="1.0" encoding="UTF-8"?>\n<{root} {NS[version]}>{env}{"".join(members)}</{root}>\n'


def _write(tmp_path, text, name="city.gml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _model_and_report(path, **kw):
    reader = CityGMLReader(path, **kw)
    builder = MeshBuilder(reader.stats)
    for p in reader.polygons():
        builder.add_polygon(p.exterior, p.interiors, p.semantic, p.building_id, p.lod)
    return builder.build(reader.crs, reader.source_crs, str(path)), reader


BOX_AREAS = {"ground": 80.0, "roof": 80.0, "wall": 2 * (10 * 6 + 8 * 6)}


@pytest.mark.parametrize("version", ["1.0", "2.0", "3.0"])
def test_inline_box_all_versions(tmp_path, version):
    body = _bounded_box("b", X0, Y0, version=version) + _solid_refs(
        [f"b_{i}" for i in range(6)], version=version
    )
    path = _write(tmp_path, _city([_building("B1", body)], version=version))
    model, reader = _model_and_report(path)
    assert reader.report.version == version
    areas = model.class_areas()
    for k, v in BOX_AREAS.items():
        assert areas[k] == pytest.approx(v, rel=1e-9)  # each polygon once, with its boundary class
    assert reader.report.duplicate_polygons == 6 and model.stats.unresolved_xlinks == 0
    assert crs_label(model.crs) == "EPSG:25833"
    np.testing.assert_allclose(model.bounds_local[0] + model.origin, [X0, Y0, 0], atol=1e-3)
    # outward normals: roof up, ground down
    n = model.triangle_normals()
    assert (n[model.classes == SemanticClass.ROOF][:, 2] > 0).all()
    assert (n[model.classes == SemanticClass.GROUND][:, 2] < 0).all()


def test_xlink_solid_member_pointing_into_a_boundary_surface_keeps_the_semantics(tmp_path):
    # Solid first, boundary surfaces after: the reference is resolved within the building, forward.
    body = _solid_refs([f"b_{i}" for i in range(6)]) + _bounded_box("b", X0, Y0)
    model = read_citygml(_write(tmp_path, _city([_building("B1", body)])))
    assert model.stats.classified_by_normal == 0
    assert model.class_areas()["roof"] == pytest.approx(80.0)


def test_xlink_to_a_composite_surface_id(tmp_path):
    faces = _box_faces(X0, Y0, 10, 8, 6)
    walls = "".join(
        f"<gml:surfaceMember>{_polygon(p, f'w{i}')}</gml:surfaceMember>" for i, (_, p) in enumerate(faces)
    )
    body = (
        "<bldg:boundedBy><bldg:WallSurface><bldg:lod2MultiSurface><gml:MultiSurface><gml:surfaceMember>"
        f'<gml:CompositeSurface gml:id="comp">{walls}</gml:CompositeSurface>'
        "</gml:surfaceMember></gml:MultiSurface></bldg:lod2MultiSurface></bldg:WallSurface></bldg:boundedBy>"
        + _solid_refs(["comp"])
    )
    model, reader = _model_and_report(_write(tmp_path, _city([_building("B1", body)])))
    assert reader.report.duplicate_polygons == 6  # the composite's 6 polygons are not meshed twice
    assert model.class_areas()["wall"] == pytest.approx(2 * 80 + 2 * 60 + 2 * 48)


def test_xlink_across_buildings_backward_forward_and_dangling(tmp_path):
    a_faces = _bounded_box("a", X0, Y0)
    c_faces = _bounded_box("c", X0 + 50, Y0)
    buildings = [
        _building("A", a_faces),
        # B points back into A (cached), forward into C (pending until C streams by), and at nothing.
        _building("B", _solid_refs(["a_0", "c_1", "nowhere"])),
        _building("C", c_faces),
    ]
    model, reader = _model_and_report(_write(tmp_path, _city(buildings)))
    assert model.stats.unresolved_xlinks == 1
    assert reader.report.xlinks_cross_object == 2
    b = model.building_ids.index("B")
    sel = model.building_index == b
    assert set(model.classes[sel].tolist()) == {int(SemanticClass.GROUND), int(SemanticClass.ROOF)}
    assert float(model.triangle_areas()[sel].sum()) == pytest.approx(160.0)  # A's ground + C's roof


def test_interior_rings_are_holes(tmp_path):
    outer = [(X0, Y0, 10.0), (X0 + 10, Y0, 10.0), (X0 + 10, Y0 + 10, 10.0), (X0, Y0 + 10, 10.0)]
    hole = [(X0 + 2, Y0 + 2, 10.0), (X0 + 2, Y0 + 5, 10.0), (X0 + 6, Y0 + 5, 10.0), (X0 + 6, Y0 + 2, 10.0)]
    poly = _polygon(outer, "r", holes=[hole])
    body = (
        "<bldg:boundedBy><bldg:RoofSurface><bldg:lod2MultiSurface><gml:MultiSurface><gml:surfaceMember>"
        f"{poly}</gml:surfaceMember></gml:MultiSurface></bldg:lod2MultiSurface></bldg:RoofSurface></bldg:boundedBy>"
    )
    model = read_citygml(_write(tmp_path, _city([_building("B1", body)])))
    assert model.class_areas()["roof"] == pytest.approx(100.0 - 12.0)


def test_building_parts_belong_to_their_building(tmp_path):
    parts = "".join(
        f'<bldg:consistsOfBuildingPart><bldg:BuildingPart gml:id="P{i}">'
        f"{_bounded_box(f'p{i}', X0 + 20 * i, Y0)}</bldg:BuildingPart></bldg:consistsOfBuildingPart>"
        for i in range(2)
    )
    # The building's own LoD1 shell is coarser than its LoD2 parts: it is dropped with lod=None.
    body = _solid_inline(X0, Y0, w=30, lod=1) + parts
    path = _write(tmp_path, _city([_building("B1", body), _building("B2", _bounded_box("q", X0 + 60, Y0))]))
    model, reader = _model_and_report(path)
    assert model.building_ids == ["B1", "B2"]
    assert reader.report.building_parts == 2
    assert model.num_buildings == 2
    assert model.lods_present() == [2]
    assert float(model.triangle_areas()[model.building_index == 0].sum()) == pytest.approx(2 * 376.0)
    # lod=1 keeps exactly the building's own LoD1 shell
    lod1 = read_citygml(path, lod=1)
    assert lod1.building_ids == ["B1"] and lod1.lods_present() == [1]


def test_orientable_surface_minus_reverses_the_rings(tmp_path):
    plus = read_citygml(
        _write(tmp_path, _city([_building("B", _solid_inline(X0, Y0, orientation="+"))]), "p.gml")
    )
    minus = read_citygml(
        _write(tmp_path, _city([_building("B", _solid_inline(X0, Y0, orientation="-"))]), "m.gml")
    )
    np_, nm = plus.triangle_normals(), minus.triangle_normals()
    assert len(np_) == len(nm) == 12
    # Same faces in the same order, opposite orientation: every triangle's normal flips.
    assert (np.sign(np_[:, 2]) == -np.sign(nm[:, 2])).all()
    np.testing.assert_allclose(np_.sum(0), -nm.sum(0), atol=1e-6)
    assert (np_[:, 2] != 0).sum() == 4
    # Unlabelled surfaces are classified by their normals: turned inside out, the top face points down
    # (an overhang underside: wall) and the bottom face points up (roof).
    assert plus.class_areas()["ground"] == pytest.approx(80.0)
    assert minus.class_areas()["ground"] == 0.0
    assert minus.class_areas()["wall"] == pytest.approx(216.0 + 80.0)


@pytest.mark.parametrize("encoding", ["pos", "coordinates"])
def test_pos_and_gml2_coordinates_equal_poslist(tmp_path, encoding):
    ref = read_citygml(_write(tmp_path, _city([_building("B", _bounded_box("b", X0, Y0))]), "ref.gml"))
    other = read_citygml(
        _write(tmp_path, _city([_building("B", _bounded_box("b", X0, Y0, encoding=encoding))]), "o.gml")
    )
    np.testing.assert_array_equal(ref.vertices, other.vertices)
    np.testing.assert_array_equal(ref.triangles, other.triangles)
    np.testing.assert_array_equal(ref.classes, other.classes)


def test_srsdimension_2_polygons_are_skipped_or_refused(tmp_path):
    flat = (
        '<bldg:lod0FootPrint><gml:MultiSurface srsDimension="2"><gml:surfaceMember><gml:Polygon>'
        "<gml:exterior>"
        f"<gml:LinearRing><gml:posList>{X0} {Y0} {X0 + 5} {Y0} {X0 + 5} {Y0 + 5} {X0} {Y0}</gml:posList>"
        "</gml:LinearRing></gml:exterior></gml:Polygon></gml:surfaceMember></gml:MultiSurface>"
        "</bldg:lod0FootPrint>"
    )
    with pytest.raises(InputFileError, match="2D coordinates"):
        read_citygml(_write(tmp_path, _city([_building("B", flat)]), "flat.gml"))
    model, reader = _model_and_report(
        _write(tmp_path, _city([_building("B", flat + _bounded_box("b", X0, Y0))]))
    )
    assert reader.report.polygons_2d == 1
    assert model.lods_present() == [2]


def test_no_crs_gives_a_local_frame_and_a_warning(tmp_path):
    model = read_citygml(_write(tmp_path, _city([_building("B", _bounded_box("b", X0, Y0))], srs=None)))
    assert model.crs is None and model.source_crs is None
    assert any("no CRS" in w for w in model.stats.warnings)
    assert model.class_areas()["roof"] == pytest.approx(80.0)


def test_crs_override_and_target_crs(tmp_path):
    path = _write(tmp_path, _city([_building("B", _bounded_box("b", X0, Y0))]))
    over = read_citygml(path, crs_override="EPSG:32633")
    assert crs_label(over.crs) == "EPSG:32633"
    moved = read_citygml(path, target_crs=pyproj.CRS.from_epsg(25832))
    assert crs_label(moved.crs) == "EPSG:25832" and crs_label(moved.source_crs) == "EPSG:25833"
    expect = pyproj.Transformer.from_crs(25833, 25832, always_xy=True).transform(X0, Y0)
    lo = moved.bounds_local[0] + moved.origin
    # the box corner (X0, Y0) is the lowest x of the rotated box within a few cm of its transformed position
    assert np.hypot(*(np.array(expect) - lo[:2])) < 10.0
    assert moved.class_areas()["roof"] == pytest.approx(80.0, rel=5e-3)  # the UTM scale differs per zone


def test_unparseable_srsname_is_a_crs_error_naming_it(tmp_path):
    path = _write(
        tmp_path, _city([_building("B", _bounded_box("b", X0, Y0))], srs="urn:example:crs:nonsense")
    )
    with pytest.raises(CRSError, match="urn:example:crs:nonsense") as err:
        read_citygml(path)
    # The hint names the option users have (crs=; the CLI prints --crs), not an internal one.
    assert "pass crs='EPSG:....'" in str(err.value) and "crs_override" not in str(err.value)
    assert read_citygml(path, crs_override="EPSG:25833").num_triangles == 12


def test_differing_srsnames_warn(tmp_path):
    body = _bounded_box("b", X0, Y0).replace(
        "<gml:MultiSurface>", '<gml:MultiSurface srsName="EPSG:25832">', 1
    )
    model = read_citygml(_write(tmp_path, _city([_building("B", body)])))
    assert any("EPSG:25832" in w and "differs" in w for w in model.stats.warnings)
    same = _bounded_box("b", X0, Y0).replace(
        "<gml:MultiSurface>", '<gml:MultiSurface srsName="EPSG:25833">', 1
    )
    model = read_citygml(_write(tmp_path, _city([_building("B", same)]), "same.gml"))
    assert not any("differs" in w for w in model.stats.warnings)  # another spelling of the same CRS


def test_gzip_is_read_transparently(tmp_path):
    text = _city([_building("B", _bounded_box("b", X0, Y0))])
    path = tmp_path / "city.gml.gz"
    with gzip.open(path, "wt", encoding="utf-8") as f:
        f.write(text)
    assert read_citygml(path).class_areas()["roof"] == pytest.approx(80.0)
    truncated = tmp_path / "cut.gml.gz"
    truncated.write_bytes(path.read_bytes()[:-20])
    with pytest.raises(InputFileError):
        read_citygml(truncated)


# ---------------------------------------------------------------------------------------------- errors
def test_unknown_root_is_named(tmp_path):
    path = _write(tmp_path, '<?xml version="1.0"?><osm version="0.6"><node id="1"/></osm>')
    with pytest.raises(UnsupportedFormatError, match="<osm>"):
        read_citygml(path)


def test_citygml_root_of_unknown_version(tmp_path):
    text = _city([_building("B", _bounded_box("b", X0, Y0))]).replace("citygml/2.0", "citygml/4.0")
    with pytest.raises(UnsupportedFormatError, match="CityGML 4.0"):
        read_citygml(_write(tmp_path, text))


def test_unknown_minor_version_still_reads(tmp_path):
    text = _city([_building("B", _bounded_box("b", X0, Y0))]).replace("/2.0", "/2.1")
    model, reader = _model_and_report(_write(tmp_path, text))
    assert reader.report.version == "2.1"
    assert model.class_areas()["roof"] == pytest.approx(80.0)


def test_truncated_file_names_file_and_line(tmp_path):
    text = _city([_building("B", _bounded_box("b", X0, Y0))])
    path = _write(tmp_path, text[: len(text) // 2], "cut.gml")
    with pytest.raises(MalformedXMLError, match=r"cut\.gml.*line \d+"):
        read_citygml(path)


def test_not_xml(tmp_path):
    with pytest.raises(MalformedXMLError, match=r"junk\.gml.*line 1"):
        read_citygml(_write(tmp_path, '{"type": "CityJSON"}', "junk.gml"))


def test_empty_model(tmp_path):
    with pytest.raises(EmptyModelError, match="no Building"):
        read_citygml(_write(tmp_path, _city([])))
    relief = '<cityObjectMember><ReliefFeature gml:id="r"/></cityObjectMember>'
    with pytest.raises(EmptyModelError, match="ReliefFeature x1"):
        read_citygml(_write(tmp_path, _city([relief]), "relief.gml"))
    with pytest.raises(EmptyModelError):
        read_citygml(
            _write(tmp_path, _city([_building("B", "<bldg:measuredHeight>3</bldg:measuredHeight>")]), "e.gml")
        )


def test_missing_file(tmp_path):
    with pytest.raises(InputFileError, match="no such file"):
        read_citygml(tmp_path / "nope.gml")
    with pytest.raises(InputFileError, match="directory"):
        read_citygml(tmp_path)


def test_bad_coordinates_are_counted_not_fatal(tmp_path):
    body = _bounded_box("b", X0, Y0).replace(f"{X0:.3f} {Y0:.3f} 0.000", "x y z", 1)
    model, reader = _model_and_report(_write(tmp_path, _city([_building("B", body)])))
    assert reader.report.malformed_polygons == 1
    assert model.class_areas()["ground"] == 0.0 and model.class_areas()["roof"] == pytest.approx(80.0)


def test_every_skipped_polygon_is_counted_and_warned_in_the_stats(tmp_path):
    """A roof with one token that is no number, a NaN, a 2D polygon: each is skipped (the mesh keeps the
    rest, as before) and now counted in ``model.stats`` with a warning, and in ``summary()["skipped"]``
    beside the model's warnings (the unreadable roof used to vanish without a count or a word)."""
    roof = f"{X0:.3f} {Y0:.3f} 6.000"
    unreadable = _bounded_box("b", X0, Y0).replace(roof, f"3x{X0:.3f} {Y0:.3f} 6.000", 1)
    ground = f"{X0 + 50:.3f} {Y0:.3f} 0.000"
    nan = _bounded_box("c", X0 + 50, Y0).replace(ground, f"nan {Y0:.3f} 0.000", 1)
    flat = (
        '<bldg:lod0FootPrint><gml:MultiSurface srsDimension="2"><gml:surfaceMember><gml:Polygon>'
        f"<gml:exterior><gml:LinearRing><gml:posList>{X0} {Y0} {X0 + 5} {Y0} {X0 + 5} {Y0 + 5} {X0} {Y0}"
        "</gml:posList></gml:LinearRing></gml:exterior></gml:Polygon></gml:surfaceMember></gml:MultiSurface>"
        "</bldg:lod0FootPrint>"
    )
    no_lod = f"<gml:MultiSurface><gml:surfaceMember>{_polygon(_box_faces(X0, Y0, 5, 5, 9)[1][1])}"
    no_lod += "</gml:surfaceMember></gml:MultiSurface>"  # outside any lodN property (as ADE content is)
    path = _write(tmp_path, _city([_building("B", unreadable + flat + no_lod), _building("C", nan)]))
    model = read_citygml(path)
    assert model.num_triangles == 2 * 12 - 2 - 2  # B's roof and C's ground are gone; nothing else
    stats = model.stats
    assert (stats.malformed_polygons, stats.polygons_2d, stats.invalid_coordinate_polygons) == (1, 1, 1)
    assert stats.polygons_without_lod == 1
    text = " | ".join(stats.warnings)
    assert "skipped 1 polygons without an exterior ring or with unreadable coordinates" in text
    assert "skipped 1 polygons with 2D coordinates (no heights)" in text
    assert "skipped 1 polygons with coordinates that are NaN" in text
    assert "skipped 1 polygons outside any lodN property" in text
    summary = model.summary()
    for key in ("malformed_polygons", "polygons_2d", "invalid_coordinate_polygons", "polygons_without_lod"):
        assert summary["skipped"][key] == 1
    assert summary["warnings"] == stats.warnings
    clean = read_citygml(_write(tmp_path, _city([_building("B", _bounded_box("b", X0, Y0))]), "clean.gml"))
    assert clean.stats.warnings == [] and not any(clean.summary()["skipped"].values())


@pytest.mark.parametrize("bad", ["nan", "NaN", "inf", "-INF", "1e300", "1e12", "-2e9"])
def test_nan_infinite_and_absurd_coordinates_are_dropped_at_parse_time(tmp_path, bad):
    """A polygon with a NaN / infinite / absurd coordinate (exterior or hole) is dropped with a counted
    warning, before the origin and the triangulation: no numpy warning escapes; nothing left is an error."""
    ground = f"{X0:.3f} {Y0:.3f} 0.000"
    in_exterior = _bounded_box("b", X0, Y0).replace(ground, f"{bad} {Y0:.3f} 0.000", 1)
    roof = _box_faces(X0 + 50, Y0, 10.0, 8.0, 6.0)[1][1]
    hole = [(X0 + 52, Y0 + 2, 6.0), (X0 + 54, Y0 + 2, 6.0), (X0 + 54, Y0 + 4, float(bad))]
    in_hole = _bounded_box("c", X0 + 50, Y0).replace(
        _polygon(roof, "c_1"), _polygon(roof, "c_1", holes=[hole])
    )
    path = _write(tmp_path, _city([_building("B", in_exterior), _building("C", in_hole)]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = read_citygml(path)
    assert model.stats.invalid_coordinate_polygons == 2
    assert "skipped 2 polygons with coordinates that are NaN, infinite or beyond" in model.stats.warnings[-1]
    assert model.class_areas()["ground"] == pytest.approx(80.0)  # B's ground and C's roof are gone
    assert model.class_areas()["roof"] == pytest.approx(80.0)
    assert abs(model.origin[0] - (X0 + 30)) < 1.0 and np.abs(model.vertices).max() < 100
    only_bad = _city([_building("B", _polygon_member(f"{bad} {Y0} 5 {X0 + 9} {Y0} 5 {X0 + 9} {Y0 + 9} 5"))])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(EmptyModelError, match="1 polygons with coordinates that are NaN, infinite"):
            read_citygml(_write(tmp_path, only_bad, "bad.gml"))


def _polygon_member(poslist: str) -> str:
    """One lod2MultiSurface polygon of the closed ring ``poslist`` (its first point repeated at the end)."""
    first = " ".join(poslist.split()[:3])
    ring = f"<gml:LinearRing><gml:posList>{poslist} {first}</gml:posList></gml:LinearRing>"
    return (
        "<bldg:lod2MultiSurface><gml:MultiSurface><gml:surfaceMember><gml:Polygon><gml:exterior>"
        f"{ring}</gml:exterior></gml:Polygon></gml:surfaceMember></gml:MultiSurface></bldg:lod2MultiSurface>"
    )


def test_a_geographic_crs_for_metre_coordinates_is_refused_naming_them(tmp_path):
    """``--crs EPSG:4326`` for a file in UTM read every coordinate as degrees, dropped every polygon as
    absurd and said the file had no readable surface; now the CRS is named as the fault, given or in the
    file. A file in degrees under the same CRS reads."""
    metres = _polygon_member(f"{X0} {Y0} 10 {X0 + 9} {Y0} 10 {X0 + 9} {Y0 + 7} 10")
    path = _write(tmp_path, _city([_building("B", metres)]))
    with pytest.raises(
        CRSError, match=r"no degrees, but 'WGS 84' is geographic.*\(given as crs='EPSG:4326'\)"
    ):
        read_citygml(path, crs_override="EPSG:4326")
    wrong = _write(tmp_path, _city([_building("B", metres)], srs="EPSG:4326"), "wrong.gml")
    with pytest.raises(CRSError, match=r"\(the file's srsName: 'EPSG:4326'\)"):
        read_citygml(wrong)
    degrees = _polygon_member("52.5 13.4 10 52.5001 13.4 10 52.5001 13.4001 10")
    assert read_citygml(
        _write(tmp_path, _city([_building("B", degrees)], srs="EPSG:4326"), "deg.gml")
    ).num_triangles


def test_a_crs_override_that_moves_the_files_coordinates_is_said(tmp_path):
    """``--crs EPSG:25832`` on a file in EPSG:25833 read it 25832's way without a word; a warning says so.
    The same CRS in another spelling, or with a height system added, says nothing."""
    metres = _polygon_member(f"{X0} {Y0} 10 {X0 + 9} {Y0} 10 {X0 + 9} {Y0 + 7} 10")
    path = _write(tmp_path, _city([_building("B", metres)]))  # urn:ogc:def:crs:EPSG::25833
    moved = read_citygml(path, crs_override="EPSG:25832")
    assert any("crs='EPSG:25832' overrides the CRS the file states" in w for w in moved.stats.warnings)
    for same in ("EPSG:25833", "EPSG:25833+7837"):
        assert not any("overrides" in w for w in read_citygml(path, crs_override=same).stats.warnings)


def test_a_point_a_geographic_crs_cannot_project_is_dropped_without_a_warning(tmp_path):
    """Latitude 95 in EPSG:4326 projects to infinity: the polygon is dropped and counted (builder)."""
    good = _polygon_member("52.5 13.4 10 52.5001 13.4 10 52.5001 13.4001 10")
    bad = _polygon_member("95 13.4 10 52.5001 13.4 10 52.5001 13.4001 10")
    path = _write(tmp_path, _city([_building("B", bad + good)], srs="EPSG:4326"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = read_citygml(path)
    assert model.stats.invalid_coordinate_polygons == 1 and model.num_triangles == 1


# One roof in EPSG:4326, whose axis order is latitude first: latitude 13.4, longitude 52.5 (UTM zone 39).
ROOF_4326 = "13.4 52.5 44 13.4 52.5001 44 13.4001 52.5001 44 13.4001 52.5 44"


def _city_4326(lower: str, upper: str) -> str:
    """A one-roof EPSG:4326 city whose root Envelope spans ``lower`` to ``upper`` (file axis order)."""
    text = _city([_building("B", _polygon_member(ROOF_4326))], srs="urn:ogc:def:crs:EPSG::4326")
    envelope = f"<gml:lowerCorner>{X0} {Y0} 0</gml:lowerCorner><gml:upperCorner>{X0 + 100} {Y0 + 100} 50"
    return text.replace(envelope, f"<gml:lowerCorner>{lower} 0</gml:lowerCorner><gml:upperCorner>{upper} 50")


def test_a_stale_root_envelope_does_not_choose_the_utm_zone(tmp_path):
    """A root Envelope that does not hold the geometry (0 0 / 1 1 left by a tool) chose UTM zone 31 for a
    building in zone 39: metres off by a wrong zone's distortion (roof 266 m2 instead of 120 m2). The
    geometry chooses then, with a warning; an Envelope that holds it chooses as before (the file's extent)."""
    good = read_citygml(_write(tmp_path, _city_4326("13.4 52.5", "13.4001 52.5001"), "good.gml"))
    stale = read_citygml(_write(tmp_path, _city_4326("0 0", "1 1"), "stale.gml"))
    assert crs_label(good.crs) == crs_label(stale.crs) == "EPSG:32639"
    assert good.class_areas()["roof"] == pytest.approx(119.8, abs=0.5)
    assert stale.class_areas()["roof"] == pytest.approx(good.class_areas()["roof"], rel=1e-9)
    assert any("Envelope" in w and "EPSG:32639" in w for w in stale.stats.warnings)
    assert not any("Envelope" in w for w in good.stats.warnings)
    # A wide Envelope that holds the roof: its centre (longitude 54, zone 40) still chooses, without a word.
    wide = read_citygml(_write(tmp_path, _city_4326("13 50", "14 58"), "wide.gml"))
    assert crs_label(wide.crs) == "EPSG:32640" and not any("Envelope" in w for w in wide.stats.warnings)


def test_a_reader_streams_once(tmp_path):
    reader = CityGMLReader(_write(tmp_path, _city([_building("B", _bounded_box("b", X0, Y0))])))
    assert len(list(reader.polygons())) == 6
    with pytest.raises(RuntimeError, match="once"):
        list(reader.polygons())


@pytest.mark.parametrize("lod", ["foo", "-1", -1, 7, "2.2", 2.5, True, "", [2]])
def test_a_lod_that_is_no_whole_citygml_lod_is_a_parameter_error(tmp_path, lod):
    """CityGML's LoDs are the whole numbers 0 to 4: anything else is a ParameterError naming the value (it
    was a raw TypeError for every str, and an EmptyModelError for 7), from the reader and load_city_model."""
    path = _write(tmp_path, _city([_building("B", _bounded_box("b", X0, Y0))]))
    with pytest.raises(ParameterError, match=r"LoD .*whole number 0 to 4"):
        read_citygml(path, lod=lod)
    with pytest.raises(ParameterError, match=re.escape(repr(lod))):
        load_city_model(path, lod=lod, cache=False)


@pytest.mark.parametrize("lod", [2, "2", " 2 ", "2.0", 2.0, np.int64(2)])
def test_a_whole_lod_is_taken_in_the_forms_cityjson_takes(tmp_path, lod):
    """``"2"`` / ``"2.0"`` / ``2.0`` name LoD 2 as they do for the CityJSON reader (``cityjson.lod_key``)."""
    body = _bounded_box("b", X0, Y0) + _solid_inline(X0, Y0, lod=1)
    model = read_citygml(_write(tmp_path, _city([_building("B", body)])), lod=lod)
    assert model.lods_present() == [2] and model.num_triangles == 12


def test_a_crs_whose_metres_are_not_ground_metres_is_refused(shared):
    """Berlin read into Web Mercator (EPSG:3857) loaded without a word: `city info` said 1609 x 557 m for
    984 x 334 m, and a point 200 m along the gimbal's direction projected 188 px off the image centre
    (frames audit, stop 51). Its point scale factor at 52.5 N is 1.64: refused naming it; UTM, a Gauss-
    Krueger zone and the Dutch grid pass."""
    from semcityloc.citymodel.crs import ground_scale_problem
    from semcityloc.citymodel.io import load_city_model

    berlin = shared("berlin_lod2_citygml2/3910_5817.gml")
    with pytest.raises(CRSError, match=r"Pseudo-Mercator is no metric frame here: .* is 1\.643, so its"):
        load_city_model(berlin, target_crs="EPSG:3857", cache=False)
    for code, lon, lat in (("EPSG:25833", 13.4, 52.5), ("EPSG:31468", 11.0, 49.5), ("EPSG:28992", 4.3, 52.0)):
        crs = pyproj.CRS(code)
        x, y = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
        assert ground_scale_problem(crs, x, y) is None
    assert ground_scale_problem(None, 0.0, 0.0) is None  # a local frame: nothing to tell


def test_a_wrong_crs_that_is_no_metric_frame_there_is_asked_about(shared):
    """Fuerth's Gauss-Krueger coordinates given ``--crs EPSG:25832`` (UTM 32N) put the model at lon 54.18,
    lat 39.49, where UTM 32's scale factor is 1.195: the only advice was "reproject the model" (user audit,
    stop 52). Outside the CRS's area of use the likelier cause comes first, the option that named the CRS
    is asked about, and reprojecting is still named; inside it (Web Mercator over Berlin) both, too."""
    from semcityloc.citymodel.crs import ground_scale_problem

    with pytest.raises(CRSError) as caught:
        load_city_model(shared(FUERTH), crs="EPSG:25832", cache=False)
    said = str(caught.value)
    assert (
        "(lon 54.181, lat 39.489)" in said
        and "outside the CRS's area of use (Europe between 6°E and 12°E)" in said
    )
    assert "the coordinates are not in ETRS89 / UTM zone 32N (is crs='EPSG:25832' right?)" in said
    assert said.index("is crs='EPSG:25832' right?") < said.index("reproject the model")
    assert "(is --crs EPSG:25832 right?)" in as_flags(said) and "(--crs EPSG:<code>)" in as_flags(said)
    crs = pyproj.CRS("EPSG:3857")
    x, y = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(13.4, 52.5)
    web = ground_scale_problem(crs, x, y)
    assert web.index("reproject the model") < web.index("(is the file's CRS right?)")


@pytest.mark.parametrize(
    "crs, said",
    [
        ("EPSG:2263", r"must be in metres, got NAD83 / New York Long Island \(ftUS\) in US survey foot"),
        ("EPSG:4978", r"must be metric \(projected\), got WGS 84 \(geocentric\)"),
        ("EPSG:5783", r"must be metric \(projected\), got DHHN92 height \(vertical crs\)"),
    ],
    ids=["us-feet", "earth-centred", "vertical-only"],
)
def test_a_model_crs_in_feet_earth_centred_or_vertical_only_is_refused(tmp_path, crs, said):
    """NYC's buildings in EPSG:2263 (US survey feet) read as metres: every distance 3.28 times too large;
    a CityGML or CityJSON given an Earth-centred or a vertical-only CRS rendered (adversarial test, stop 51).
    One rule for every reader: ``crs.check_projected`` on the model's CRS, naming the file."""
    from semcityloc.citymodel.generator import generate_city
    from semcityloc.citymodel.io import load_city_model

    path = generate_city(tmp_path, seed=0, lods=(2,))[2]
    with pytest.raises(CRSError, match=rf"{re.escape(str(path))}: the model's CRS {said}"):
        load_city_model(path, crs=crs, cache=False)

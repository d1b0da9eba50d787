"""OBJ reader: parsing, triangulation, buildings from connectivity, winding fix, classes from normals."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest

from semcityloc.citymodel.crs import check_projected, parse_crs_name
from semcityloc.citymodel.obj import read_obj
from semcityloc.classes import SemanticClass
from semcityloc.errors import CRSError, EmptyModelError, InputFileError

CUBE_V = [(0, 0, 0), (4, 0, 0), (4, 3, 0), (0, 3, 0), (0, 0, 5), (4, 0, 5), (4, 3, 5), (0, 3, 5)]
# Counter-clockwise seen from outside (1-based).
CUBE_F = [(1, 4, 3, 2), (5, 6, 7, 8), (1, 2, 6, 5), (2, 3, 7, 6), (3, 4, 8, 7), (4, 1, 5, 8)]


def cube_text(offset=(0.0, 0.0, 0.0), clockwise: bool = False, base: int = 0) -> str:
    lines = [f"v {x + offset[0]} {y + offset[1]} {z + offset[2]}" for x, y, z in CUBE_V]
    for face in CUBE_F:
        idx = face[::-1] if clockwise else face
        lines.append("f " + " ".join(str(i + base) for i in idx))
    return "\n".join(lines) + "\n"


def write(tmp_path: Path, text: str, name: str = "m.obj") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def class_counts(model) -> tuple[int, int, int]:
    c = model.class_triangle_counts()
    return c["roof"], c["wall"], c["ground"]


def wall_footprint_area(model) -> np.ndarray:
    """Footprint area per building from its walls alone (divergence theorem: the x-flux of the walls of
    a vertical prism with flat roof and base is footprint * height). Independent of the roof faces."""
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
    height = z_hi - z_lo
    return np.where(height > 0.5, flux / np.maximum(height, 1e-9), np.nan)


# ---------------------------------------------------------------------------------------------- synthetic


@pytest.mark.parametrize("clockwise", [False, True])
def test_cube_both_windings_give_roof_wall_ground(tmp_path, clockwise):
    model = read_obj(write(tmp_path, cube_text(clockwise=clockwise)))
    assert class_counts(model) == (2, 8, 2)
    assert model.building_ids == ["obj_0"]
    assert model.lods_present() == [1]
    # After the winding fix every triangle faces outward: the roof's normals point up.
    normals = model.triangle_normals()
    assert (normals[model.classes == SemanticClass.ROOF][:, 2] > 0).all()
    assert np.isclose(model.class_areas()["roof"], 12.0) and np.isclose(model.class_areas()["wall"], 70.0)
    flipped = [w for w in model.stats.warnings if "flipped" in w]
    assert bool(flipped) == clockwise


def test_open_bottom_clockwise_prism_is_flipped(tmp_path):
    """LoD1 exports often have no floor: the signed volume against the foot still tells the winding."""
    text = "\n".join(f"v {x} {y} {z}" for x, y, z in CUBE_V) + "\n"
    text += "".join("f " + " ".join(map(str, f[::-1])) + "\n" for f in CUBE_F[1:])
    model = read_obj(write(tmp_path, text))
    assert class_counts(model) == (2, 8, 0)
    assert any("flipped the winding of 1 of the 1 building with a volume" in w for w in model.stats.warnings)


def test_negative_indices_and_slash_forms(tmp_path):
    positive = read_obj(write(tmp_path, cube_text(), "a.obj"))
    lines = [f"v {x} {y} {z}" for x, y, z in CUBE_V] + ["vt 0 0", "vn 0 0 1"]
    forms = ["{i}", "{i}/1", "{i}//1", "{i}/1/1"]
    for k, face in enumerate(CUBE_F):
        lines.append("f " + " ".join(forms[k % 4].format(i=i - 9) for i in face))  # -8 .. -1
    negative = read_obj(write(tmp_path, "\n".join(lines) + "\n", "b.obj"))
    np.testing.assert_array_equal(positive.triangles, negative.triangles)
    np.testing.assert_allclose(positive.vertices, negative.vertices)
    assert class_counts(negative) == (2, 8, 2)


def test_relative_index_counts_vertices_defined_so_far(tmp_path):
    text = cube_text() + "v 10 10 1\nv 11 10 1\nv 10 11 1\nf -3 -2 -1\n"
    model = read_obj(write(tmp_path, text))
    assert model.num_triangles == 13
    corners = model.to_world(model.triangle_corners()[-1])
    np.testing.assert_allclose(corners, [[10, 10, 1], [11, 10, 1], [10, 11, 1]])


def test_polygons_convex_fanned_concave_earcut(tmp_path):
    # An L-shaped (concave) roof at z = 2 and a convex hexagon at z = 3, both counter-clockwise from above.
    l_shape = [(0, 0), (6, 0), (6, 2), (2, 2), (2, 6), (0, 6)]
    hexagon = [(20 + 2 * np.cos(a), 2 * np.sin(a)) for a in np.linspace(0, 2 * np.pi, 7)[:-1]]
    lines = [f"v {x} {y} 2" for x, y in l_shape] + [f"v {x} {y} 3" for x, y in hexagon]
    lines += ["f 1 2 3 4 5 6", "f 7 8 9 10 11 12"]
    model = read_obj(write(tmp_path, "\n".join(lines) + "\n"))
    assert model.num_triangles == 8 and model.num_buildings == 2
    area = model.triangle_areas()
    first = model.building_index == 0
    assert np.isclose(area[first].sum(), 20.0)  # 6*6 - 4*4: earcut did not fill the notch
    assert np.isclose(area[~first].sum(), 1.5 * np.sqrt(3) * 4)
    assert (model.triangle_normals()[:, 2] > 0).all()  # winding of the faces kept


def test_degenerate_faces_are_counted_not_fatal(tmp_path):
    text = cube_text() + "v 9 0 0\nv 10 0 0\nv 11 0 0\nf 9 10 11\nf 9 10 11 9\n"
    model = read_obj(write(tmp_path, text))
    assert model.stats.degenerate_polygons == 2
    assert model.stats.polygons == 8
    assert class_counts(model) == (2, 8, 2)


def test_buildings_from_connectivity_groups_and_welding(tmp_path):
    # Two separate cubes in one object -> two buildings, numbered in file order.
    text = cube_text() + cube_text(offset=(10, 0, 0), base=8)
    model = read_obj(write(tmp_path, text, "two.obj"))
    assert model.building_ids == ["obj_0", "obj_1"]
    assert model.to_world(model.triangle_corners()[model.building_index == 1])[:, :, 0].min() == 10

    # Blender-style: every face has its own copies of its corners (0.2 mm apart) -> still one building.
    rng = np.random.default_rng(0)
    lines, n = [], 0
    for face in CUBE_F:
        for i in face:
            x, y, z = np.asarray(CUBE_V[i - 1], dtype=float) + rng.uniform(-1e-4, 1e-4, 3)
            lines.append(f"v {x:.6f} {y:.6f} {z:.6f}")
        lines.append(f"f {n + 1} {n + 2} {n + 3} {n + 4}")
        n += 4
    welded = read_obj(write(tmp_path, "\n".join(lines) + "\n", "dup.obj"))
    assert welded.num_buildings == 1 and class_counts(welded) == (2, 8, 2)

    # Two cubes touching along a wall (coincident vertices, no shared index): one building in one
    # group, two buildings when each is its own `o`.
    one = read_obj(write(tmp_path, cube_text() + cube_text(offset=(4, 0, 0), base=8), "joined.obj"))
    assert one.num_buildings == 1
    text_o = "o a\n" + cube_text() + "o b\n" + cube_text(offset=(4, 0, 0), base=8)
    assert read_obj(write(tmp_path, text_o, "objects.obj")).num_buildings == 2


def test_y_up_mapping(tmp_path):
    # The cube exported Y-up: file (x, y, z) = world (x, z, -y).
    lines = [f"v {x} {z} {-y}" for x, y, z in CUBE_V]
    lines += ["f " + " ".join(map(str, f)) for f in CUBE_F]
    path = write(tmp_path, "\n".join(lines) + "\n")
    model = read_obj(path, z_up=False)
    np.testing.assert_allclose(model.extent_m, [4, 3, 5])
    assert class_counts(model) == (2, 8, 2)
    np.testing.assert_allclose(model.to_world(model.bounds_local), [[0, 0, 0], [4, 3, 5]])
    assert any("x, -z, y" in w for w in model.stats.warnings)
    as_z_up = read_obj(path)  # read as Z-up the cube lies on its side: 3 m tall
    np.testing.assert_allclose(as_z_up.extent_m, [4, 5, 3])


def test_crs_option(tmp_path):
    path = write(tmp_path, cube_text(offset=(500000.0, 5400000.0, 300.0)))
    model = read_obj(path, crs="EPSG:25832")
    assert model.crs.to_epsg() == 25832 and model.source_crs.to_epsg() == 25832
    np.testing.assert_allclose(model.to_world(model.bounds_local)[0], [500000, 5400000, 300])
    assert read_obj(path).crs is None
    with pytest.raises(CRSError, match="geographic"):
        read_obj(path, crs="EPSG:4326")
    with pytest.raises(CRSError):
        read_obj(path, crs="EPSG:999999999")


def test_crs_and_lod_options_are_applied_warned_of_or_refused_for_obj_and_npz_as_for_citygml(tmp_path):
    """Stop 55 audit: ``--crs`` and ``--lod`` were ignored without a word for a semcityloc ``.npz``, ``--crs``
    replaced an OBJ header's CRS without the warning the CityGML reader gives, and ``--lod`` on an OBJ was
    accepted silently. Now an override of another CRS warns as CityGML's does (and a ``.npz`` takes it), a
    ``--lod`` an OBJ cannot apply warns, and one a ``.npz`` does not hold alone is refused."""
    from semcityloc.citymodel.io import load_city_model
    from semcityloc.errors import ParameterError, as_flags

    header = "# semcityloc local frame: world = origin + vertex; origin 500000 5400000 0; crs EPSG:25832\n"
    obj = write(tmp_path, header + cube_text(), "h.obj")
    said = "crs='EPSG:25833' overrides the CRS the file states (EPSG:25832): the coordinates are read as"
    model = load_city_model(obj, crs="EPSG:25833", lod=2, cache=False)
    assert model.crs.to_epsg() == 25833 and any(said in w for w in model.stats.warnings)
    assert "--lod 2 is ignored for an OBJ" in as_flags(" ".join(model.stats.warnings))
    assert any(w.startswith("load_city_model(..., lod=2) is ignored") for w in model.stats.warnings)
    assert load_city_model(obj, crs="EPSG:25832", cache=False).stats.warnings == []  # its own: no word
    load_city_model(obj, cache=False).save_npz(tmp_path / "m.npz")
    npz = load_city_model(tmp_path / "m.npz", crs="EPSG:25833")
    assert npz.crs.to_epsg() == 25833 and any(said in w for w in npz.stats.warnings)
    assert load_city_model(tmp_path / "m.npz", lod=1).crs.to_epsg() == 25832  # the LoD it holds
    with pytest.raises(
        ParameterError, match=r"m\.npz: a semcityloc \.npz holds the LoD it was converted with \(LoD1\)"
    ):
        load_city_model(tmp_path / "m.npz", lod=2)
    read_obj(write(tmp_path, cube_text(), "bare.obj")).save_npz(tmp_path / "bare.npz")
    assert load_city_model(tmp_path / "bare.npz", crs="EPSG:25832").crs.to_epsg() == 25832  # labelled


def test_an_earth_centred_crs_is_refused_as_check_projected_refuses_it(tmp_path):
    """Stop 51: OBJ reading refused only geographic CRSs, so ``crs='EPSG:4978'`` (geocentric) loaded while a
    prior for the same CRS was refused; one rule now (``crs.check_projected``), for the option and the
    export header's CRS alike."""
    path = write(tmp_path, cube_text(offset=(500000.0, 5400000.0, 300.0)))
    with pytest.raises(
        CRSError, match=r"the OBJ's CRS 'EPSG:4978' must be metric \(projected\), got WGS 84 \(geocentric\)"
    ):
        read_obj(path, crs="EPSG:4978")
    with pytest.raises(CRSError) as projected:
        check_projected(parse_crs_name("EPSG:4978"), "the OBJ's CRS 'EPSG:4978'")
    with pytest.raises(CRSError) as obj:
        read_obj(path, crs="EPSG:4978")
    assert str(obj.value) == str(projected.value)
    header = "# semcityloc local frame: world = origin + vertex; origin 0 0 0; crs EPSG:4978\n"
    with pytest.raises(CRSError, match="geocentric"):
        read_obj(write(tmp_path, header + cube_text(), "h.obj"))
    assert read_obj(path, crs="EPSG:25832+5783").crs.is_compound  # a height system is kept


def test_ignored_and_unknown_keywords(tmp_path):
    text = "# comment\nmtllib x.mtl\nusemtl a\ns off\n" + cube_text() + "l 1 2\ncurv 0 1 1 2\n"
    model = read_obj(write(tmp_path, text))
    assert class_counts(model) == (2, 8, 2)
    assert any("curv (1 lines)" in w for w in model.stats.warnings)


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        ("v 1 2", "line 9: a vertex needs x y z"),
        ("v 1 two 3", "line 9: vertex coordinates are not numbers"),
        ("v 1 nan 3", "line 9: vertex coordinates are not finite"),
        ("v 1 1e300 3", "line 9: vertex coordinates are not finite or beyond"),
        ("f 1 2", "line 9: a face needs at least 3 vertices"),
        ("f 1 2 x", "line 9: face vertex 'x' is not an index"),
        ("f 1 2 0", "line 9: face vertex index 0 refers to no vertex"),
        ("f 1 2 -9", "line 9: face vertex index -9 refers to no vertex"),
        ("f 1 2 99", "line 9: face vertex index 99 refers to no vertex"),
    ],
)
def test_malformed_lines_name_the_line(tmp_path, bad, message):
    text = "\n".join(f"v {x} {y} {z}" for x, y, z in CUBE_V) + "\n" + bad + "\n" + "f 1 2 3\n"
    with pytest.raises(InputFileError, match=message):
        read_obj(write(tmp_path, text))


def test_unusable_files(tmp_path):
    with pytest.raises(InputFileError, match="cannot read"):
        read_obj(tmp_path / "missing.obj")
    binary = tmp_path / "bin.obj"
    binary.write_bytes(b"\x00\x01\x02" * 10)
    with pytest.raises(InputFileError, match="binary"):
        read_obj(binary)
    with pytest.raises(EmptyModelError, match="no faces"):
        read_obj(write(tmp_path, "v 0 0 0\nv 1 0 0\nv 0 1 0\n"))
    with pytest.raises(EmptyModelError, match="no face of the OBJ has an area"):
        read_obj(write(tmp_path, "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"))


# ---------------------------------------------------------------------------------------------- real file


@functools.cache
def _read_cached(path: str):
    return read_obj(path)


@pytest.fixture
def uavd4l(shared):
    return _read_cached(str(shared("real_uav_lodloc/UAVD4L-LoD1.obj")))


def test_real_uavd4l_obj_loads(uavd4l):
    model = uavd4l
    assert model.stats.polygons == 16511
    assert model.num_triangles >= 16511
    counts = model.class_triangle_counts()
    assert counts["roof"] > 1000 and counts["wall"] > 1000
    dx, dy, _ = model.extent_m
    assert abs(dx - 2100) / 2100 < 0.05 and abs(dy - 950) / 950 < 0.05
    assert model.num_buildings > 100 and model.building_ids[0] == "obj_0"
    # The local frame is the file's frame: origin + local = OBJ coordinates (z stays absolute).
    assert model.origin[2] == 0.0
    assert np.isclose(model.to_world(model.bounds_local)[1, 2], 125.506, atol=1e-3)


def test_real_uavd4l_roofs_face_up(uavd4l):
    model = uavd4l
    areas = model.class_areas()
    normals = model.triangle_normals()
    down = -0.5 * normals[normals[:, 2] < 0, 2].sum()
    assert down < 0.01 * areas["roof"]  # almost nothing faces down: the file's LoD1 blocks have no floor
    footprint = wall_footprint_area(model)
    ok = np.isfinite(footprint)
    roof_per_building = np.bincount(
        model.building_index, weights=model.triangle_areas() * (model.classes == SemanticClass.ROOF)
    )[ok]
    ratio = roof_per_building.sum() / footprint[ok].sum()
    assert 0.9 < ratio < 1.2, ratio  # roof area ~ footprint measured from the walls alone
    assert np.isclose(np.median(roof_per_building / footprint[ok]), 1.0, atol=0.01)


def test_an_exported_obj_reads_back_in_place_with_its_classes(generated_lod2, tmp_path):
    """``city convert x.gml y.obj`` then reading y.obj lost the origin and CRS its header names (the model
    came back near 0, 0 without a CRS) and the classes its ``usemtl`` groups carry (classified by normals:
    windows and doors gone). Both are read now; world coordinates agree to the export's 0.1 mm."""
    from semcityloc.citymodel.export import export_model

    model = generated_lod2
    back = read_obj(export_model(model, tmp_path / "city.obj"))
    np.testing.assert_array_equal(back.origin, model.origin)
    assert back.crs == model.crs and back.stats.classified_by_normal == 0
    assert back.class_triangle_counts() == model.class_triangle_counts()
    world = np.sort(back.to_world(back.vertices[back.triangles].reshape(-1, 3)), axis=0)
    np.testing.assert_allclose(
        world, np.sort(model.to_world(model.vertices[model.triangles].reshape(-1, 3)), axis=0), atol=2e-4
    )
    # A material named like no class: those faces are classified by normals, as any OBJ's
    text = (tmp_path / "city.obj").read_text().replace("usemtl roof", "usemtl tiles")
    (tmp_path / "other.obj").write_text(text)
    other = read_obj(tmp_path / "other.obj")
    assert other.stats.classified_by_normal == model.class_triangle_counts()["roof"] > 0


def test_a_ply_export_is_named_as_write_only(generated_lod2, tmp_path):
    """``city convert`` writes PLY for viewers; reading one back said "not CityGML, CityJSON or OBJ"."""
    from semcityloc.citymodel.export import export_model
    from semcityloc.citymodel.io import load_city_model
    from semcityloc.errors import UnsupportedFormatError

    ply = export_model(generated_lod2, tmp_path / "city.ply")
    with pytest.raises(UnsupportedFormatError, match="a PLY mesh, which semcityloc writes for viewers"):
        load_city_model(ply, cache=False)


def test_an_exported_obj_keeps_every_building_of_a_block_and_its_exact_origin(shared, tmp_path):
    """Berlin to OBJ and back gave 163 buildings for 166 (the faces were grouped by class only, and
    buildings sharing a wall merged by connectivity), and the header kept the origin to 1 mm. Now each
    building is an ``o`` object named by its id: the same buildings, ids, classes and triangles (to the
    export's micrometres), and the float64 origin exactly; ``write_obj`` takes a path string too."""
    from semcityloc.citymodel.export import write_obj
    from semcityloc.citymodel.io import load_city_model

    model = load_city_model(shared("berlin_lod2_citygml2/3910_5817.gml"), cache=False)
    model = model.with_origin(model.origin + [0.123456789, -0.5, 0.25])
    back = read_obj(write_obj(model, str(tmp_path / "berlin.obj")))
    assert back.building_ids == model.building_ids and len(back.building_ids) == 166
    np.testing.assert_array_equal(back.origin, model.origin)

    def triangles(m):
        corners = m.vertices[m.triangles].astype(np.float64).reshape(-1, 9)
        rows = np.c_[m.building_index, m.classes, corners]
        return rows[np.lexsort(rows.T[::-1])]

    np.testing.assert_allclose(triangles(back), triangles(model), atol=5e-6)


def test_an_exported_obj_whose_object_names_repeat_falls_back_to_connectivity(generated_lod2, tmp_path):
    """A hand-edited export whose ``o`` lines all say ``BLDG`` came back as one building (every face in one
    group), without a word (adversarial test, stop 51): repeated names are no building ids, so the
    buildings come from connectivity, as any OBJ's, and a warning says so."""
    from semcityloc.citymodel.export import write_obj

    path = write_obj(generated_lod2, tmp_path / "city.obj")
    lines = path.read_text().splitlines()
    (tmp_path / "same.obj").write_text("\n".join("o BLDG" if ln.startswith("o ") else ln for ln in lines))
    same = read_obj(tmp_path / "same.obj")
    assert "object names repeat in the file: its buildings are taken by connectivity" in same.stats.warnings
    assert len(same.building_ids) > 1 and same.building_ids[0].startswith("obj_")
    assert read_obj(path).building_ids == generated_lod2.building_ids

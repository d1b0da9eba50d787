"""CityModel: builder, origin handling, classification by normals, npz round trip, exports."""

from __future__ import annotations

import numpy as np
import pytest

from semcityloc.citymodel.builder import MeshBuilder, choose_origin
from semcityloc.citymodel.export import export_model
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import SemanticClass
from semcityloc.errors import (
    EmptyModelError,
    InputFileError,
    ParameterError,
    ShapeError,
    UnsupportedFormatError,
)

E, N = 391000.0, 5817000.0  # UTM-sized offsets: float32 would lose centimetres here


def box_polygons(x0, y0, z0, dx, dy, dz):
    """Outward-oriented (counter-clockwise from outside) faces of an axis-aligned box."""
    c = np.array(
        [[x0, y0, z0], [x0 + dx, y0, z0], [x0 + dx, y0 + dy, z0], [x0, y0 + dy, z0]], dtype=np.float64
    )
    top = c + [0, 0, dz]
    faces = [c[::-1], top]  # bottom faces down, top faces up
    for i in range(4):
        j = (i + 1) % 4
        faces.append(np.array([c[i], c[j], top[j], top[i]]))
    return faces


def build_box(semantic=True, dz=10.0) -> CityModel:
    b = MeshBuilder()
    labels = [SemanticClass.GROUND, SemanticClass.ROOF] + [SemanticClass.WALL] * 4
    for face, label in zip(box_polygons(E + 0.123, N + 0.456, 34.0, 20.0, 10.0, dz), labels, strict=True):
        b.add_polygon(face, semantic=int(label) if semantic else None, building_id="b1", lod=2)
    return b.build(source="box")


def test_origin_subtracted_in_float64_keeps_centimetres():
    model = build_box()
    world = model.to_world(model.vertices)
    assert world[:, 0].min() == pytest.approx(E + 0.123, abs=1e-4)
    assert world[:, 1].min() == pytest.approx(N + 0.456, abs=1e-4)
    assert model.origin.dtype == np.float64 and model.vertices.dtype == np.float32
    assert model.origin[2] == 0.0  # heights stay absolute in the local frame


def test_a_building_far_from_the_rest_is_refused_by_name_not_rounded_silently():
    """Stop 45's audit: one box at 1e8 m moved the origin so far that float32 read the 15 m boxes as 16 m."""
    b = MeshBuilder()
    labels = [SemanticClass.GROUND, SemanticClass.ROOF] + [SemanticClass.WALL] * 4
    for i, x0 in enumerate((E, E + 30.0, E + 1e8)):
        for face, label in zip(box_polygons(x0, N, 34.0, 15.0, 15.0, 10.0), labels, strict=True):
            b.add_polygon(face, semantic=int(label), building_id=f"b{i}", lod=2)
    with pytest.raises(InputFileError, match="building 'b2' lies 100,000.0 km from the middle"):
        b.build(source="far")


@pytest.mark.parametrize("origin", [[1.0, 2.0], [np.nan, 0.0, 0.0], "here"])
def test_a_given_origin_must_be_three_finite_numbers(origin):
    b = MeshBuilder()
    for face in box_polygons(E, N, 34.0, 15.0, 15.0, 10.0):
        b.add_polygon(face, building_id="b", lod=2)
    with pytest.raises(ParameterError, match="origin must be three finite numbers"):
        b.build(source="box", origin=origin)


def test_choose_origin_large_heights_recentre_z():
    pts = np.array([[4e6, 5e5, 4.7e6], [4.001e6, 5.01e5, 4.701e6]])
    assert choose_origin(pts)[2] != 0.0


@pytest.mark.parametrize("semantic", [True, False])
def test_box_classes_and_areas(semantic):
    model = build_box(semantic=semantic)
    areas = model.class_areas()
    assert areas["roof"] == pytest.approx(200.0, rel=1e-5)
    assert areas["ground"] == pytest.approx(200.0, rel=1e-5)
    assert areas["wall"] == pytest.approx(2 * (20 + 10) * 10.0, rel=1e-5)
    assert model.num_buildings == 1
    np.testing.assert_allclose(model.extent_m, [20, 10, 10], atol=1e-4)
    if not semantic:
        assert model.stats.classified_by_normal == 6


def test_overhang_underside_is_wall_not_ground():
    b = MeshBuilder()
    for face in box_polygons(0, 0, 0, 10, 10, 10):
        b.add_polygon(face, semantic=None, building_id="b", lod=2)
    # A downward-facing face 5 m up (underside of a balcony): not ground.
    under = np.array([[0, 0, 5], [10, 0, 5], [10, -2, 5], [0, -2, 5]], dtype=float)
    b.add_polygon(under, semantic=None, building_id="b", lod=2)
    model = b.build()
    assert model.classes[-1] == SemanticClass.WALL
    assert model.class_areas()["ground"] == pytest.approx(100.0)


def test_degenerate_polygons_are_counted_not_fatal():
    b = MeshBuilder()
    b.add_polygon(np.array([[0, 0, 0], [0, 0, 0], [0, 0, 0]], dtype=float), semantic=3, building_id="x")
    b.add_polygon(np.array([[0, 0, 0], [1, 0, 0]], dtype=float), semantic=3, building_id="x")
    b.add_polygon(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=float), semantic=3, building_id="x")
    model = b.build()
    assert model.stats.degenerate_polygons == 2 and model.num_triangles == 1


def test_empty_builder_raises_typed_error():
    with pytest.raises(EmptyModelError):
        MeshBuilder().build(source="nothing.gml")


def test_inconsistent_arrays_are_rejected():
    with pytest.raises(ShapeError):
        CityModel(np.zeros(3), np.zeros((3, 3)), [[0, 1, 2]], [1, 2], [0], [2], ["a"])
    with pytest.raises(ShapeError):
        CityModel(np.zeros(3), np.zeros((3, 3)), [[0, 1, 5]], [1], [0], [2], ["a"])


def test_npz_round_trip(tmp_path):
    model = build_box()
    import pyproj

    model.crs = pyproj.CRS.from_epsg(25833)
    back = CityModel.load_npz(model.save_npz(tmp_path / "m.npz"))
    for name in ("origin", "vertices", "triangles", "classes", "building_index", "lods"):
        np.testing.assert_array_equal(getattr(back, name), getattr(model, name))
    assert back.crs == model.crs and back.building_ids == model.building_ids


def test_with_origin_shifts_vertices_in_float64_then_casts():
    model = build_box()
    new_origin = model.origin + np.array([10.25, -20.5, 5.0])
    moved = model.with_origin(new_origin)
    assert moved is not model and moved.origin.dtype == np.float64 and moved.vertices.dtype == np.float32
    np.testing.assert_array_equal(moved.origin, new_origin)
    want = (model.vertices.astype(np.float64) + (model.origin - new_origin)).astype(np.float32)
    np.testing.assert_array_equal(moved.vertices, want)
    np.testing.assert_allclose(moved.to_world(moved.vertices), model.to_world(model.vertices), atol=1e-5)
    np.testing.assert_array_equal(moved.triangles, model.triangles)
    np.testing.assert_array_equal(moved.classes, model.classes)
    assert moved.building_ids == model.building_ids and moved.crs == model.crs
    np.testing.assert_array_equal(model.origin, new_origin - [10.25, -20.5, 5.0])  # self is untouched
    assert model.with_origin(model.origin.copy()) is model
    assert model.with_origin(model.origin.tolist()) is model


def test_pose_to_local_and_to_world_are_the_origin_shift():
    from semcityloc.geometry.pose import Pose

    model = build_box()
    world = Pose.from_xyz_rpy(np.array([E + 12.345678, N - 9.87654321, 120.5]), 1.5, 34.5, 124.0)
    ulps = 4 * np.spacing(np.abs(world.center))  # exact to float64 precision (a few ulp of the CRS value)
    local = model.pose_to_local(world)
    np.testing.assert_allclose(local.center, world.center - model.origin, rtol=0, atol=ulps.max())
    np.testing.assert_array_equal(local.R, world.R)
    same = world.shift_world(model.origin)
    np.testing.assert_array_equal(local.R, same.R)
    np.testing.assert_array_equal(local.t, same.t)
    back = model.pose_to_world(local)
    np.testing.assert_array_equal(back.R, world.R)
    np.testing.assert_array_equal(back.t, local.shift_world(-model.origin).t)
    np.testing.assert_allclose(back.center, world.center, rtol=0, atol=ulps.max())
    np.testing.assert_allclose(back.t, world.t, rtol=0, atol=4 * np.spacing(np.abs(world.t)).max())
    again = model.pose_to_local(back)
    np.testing.assert_allclose(again.center, local.center, rtol=0, atol=ulps.max())
    # A pose re-expressed for another origin stays the same camera in the world.
    moved = model.with_origin(model.origin + [100.0, 50.0, 0.0])
    round_trip = moved.pose_to_world(moved.pose_to_local(world))
    np.testing.assert_allclose(round_trip.center, world.center, rtol=0, atol=ulps.max())
    np.testing.assert_allclose(
        moved.pose_to_local(world).center, local.center - [100.0, 50.0, 0.0], rtol=0, atol=ulps.max()
    )


def test_select_compacts_vertices():
    model = build_box()
    roof = model.select(model.classes == SemanticClass.ROOF)
    assert roof.num_triangles == 2 and len(roof.vertices) == 4
    assert roof.class_areas()["roof"] == pytest.approx(200.0, rel=1e-5)


def test_exports(tmp_path):
    model = build_box()
    ply = export_model(model, tmp_path / "m.ply")
    data = ply.read_bytes()
    header, body = data.split(b"end_header\n", 1)
    assert b"element face 12" in header and b"property uchar class" in header
    # 36 vertices x 15 bytes + 12 faces x (1 + 12 + 1 + 4) bytes
    assert len(body) == 36 * 15 + 12 * 18
    faces = np.frombuffer(body[36 * 15 :], dtype=[("n", "u1"), ("v", "<i4", (3,)), ("c", "u1"), ("b", "<i4")])
    np.testing.assert_array_equal(faces["c"], model.classes)
    obj = export_model(model, tmp_path / "m.obj")
    text = obj.read_text()
    assert text.count("\nf ") == 12 and "usemtl roof" in text and (tmp_path / "m.mtl").exists()
    with pytest.raises(UnsupportedFormatError):
        export_model(model, tmp_path / "m.stl")

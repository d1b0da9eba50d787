"""Derived LoD1 (``semcityloc.citymodel.lod1``): footprints, heights, orientation, fallbacks."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from semcityloc.citymodel import lod1 as lod1_module
from semcityloc.citymodel.builder import MeshBuilder
from semcityloc.citymodel.citygml import read_citygml
from semcityloc.citymodel.crs import parse_crs_name
from semcityloc.citymodel.generator import footprints_to_model
from semcityloc.citymodel.generator_footprints import generate_footprints
from semcityloc.citymodel.lod1 import HEIGHT_MODES, Lod1ParameterError, derive_lod1, roof_median_height
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import SemanticClass as C
from semcityloc.errors import EmptyModelError, SemCityLocError

ORIGIN = np.array([690000.0, 5336000.0, 0.0])
CRS = parse_crs_name("EPSG:25832")


def _w(points) -> np.ndarray:
    """Local points -> world coordinates (what readers hand to MeshBuilder)."""
    return np.asarray(points, dtype=np.float64) + ORIGIN


def _prism_walls(b: MeshBuilder, ring, z0, z1, bid) -> None:
    ring = np.asarray(ring, dtype=np.float64)
    for p, q in zip(ring, np.roll(ring, -1, axis=0), strict=True):
        b.add_polygon(_w([[*p, z0], [*q, z0], [*q, z1], [*p, z1]]), (), int(C.WALL), bid, 2)


def _flat(ring, z) -> np.ndarray:
    ring = np.asarray(ring, dtype=np.float64)
    return np.column_stack([ring, np.full(len(ring), z)])


def _add_gable_house(b: MeshBuilder, bid="gable") -> None:
    """10 x 8 m at (0..10, 0..8), ground 500, eaves 506, ridge 510 along x at y = 4."""
    g, e, r = 500.0, 506.0, 510.0
    b.add_polygon(_w(_flat([(0, 0), (0, 8), (10, 8), (10, 0)], g)), (), int(C.GROUND), bid, 2)
    b.add_polygon(_w([[0, 0, g], [10, 0, g], [10, 0, e], [0, 0, e]]), (), int(C.WALL), bid, 2)
    b.add_polygon(_w([[10, 8, g], [0, 8, g], [0, 8, e], [10, 8, e]]), (), int(C.WALL), bid, 2)
    b.add_polygon(_w([[10, 0, g], [10, 8, g], [10, 8, e], [10, 4, r], [10, 0, e]]), (), int(C.WALL), bid, 2)
    b.add_polygon(_w([[0, 8, g], [0, 0, g], [0, 0, e], [0, 4, r], [0, 8, e]]), (), int(C.WALL), bid, 2)
    b.add_polygon(_w([[0, 0, e], [10, 0, e], [10, 4, r], [0, 4, r]]), (), int(C.ROOF), bid, 2)
    b.add_polygon(_w([[10, 8, e], [0, 8, e], [0, 4, r], [10, 4, r]]), (), int(C.ROOF), bid, 2)


L_RING = [(20, 0), (44, 0), (44, 9), (29, 9), (29, 30), (20, 30)]  # counter-clockwise, area 24*9 + 9*21
L_AREA = 24 * 9 + 9 * 21
L_PERIMETER = 24 + 9 + 15 + 21 + 9 + 30


def _add_l_flat(b: MeshBuilder, bid="flat_l", z0=499.0, z1=511.0) -> None:
    b.add_polygon(_w(_flat(L_RING[::-1], z0)), (), int(C.GROUND), bid, 2)
    _prism_walls(b, L_RING, z0, z1, bid)
    b.add_polygon(_w(_flat(L_RING, z1)), (), int(C.ROOF), bid, 2)


def _build(b: MeshBuilder) -> CityModel:
    return b.build(crs=CRS, source_crs=CRS, source="hand-built", origin=ORIGIN)


@pytest.fixture(scope="module")
def two_buildings() -> CityModel:
    b = MeshBuilder()
    _add_gable_house(b)
    _add_l_flat(b)
    return _build(b)


def _per_building(model: CityModel, cls: int) -> dict[str, float]:
    areas = model.triangle_areas()
    out = {}
    for i, bid in enumerate(model.building_ids):
        out[bid] = float(areas[(model.building_index == i) & (model.classes == cls)].sum())
    return out


def _volume(model: CityModel, building: int) -> float:
    """Signed volume (divergence theorem): positive only for a closed, outward-oriented surface."""
    c = model.triangle_corners()[model.building_index == building]
    c = c - c.reshape(-1, 3).mean(0)
    return float(np.einsum("ij,ij->i", c[:, 0], np.cross(c[:, 1], c[:, 2])).sum() / 6.0)


def test_footprint_area_equals_ground_area(two_buildings):
    lod1 = derive_lod1(two_buildings)
    src_ground = _per_building(two_buildings, C.GROUND)
    for cls in (C.GROUND, C.ROOF):
        got = _per_building(lod1, cls)
        for bid, area in src_ground.items():
            assert got[bid] == pytest.approx(area, rel=1e-6)
    assert src_ground["gable"] == pytest.approx(80.0, rel=1e-6)
    assert src_ground["flat_l"] == pytest.approx(L_AREA, rel=1e-6)


def test_median_roof_height_and_wall_area_is_perimeter_times_height(two_buildings):
    lod1 = derive_lod1(two_buildings, "median_roof")
    walls = _per_building(lod1, C.WALL)
    # gable: the roof height is uniform over 506..510, the area-weighted median is the mid-height 508
    assert walls["gable"] == pytest.approx(36.0 * 8.0, rel=1e-5)
    assert walls["flat_l"] == pytest.approx(L_PERIMETER * 12.0, rel=1e-5)
    top = lod1.vertices[lod1.triangles[(lod1.building_index == 0) & (lod1.classes == C.ROOF)]][..., 2]
    assert np.allclose(top, 508.0, atol=1e-4)
    # one wall quad (2 triangles) per footprint edge: 4 for the house, 6 for the L
    counts = np.bincount(lod1.building_index[lod1.classes == C.WALL])
    assert counts.tolist() == [8, 12]


@pytest.mark.parametrize(("mode", "top"), [("max", 510.0), ("eaves", 506.0), ("median_roof", 508.0)])
def test_height_modes(two_buildings, mode, top):
    lod1 = derive_lod1(two_buildings, mode)
    v = lod1.vertices[lod1.triangles[lod1.building_index == 0]].reshape(-1, 3)
    assert v[:, 2].max() == pytest.approx(top, abs=1e-4)
    assert v[:, 2].min() == pytest.approx(500.0, abs=1e-4)
    assert _volume(lod1, 0) == pytest.approx(80.0 * (top - 500.0), rel=1e-5)


def test_every_triangle_classified_and_frame_kept(two_buildings):
    lod1 = derive_lod1(two_buildings)
    assert set(np.unique(lod1.classes).tolist()) == {C.GROUND, C.WALL, C.ROOF}
    assert lod1.lods_present() == [1]
    assert lod1.building_ids == two_buildings.building_ids
    assert np.array_equal(lod1.origin, two_buildings.origin)
    assert lod1.crs == two_buildings.crs
    assert lod1.stats.warnings == []
    # walls vertical and outward, roof up, ground down: the closed volume is positive and exact
    assert _volume(lod1, 1) == pytest.approx(L_AREA * 12.0, rel=1e-5)
    n = lod1.triangle_normals()
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    assert np.all(n[lod1.classes == C.ROOF, 2] > 0.999)
    assert np.all(n[lod1.classes == C.GROUND, 2] < -0.999)
    assert np.all(np.abs(n[lod1.classes == C.WALL, 2]) < 1e-6)


def test_no_ground_uses_roof_outline(two_buildings):
    roofless_ground = two_buildings.select(two_buildings.classes != C.GROUND)
    lod1 = derive_lod1(roofless_ground)
    ground = _per_building(lod1, C.GROUND)
    assert ground["gable"] == pytest.approx(80.0, rel=1e-5)
    assert ground["flat_l"] == pytest.approx(L_AREA, rel=1e-5)
    assert lod1.stats.warnings == []


def test_courtyard_hole_is_kept():
    outer = [(0, 0), (30, 0), (30, 20), (0, 20)]
    hole = [(10, 5), (10, 15), (20, 15), (20, 5)]  # clockwise seen from above
    b = MeshBuilder()
    b.add_polygon(_w(_flat(outer[::-1], 0.0)), [_w(_flat(hole[::-1], 0.0))], int(C.GROUND), "court", 2)
    b.add_polygon(_w(_flat(outer, 9.0)), [_w(_flat(hole, 9.0))], int(C.ROOF), "court", 2)
    _prism_walls(b, outer, 0.0, 9.0, "court")
    _prism_walls(b, hole, 0.0, 9.0, "court")
    lod1 = derive_lod1(_build(b))
    areas = lod1.class_areas()
    assert areas["roof"] == pytest.approx(600 - 100, rel=1e-6)
    assert areas["ground"] == pytest.approx(500, rel=1e-6)
    assert areas["wall"] == pytest.approx((100 + 40) * 9.0, rel=1e-6)
    assert _volume(lod1, 0) == pytest.approx(500 * 9.0, rel=1e-6)


def test_t_junction_between_ground_polygons_leaves_no_inner_wall():
    b = MeshBuilder()
    # two ground polygons sharing x = 10; the left one has an extra vertex (10, 3) on the shared edge
    b.add_polygon(_w(_flat([(0, 0), (0, 6), (10, 6), (10, 3), (10, 0)], 0.0)), (), int(C.GROUND), "t", 2)
    b.add_polygon(_w(_flat([(10, 0), (10, 6), (16, 6), (16, 0)], 0.0)), (), int(C.GROUND), "t", 2)
    b.add_polygon(_w(_flat([(0, 0), (16, 0), (16, 6), (0, 6)], 7.0)), (), int(C.ROOF), "t", 2)
    lod1 = derive_lod1(_build(b), "max")
    assert lod1.class_areas()["wall"] == pytest.approx(44.0 * 7.0, rel=1e-6)
    assert lod1.class_triangle_counts()["wall"] == 8  # 4 straight walls, collinear vertices merged
    assert lod1.class_areas()["roof"] == pytest.approx(96.0, rel=1e-6)


def test_disjoint_parts_give_two_outlines():
    b = MeshBuilder()
    for x0 in (0.0, 20.0):
        ring = [(x0, 0), (x0 + 5, 0), (x0 + 5, 5), (x0, 5)]
        b.add_polygon(_w(_flat(ring[::-1], 0.0)), (), int(C.GROUND), "two", 2)
        b.add_polygon(_w(_flat(ring, 4.0)), (), int(C.ROOF), "two", 2)
    lod1 = derive_lod1(_build(b))
    assert lod1.class_areas()["wall"] == pytest.approx(2 * 20 * 4.0, rel=1e-6)
    assert lod1.class_areas()["roof"] == pytest.approx(50.0, rel=1e-6)
    assert lod1.num_buildings == 1


def test_overlapping_roofs_give_their_union():
    b = MeshBuilder()  # no ground; a dormer roof sticking out over the main roof: the projections overlap
    b.add_polygon(_w(_flat([(0, 0), (10, 0), (10, 10), (0, 10)], 6.0)), (), int(C.ROOF), "d", 2)
    b.add_polygon(_w(_flat([(2, 2), (12, 2), (12, 4), (2, 4)], 8.0)), (), int(C.ROOF), "d", 2)
    lod1 = derive_lod1(_build(b), "max")
    assert lod1.stats.warnings == []
    assert lod1.class_areas()["roof"] == pytest.approx(100.0 + 2.0 * 2.0, rel=1e-6)
    # outline: the square's 40 m plus the 2 m top and bottom of the strip; from z 6 (lowest) to 8 (max)
    assert lod1.class_areas()["wall"] == pytest.approx(44.0 * 2.0, rel=1e-6)


def test_overlapping_ground_polygons_crossing_at_angles_give_their_union():
    square = np.array([(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]) * 3.0
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    turned = square @ np.array([[c, -s], [s, c]]).T
    b = MeshBuilder()
    for ring in (square, turned):
        b.add_polygon(_w(_flat((ring + 50.0)[::-1], 0.0)), (), int(C.GROUND), "star", 2)
        b.add_polygon(_w(_flat(ring + 50.0, 5.0)), (), int(C.ROOF), "star", 2)
    lod1 = derive_lod1(_build(b))
    octagon = 8.0 * np.tan(np.pi / 8) * 3.0**2  # the overlap: a regular octagon of inradius 3
    star = 2 * 36.0 - octagon
    assert lod1.stats.warnings == []
    assert lod1.class_areas()["ground"] == pytest.approx(star, rel=1e-6)
    star_perimeter = 16 * 3.0 * (1 - np.tan(np.pi / 8))  # 16 edges from a corner to an octagon vertex
    assert lod1.class_areas()["wall"] == pytest.approx(star_perimeter * 5.0, rel=1e-6)
    assert _volume(lod1, 0) == pytest.approx(star * 5.0, rel=1e-6)


def test_a_failed_union_keeps_the_outline_as_drawn(monkeypatch):
    monkeypatch.setattr(lod1_module, "_union_boundary", lambda pts, boundary: (pts, boundary[:0]))
    b = MeshBuilder()
    for x0 in (0.0, 3.0):  # two overlapping 6 x 6 squares
        ring = np.array([(x0, 0), (x0 + 6, 0), (x0 + 6, 6), (x0, 6)], dtype=float)
        b.add_polygon(_w(_flat(ring[::-1], 0.0)), (), int(C.GROUND), "o", 2)
        b.add_polygon(_w(_flat(ring, 4.0)), (), int(C.ROOF), "o", 2)
    lod1 = derive_lod1(_build(b))
    assert any("outline kept as drawn" in w for w in lod1.stats.warnings)
    assert lod1.class_areas()["ground"] == pytest.approx(72.0, rel=1e-6)  # both squares, overlap twice


def test_walls_only_fall_back_to_the_convex_hull():
    b = MeshBuilder()  # neither ground nor roof: the walls project to lines, only their hull has area
    _prism_walls(b, L_RING, 0.0, 6.0, "walls")
    lod1 = derive_lod1(_build(b))
    assert any("convex hull" in w for w in lod1.stats.warnings)
    hull_area = L_AREA + 0.5 * 15 * 21  # the L plus the triangle its hull adds
    assert lod1.class_areas()["roof"] == pytest.approx(hull_area, rel=1e-6)
    assert lod1.vertices[:, 2].max() == pytest.approx(6.0, abs=1e-5)


def test_bad_inputs_raise_typed_errors(two_buildings):
    with pytest.raises(Lod1ParameterError, match="median_roof"):
        derive_lod1(two_buildings, "mean")
    assert issubclass(Lod1ParameterError, SemCityLocError)
    empty = two_buildings.select(np.zeros(two_buildings.num_triangles, dtype=bool))
    with pytest.raises(EmptyModelError):
        derive_lod1(empty)
    # Every mode the module names is accepted, and "max" is never below the other two (no copy of the tuple).
    heights = {mode: derive_lod1(two_buildings, mode).vertices[:, 2].max() for mode in HEIGHT_MODES}
    assert len(heights) >= 3 and heights["max"] >= max(heights.values()) - 1e-6


def test_roof_median_height_is_triangulation_independent():
    quad = np.array([[0, 0, 0.0], [4, 0, 0.0], [4, 2, 10.0], [0, 2, 10.0]])
    one = np.stack([quad[[0, 1, 2]], quad[[0, 2, 3]]])
    other = np.stack([quad[[0, 1, 3]], quad[[1, 2, 3]]])
    assert roof_median_height(one) == pytest.approx(5.0, abs=1e-7)
    assert roof_median_height(other) == pytest.approx(5.0, abs=1e-7)
    # two flat roofs: 30 m2 at 3 m, 10 m2 at 9 m -> the median lies on the larger one
    flat_a = np.array([[[0, 0, 3.0], [6, 0, 3.0], [6, 5, 3.0]], [[0, 0, 3.0], [6, 5, 3.0], [0, 5, 3.0]]])
    flat_b = np.array([[[0, 0, 9.0], [5, 0, 9.0], [5, 4, 9.0]]])
    assert roof_median_height(np.concatenate([flat_a, flat_b])) == pytest.approx(3.0, abs=1e-7)


def _cell_model(cells: np.ndarray, height: float) -> CityModel:
    """A building made of unit grid cells: ground (facing down) and flat roof triangles per cell."""
    pts, tris, cls = [], [], []
    for i, j in zip(*np.nonzero(cells), strict=True):
        base = len(pts)
        for z in (0.0, height):
            pts += [(i, j, z), (i + 1, j, z), (i + 1, j + 1, z), (i, j + 1, z)]
        tris += [(base, base + 2, base + 1), (base, base + 3, base + 2)]  # ground, clockwise from above
        tris += [(base + 4, base + 5, base + 6), (base + 4, base + 6, base + 7)]
        cls += [C.GROUND, C.GROUND, C.ROOF, C.ROOF]
    b = MeshBuilder()
    b.building("cells")
    b.add_mesh(_w(pts), np.array(tris), np.array(cls), np.zeros(len(tris), dtype=int), 2)
    return _build(b)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.booleans(), min_size=25, max_size=25).filter(any))
@example([(i + j) % 2 == 0 for i in range(5) for j in range(5)])  # checkerboard: pinches everywhere
@example([not (i == 2 and j == 2) for i in range(5) for j in range(5)])  # courtyard
@example([(i, j) not in {(1, 1), (2, 2)} for i in range(5) for j in range(5)])  # two holes touching
def test_union_of_grid_cells(flags):
    """Any union of cells (holes, diagonal pinches, several parts) keeps its area and its perimeter."""
    cells = np.array(flags).reshape(5, 5)
    padded = np.pad(cells, 1)
    perimeter = int(np.sum(padded[1:, :] != padded[:-1, :]) + np.sum(padded[:, 1:] != padded[:, :-1]))
    lod1 = derive_lod1(_cell_model(cells, 3.0))
    areas = lod1.class_areas()
    assert lod1.stats.warnings == []
    assert areas["ground"] == pytest.approx(cells.sum(), rel=1e-6)
    assert areas["roof"] == pytest.approx(cells.sum(), rel=1e-6)
    assert areas["wall"] == pytest.approx(3.0 * perimeter, rel=1e-6)
    assert _volume(lod1, 0) == pytest.approx(3.0 * cells.sum(), rel=1e-6)


def test_generated_city_keeps_every_building():
    footprints = generate_footprints(seed=0, blocks=(3, 2))
    lod2 = footprints_to_model(footprints, lod=2)
    lod1 = derive_lod1(lod2)
    assert lod1.num_buildings == lod2.num_buildings == len(footprints)
    assert lod1.building_ids == [fp.id for fp in footprints]
    assert lod1.stats.warnings == []
    got = _per_building(lod1, C.GROUND)
    for fp in footprints:
        assert got[fp.id] == pytest.approx(fp.area, rel=1e-5)
    # the derived blocks lie between each building's eaves and ridge
    for i, fp in enumerate(footprints):
        top = lod1.vertices[lod1.triangles[lod1.building_index == i]][..., 2].max()
        assert fp.eaves_z - 1e-3 <= top <= fp.ridge_z + 1e-3


def test_berlin_lod2_keeps_every_building_and_its_footprint(shared):
    path = shared("berlin_lod2_citygml2/3910_5817.gml")
    model = read_citygml(path)
    lod1 = derive_lod1(model)
    assert lod1.num_buildings == model.num_buildings == 166
    assert lod1.stats.warnings == []  # every ground outline was consistent: no hull, no overlap
    src, got = _per_building(model, C.GROUND), _per_building(lod1, C.GROUND)
    np.testing.assert_allclose([got[b] for b in src], [src[b] for b in src], rtol=1e-4)
    top_src = np.full(len(model.building_ids), -np.inf)
    np.maximum.at(top_src, model.building_index, model.triangle_corners()[:, :, 2].max(1))
    top_lod1 = np.full(len(model.building_ids), -np.inf)
    np.maximum.at(top_lod1, lod1.building_index, lod1.triangle_corners()[:, :, 2].max(1))
    assert np.all(top_lod1 <= top_src + 1e-3)

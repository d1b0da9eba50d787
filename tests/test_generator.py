"""Procedural CityGML district (``semcityloc.citymodel.generator``): determinism, CityGML 2.0 structure,
geometry rules (closed solids, outward orientation, openings) and read-back through the CityGML reader."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from lxml import etree

from semcityloc.citymodel.citygml import read_citygml
from semcityloc.citymodel.citygml_writer import BLDG_NS, CORE_NS, GML_NS, XLINK_NS
from semcityloc.citymodel.generator import (
    default_city_path,
    footprints_to_model,
    generate_city,
)
from semcityloc.citymodel.generator_footprints import Footprint, generate_footprints
from semcityloc.citymodel.generator_surfaces import building_surfaces
from semcityloc.citymodel.triangulate import newell_normal, polygon_area
from semcityloc.errors import CRSError, InputFileError, ParameterError, SemCityLocError

G = f"{{{GML_NS}}}"
B = f"{{{BLDG_NS}}}"
ROOF_POLYGONS = {"flat": 1, "mono": 1, "gable": 2, "hip": 4}


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("generated_cache")


@pytest.fixture(scope="module")
def city(cache_dir) -> dict[int, Path]:
    """The default district, generated once through the cache."""
    return {lod: default_city_path(lod, cache_dir=cache_dir) for lod in (1, 2, 3)}


@pytest.fixture(scope="module")
def footprints() -> list[Footprint]:
    return generate_footprints()


@pytest.fixture(scope="module")
def trees(city) -> dict[int, etree._ElementTree]:
    return {lod: etree.parse(str(path)) for lod, path in city.items()}


@pytest.fixture(scope="module")
def surfaces(footprints) -> dict[int, list[list]]:
    blocks: dict[tuple, list[Footprint]] = {}
    for fp in footprints:
        blocks.setdefault(fp.block, []).append(fp)
    return {lod: [building_surfaces(fp, lod, blocks[fp.block]) for fp in footprints] for lod in (1, 2, 3)}


@pytest.fixture(scope="module")
def models(footprints) -> dict:
    return {lod: footprints_to_model(footprints, lod) for lod in (2, 3)}


# ------------------------------------------------------------------------------------------ determinism
def test_same_seed_gives_identical_bytes(city, tmp_path):
    again = generate_city(tmp_path)
    assert sorted(again) == [1, 2, 3]
    for lod, path in again.items():
        assert path.name == f"generated_lod{lod}.gml"
        assert path.read_bytes() == city[lod].read_bytes()


def test_different_seed_gives_a_different_city(tmp_path):
    a = generate_city(tmp_path / "a", seed=0, blocks=(2, 2), lods=(2,))[2].read_bytes()
    b = generate_city(tmp_path / "b", seed=1, blocks=(2, 2), lods=(2,))[2].read_bytes()
    a2 = generate_city(tmp_path / "c", seed=0, blocks=(2, 2), lods=(2,))[2].read_bytes()
    assert a != b
    assert a == a2
    f0, f1 = generate_footprints(0, (2, 2)), generate_footprints(1, (2, 2))
    assert [f.polygon.tolist() for f in f0] != [f.polygon.tolist() for f in f1]


def test_default_city_path_is_cached(city, cache_dir):
    stamp = city[2].stat().st_mtime_ns
    assert default_city_path(2, cache_dir=cache_dir) == city[2]
    assert city[2].stat().st_mtime_ns == stamp
    assert all(p.parent == city[2].parent and p.exists() for p in city.values())
    assert "v1-seed0-blocks4x3" in city[2].parent.name
    assert not [p for p in cache_dir.iterdir() if p.name.startswith(".")]  # no temporary folder left


def test_default_city_path_repairs_an_incomplete_folder(city, tmp_path):
    folder = tmp_path / city[1].parent.name
    folder.mkdir()
    (folder / city[1].name).write_bytes(city[1].read_bytes())
    repaired = default_city_path(3, cache_dir=tmp_path)
    assert repaired == folder / "generated_lod3.gml"
    assert repaired.read_bytes() == city[3].read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == [folder.name]


def test_unwritable_cache_dir_is_a_typed_error(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    with pytest.raises(InputFileError, match="cannot write the generated city"):
        default_city_path(2, cache_dir=blocker / "cache")


def test_bad_parameters_raise_typed_errors(tmp_path):
    with pytest.raises(ParameterError):
        generate_footprints(0, (0, 3))
    with pytest.raises(ParameterError):
        generate_footprints(0, "ab")
    with pytest.raises(ParameterError, match="seed"):
        generate_footprints(-1)
    with pytest.raises(ParameterError, match="seed"):
        generate_footprints("zero")
    with pytest.raises(ParameterError):
        generate_city(tmp_path, lods=(4,))
    with pytest.raises(ParameterError):
        generate_city(tmp_path, lods=())
    with pytest.raises(ParameterError):
        default_city_path(0, cache_dir=tmp_path)
    with pytest.raises(CRSError, match="projected"):
        generate_city(tmp_path, crs="EPSG:4326")
    with pytest.raises(CRSError):
        generate_city(tmp_path, crs="not a crs")
    assert issubclass(ParameterError, SemCityLocError)
    assert not list(tmp_path.iterdir())  # nothing written before the parameters were checked


# ---------------------------------------------------------------------------------------------- district
def _inside(pts: np.ndarray, poly: np.ndarray) -> np.ndarray:
    x, y = poly[:, 0], poly[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    px, py = pts[:, :1], pts[:, 1:]
    cross = (y > py) != (yn > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        xs = x + (py - y) * (xn - x) / (yn - y)
    return np.count_nonzero(cross & (px < xs), axis=1) % 2 == 1


def test_district_has_the_documented_variety(footprints):
    assert len(footprints) >= 40
    assert len({f.id for f in footprints}) == len(footprints)
    assert set(Counter(f.roof_type for f in footprints)) == {"flat", "gable", "hip", "mono"}
    assert set(Counter(len(f.polygon) for f in footprints)) == {4, 6}  # rectangles and L shapes
    assert set(Counter(f.block_style for f in footprints)) == {"perimeter", "detached", "towers"}
    heights = np.array([f.height for f in footprints])
    assert heights.min() >= 6.0 and heights.max() <= 45.0
    assert (heights > 30.0).sum() >= 2  # towers
    assert np.ptp([f.eaves_z - f.ground_z for f in footprints]) > 10.0
    ground = np.array([f.ground_z for f in footprints])
    assert np.ptp(ground) > 2.0  # the terrain is tilted: a flat-ground assumption is wrong
    for f in footprints:
        assert f.area > 0  # counter-clockwise seen from above
        assert f.eaves_z < f.lod1_z <= f.ridge_z or f.roof_type == "flat"
        size = np.ptp(f.polygon, axis=0)
        assert 8.0 - 1e-6 <= size.max() <= 40.0 + 1e-6
        if f.roof_type in ("gable", "hip"):
            assert len(f.polygon) == 4
            long, short = (
                np.linalg.norm(f.polygon[1] - f.polygon[0]),
                np.linalg.norm(f.polygon[2] - f.polygon[1]),
            )
            assert long >= short - 1e-2  # the ridge runs along the long axis (mm-rounded corners)
            assert np.allclose(f.roof_axis, (f.polygon[1] - f.polygon[0]) / long, atol=1e-4)
    ridge_dirs = {int(round(abs(f.roof_axis[0]))) for f in footprints if f.roof_type == "gable"}
    assert ridge_dirs == {0, 1}  # ridges along x and along y


def test_buildings_touch_but_never_overlap(footprints):
    touching = 0
    for f in footprints:
        others = [o for o in footprints if o.block == f.block and o.id != f.id]
        ring, nxt = f.polygon, np.roll(f.polygon, -1, axis=0)
        d = nxt - ring
        out = np.stack([d[:, 1], -d[:, 0]], 1) / np.linalg.norm(d, axis=1)[:, None]
        probes = 0.5 * (ring + nxt) + 0.3 * out
        lo, hi = f.polygon.min(0), f.polygon.max(0)
        gx, gy = np.meshgrid(np.arange(lo[0] + 0.37, hi[0], 1.0), np.arange(lo[1] + 0.41, hi[1], 1.0))
        grid = np.column_stack([gx.ravel(), gy.ravel()])
        grid = grid[_inside(grid, f.polygon)]
        for o in others:
            touching += int(_inside(probes, o.polygon).any())
            assert not _inside(grid, o.polygon).any(), f"{f.id} overlaps {o.id}"
    assert touching >= 20  # perimeter blocks: neighbours share walls


def test_streets_between_blocks_are_12_to_20_m(footprints):
    nx = max(f.block[0] for f in footprints) + 1
    for i in range(nx - 1):
        left = max(f.polygon[:, 0].max() for f in footprints if f.block[0] == i)
        right = min(f.polygon[:, 0].min() for f in footprints if f.block[0] == i + 1)
        assert right - left >= 12.0


# ---------------------------------------------------------------------------------------------- CityGML
def test_files_are_citygml_2(trees, footprints, surfaces):
    n = len(footprints)
    for lod, tree in trees.items():
        root = tree.getroot()
        assert root.tag == f"{{{CORE_NS}}}CityModel"
        assert {CORE_NS, BLDG_NS, GML_NS, XLINK_NS} <= set(root.nsmap.values())
        env = root.find(f"{G}boundedBy/{G}Envelope")
        assert env.get("srsName") == "urn:ogc:def:crs:EPSG::25832" and env.get("srsDimension") == "3"
        lo = np.array(env.findtext(f"{G}lowerCorner").split(), dtype=float)
        hi = np.array(env.findtext(f"{G}upperCorner").split(), dtype=float)
        assert np.all(lo < hi) and 689000 < lo[0] < 691000 and 5335000 < lo[1] < 5337000
        buildings = root.findall(f"{{{CORE_NS}}}cityObjectMember/{B}Building")
        assert len(buildings) == n
        assert all(b.get(f"{G}id") for b in buildings)
        polygons = root.iter(f"{G}Polygon")
        ids = [p.get(f"{G}id") for p in polygons]
        assert all(ids)
        all_ids = [e.get(f"{G}id") for e in root.iter() if e.get(f"{G}id")]
        assert len(all_ids) == len(set(all_ids))
        hrefs = [e.get(f"{{{XLINK_NS}}}href") for e in root.iter() if e.get(f"{{{XLINK_NS}}}href")]
        assert all(h.startswith("#") for h in hrefs)
        assert {h[1:] for h in hrefs} <= set(all_ids)  # every xlink resolves within the file
        for b in buildings:  # building envelopes lie inside the file envelope
            blo = np.array(b.findtext(f"{G}boundedBy/{G}Envelope/{G}lowerCorner").split(), dtype=float)
            assert np.all(blo >= lo - 1e-9)
        counts = Counter(etree.QName(e).localname for e in root.iter() if isinstance(e.tag, str))
        if lod == 1:
            assert counts["lod1Solid"] == n and not hrefs
            assert counts["RoofSurface"] == counts["WallSurface"] == counts["GroundSurface"] == 0
            assert counts["Polygon"] == sum(len(s) for s in surfaces[1])
            continue
        expected_roofs = sum(ROOF_POLYGONS[f.roof_type] for f in footprints)
        assert counts["RoofSurface"] == expected_roofs
        assert counts["GroundSurface"] == n
        assert counts["WallSurface"] == sum(len(f.polygon) for f in footprints)
        assert counts[f"lod{lod}Solid"] == n
        windows = sum(o.kind == "Window" for s in surfaces[lod] for w in s for o in w.openings)
        doors = sum(o.kind == "Door" for s in surfaces[lod] for w in s for o in w.openings)
        assert counts["Window"] == windows and counts["Door"] == doors
        assert counts["interior"] == windows + doors  # each opening is a hole in its wall
        # the solid xlinks every polygon of the building exactly once
        assert len(hrefs) == len(set(hrefs)) == counts["Polygon"]
        if lod == 2:
            assert windows == doors == 0
        else:
            assert windows > 1000 and n <= doors <= 2 * n


def test_lods_share_building_ids(trees, footprints):
    expected = [f.id for f in footprints]
    for tree in trees.values():
        ids = [b.get(f"{G}id") for b in tree.getroot().iter(f"{B}Building")]
        assert ids == expected


def test_lod1_file_is_the_documented_extrusion(trees, footprints):
    by_id = {f.id: f for f in footprints}
    for b in trees[1].getroot().iter(f"{B}Building"):
        f = by_id[b.get(f"{G}id")]
        z = np.concatenate(
            [np.array(t.text.split(), dtype=float).reshape(-1, 3)[:, 2] for t in b.iter(f"{G}posList")]
        )
        assert z.min() == pytest.approx(f.ground_z, abs=1e-6)
        assert z.max() == pytest.approx(f.lod1_z, abs=1e-6)


def _signed_volume(model, building: int, check_edges: bool) -> float:
    """Signed volume of one building's triangles (positive: outward orientation); with ``check_edges``
    also asserts that every directed triangle edge has its reverse (a closed, consistently oriented mesh)."""
    tris = model.triangles[model.building_index == building]
    v = np.round(model.vertices.astype(np.float64), 3)
    if check_edges:
        _, weld = np.unique(v, axis=0, return_inverse=True)
        t = weld.reshape(-1)[tris]
        edges = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
        fwd = Counter(map(tuple, edges.tolist()))
        assert all(fwd[(b, a)] == c for (a, b), c in fwd.items()), "open or inconsistently oriented solid"
    c = v[tris]
    c = c - c.reshape(-1, 3).mean(0)
    return float(np.einsum("ij,ij->i", c[:, 0], np.cross(c[:, 1], c[:, 2])).sum() / 6.0)


def _ring_edges(ring: np.ndarray) -> list[tuple]:
    pts = [tuple(p) for p in np.round(ring, 3).tolist()]
    return list(zip(pts, pts[1:] + pts[:1], strict=True))


def _expected_volume(f: Footprint) -> float:
    area, rise = f.area, f.ridge_z - f.eaves_z
    walls = area * (f.eaves_z - f.ground_z)
    if f.roof_type == "flat":
        return walls
    if f.roof_type == "hip":
        length = np.linalg.norm(f.polygon[1] - f.polygon[0])
        width = np.linalg.norm(f.polygon[2] - f.polygon[1])
        return walls + rise * width * (3 * length - width) / 6.0
    return walls + area * rise / 2.0  # gable; mono-pitch rectangles and Ls (plane through the centroid)


@pytest.mark.parametrize("lod", [2, 3])
def test_solids_are_closed_and_oriented_outward(models, surfaces, footprints, lod):
    model = models[lod]
    for i, f in enumerate(footprints):
        # polygon level: every ring edge (exteriors, holes, openings) is met once in the other direction
        edges = Counter()
        for s in surfaces[lod][i]:
            for ring in (s.exterior, *s.interiors, *(o.exterior for o in s.openings)):
                edges.update(_ring_edges(ring))
        assert all(edges[(b, a)] == c for (a, b), c in edges.items()), f.id
        # triangle level (LoD3 walls have T-junctions where earcut bridges aligned windows: volume only)
        volume = _signed_volume(model, i, check_edges=lod == 2)
        if f.roof_type == "mono" and len(f.polygon) != 4:
            assert volume > 0
        else:
            assert volume == pytest.approx(_expected_volume(f), rel=1e-4), f.id


def _quad_normals(quads: np.ndarray) -> np.ndarray:
    return np.cross(quads[:, 1] - quads[:, 0], quads[:, 2] - quads[:, 0])


def test_openings_and_holes_follow_the_citygml_rules(surfaces, footprints):
    walls, holes, openings, kinds, ground = [], [], [], [], []
    for f, building in zip(footprints, surfaces[3], strict=True):
        doors = 0
        for s in building:
            assert len(s.interiors) == len(s.openings)
            for hole, opening in zip(s.interiors, s.openings, strict=True):
                walls.append(newell_normal(s.exterior))
                holes.append(hole)
                openings.append(opening.exterior)
                kinds.append(opening.kind)
                ground.append(f.ground_z)
                doors += opening.kind == "Door"
        assert 1 <= doors <= 2, f.id
    wall_n, holes, openings = np.array(walls), np.array(holes), np.array(openings)
    kinds, ground = np.array(kinds), np.array(ground)
    assert np.all(np.einsum("ij,ij->i", _quad_normals(holes), wall_n) < 0)  # interior rings run backwards
    assert np.all(np.einsum("ij,ij->i", _quad_normals(openings), wall_n) > 0)  # openings face outward
    assert np.allclose(holes, openings[:, ::-1])  # each hole has exactly the corners of its opening
    z = openings[:, :, 2]
    height = np.ptp(z, axis=1)
    width = np.linalg.norm(_quad_normals(openings), axis=1) / height
    win = kinds == "Window"
    assert np.allclose(width[win], 1.2) and np.allclose(height[win], 1.5)
    assert np.allclose(width[~win], 1.0) and np.allclose(height[~win], 2.1)
    floor = (z[win].min(1) - ground[win] - 0.9) / 3.0  # sills 0.9 m above each 3 m floor
    assert np.allclose(floor, np.round(floor), atol=1e-9)
    assert np.allclose(z[~win].min(1), ground[~win] + 0.1)  # doors on a 0.1 m step at street level
    assert polygon_area(openings[0]) == pytest.approx(width[0] * height[0])


def test_lod3_openings_cut_the_walls(models):
    lod2, lod3 = models[2].class_areas(), models[3].class_areas()
    assert models[3].num_triangles < 150_000
    assert models[3].class_triangle_counts()["window"] > 0 and models[3].class_triangle_counts()["door"] > 0
    assert lod3["wall"] + lod3["window"] + lod3["door"] == pytest.approx(lod2["wall"], rel=1e-6)
    assert lod3["roof"] == pytest.approx(lod2["roof"], rel=1e-9)


# -------------------------------------------------------------------------------- read back (reader)
@pytest.fixture(scope="module")
def read_back(city) -> dict:
    return {lod: read_citygml(path) for lod, path in city.items()}


def test_reader_sees_the_same_buildings_at_every_lod(read_back, footprints):
    for lod, model in read_back.items():
        assert model.num_buildings == len(footprints), lod
        assert model.building_ids == [f.id for f in footprints]
        assert model.lods_present() == [lod]
        assert model.stats.unresolved_xlinks == 0 and model.stats.degenerate_polygons == 0
    assert read_back[1].stats.classified_by_normal == read_back[1].stats.polygons  # LoD1 has no semantics
    assert read_back[2].stats.classified_by_normal == 0


def test_reader_lod3_has_openings_and_less_wall(read_back, models):
    lod2, lod3 = read_back[2].class_areas(), read_back[3].class_areas()
    counts = read_back[3].class_triangle_counts()
    assert counts["window"] > 0 and counts["door"] > 0
    openings = lod3["window"] + lod3["door"]
    assert lod2["wall"] - lod3["wall"] == pytest.approx(openings, rel=0.01)
    assert read_back[3].num_triangles < 150_000
    # the file says what the in-memory surfaces say (millimetre rounding aside)
    for lod in (2, 3):
        direct = models[lod].class_areas()
        for name, area in read_back[lod].class_areas().items():
            assert area == pytest.approx(direct[name], rel=1e-4, abs=1e-6), (lod, name)

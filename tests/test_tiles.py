"""The tile store (``citymodel.tiles``) and localizing against it (``localization.tiled``)."""

from __future__ import annotations

import copy
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from lxml import etree

from conftest import shared_file
from semcityloc.benchmark.methods import get_method
from semcityloc.benchmark.queries import QueryConfig, QuerySimulator, zenmuse_l2_camera
from semcityloc.benchmark.results import TIMING_COLUMNS, make_row, read_results
from semcityloc.citymodel.generator import generate_city
from semcityloc.citymodel.io import load_city_model
from semcityloc.citymodel.tiles import (
    BUDGET_ENV,
    DEFAULT_BUDGET_MB,
    TileCache,
    TileStore,
    build_store,
    load_city,
    merge_models,
    model_nbytes,
)
from semcityloc.cli.main import main
from semcityloc.errors import CRSError, OutputPathError
from semcityloc.geometry.pose import Pose
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.tiled import TiledMethod
from test_benchmark_reference import same

BERLIN = "berlin_lod2_citygml2/3910_5817.gml"
GML = "{http://www.opengis.net/gml}"


def split_citygml(path: Path, out_dir: Path, nx: int = 2, ny: int = 2) -> list[Path]:
    """Write ``path``'s city objects as nx x ny CityGML tiles by the centre of each object's coordinates
    (objects kept whole; every tile keeps the root element, its namespaces and the other children)."""
    parser = etree.XMLParser(resolve_entities=False, no_network=True, huge_tree=True)
    tree = etree.parse(str(path), parser)
    root = tree.getroot()
    members = [m for m in root if isinstance(m.tag, str) and m.tag.endswith("cityObjectMember")]
    centres = []
    for m in members:
        values = [float(v) for el in m.iter(f"{GML}posList", f"{GML}pos") for v in el.text.split()]
        xyz = np.array(values).reshape(-1, 3)
        centres.append(0.5 * (xyz.min(0) + xyz.max(0))[:2])
    centres = np.array(centres)
    lo, hi = centres.min(0), centres.max(0)
    cell = np.minimum(((centres - lo) / (hi - lo) * [nx, ny]).astype(int), [nx - 1, ny - 1])
    for m in members:
        root.remove(m)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for j in range(ny):
        for i in range(nx):
            tile = copy.deepcopy(root)
            for k in np.flatnonzero((cell[:, 0] == i) & (cell[:, 1] == j)):
                tile.append(copy.deepcopy(members[k]))
            p = out_dir / f"tile_{i}_{j}.gml"
            etree.ElementTree(tile).write(str(p), xml_declaration=True, encoding="UTF-8")
            paths.append(p)
    return paths


@pytest.fixture(scope="module")
def berlin_store(tmp_path_factory):
    single = shared_file(BERLIN)
    root = tmp_path_factory.mktemp("berlin_tiles")
    split_citygml(single, root / "tiles", nx=4, ny=1)  # Berlin's file is 1 km x 330 m
    report = build_store(root / "tiles", root / "store")
    return single, report


def _row(method, q, origin) -> dict[str, str]:
    return {k: v for k, v in make_row(q, method.localize(q), origin).items() if k not in TIMING_COLUMNS}


@pytest.mark.slow
def test_berlin_in_four_tiles_localizes_exactly_as_the_single_file(berlin_store):
    single_path, report = berlin_store
    store = report.store
    assert report.tiles == 4 and all(t.buildings > 0 for t in store.tiles)
    # The single file parsed into the store's origin: the same float64 world points, the same float32.
    single = load_city_model(single_path, cache=False, origin=store.origin)
    assert store.num_buildings == len(single.building_ids)
    merged = store.load_all()
    assert sorted(merged.building_ids) == sorted(single.building_ids)
    assert merged.num_triangles == single.num_triangles
    assert np.array_equal(np.sort(merged.vertices, axis=0), np.sort(single.vertices, axis=0))

    # Nadir and oblique views; each query localized with the single file and with the store.
    sim = QuerySimulator(single, QueryConfig(queries=8, seed=5, width=256, height=192, oblique_fraction=0.5))
    config = LocalizerConfig.preset("fast")
    whole = get_method("semcityloc", single, config)
    tiled = TiledMethod("semcityloc", store, config)
    loaded, differing = [], []
    for i in range(8):
        q = sim.query(i)
        expected, got = _row(whole, q, store.origin), _row(tiled, q, store.origin)
        loaded.append(tiled.used_tiles)
        assert set(tiled.last_tiles) <= set(tiled.used_tiles)
        # Statuses, reasons and every number as in the reference rows (1e-9 relative): where only some
        # tiles load, the terrain is triangulated from fewer points (the same triangles in view, their
        # corners in another order), which moves estimates by ~1e-13 m (measured).
        differing += [(i, k, expected[k], got[k]) for k in expected if not same(expected[k], got[k])]
        if len(tiled.used_tiles) == len(store.tiles):
            assert got == expected  # every tile loaded: identical to the last bit
    assert differing == []
    assert any(len(t) < 4 for t in loaded), (
        f"every query loaded every tile ({loaded}): the test proves little"
    )
    assert any(len(t) == 4 for t in loaded)


def test_a_prior_between_two_tiles_loads_both(berlin_store):
    _, report = berlin_store
    store = report.store
    ext = np.array([t.extent for t in store.tiles]) - np.concatenate([store.origin, store.origin])
    # Strips 1 and 2 (of four, west to east, about 245 m wide) meet here; the reach is about 190 m.
    x = 0.5 * (ext[1, 3] + ext[2, 0])
    y = 0.5 * (ext[1, 1] + ext[1, 4])
    ground = store.ground_z_near((x, y), 500.0)
    prior = Pose.from_xyz_rpy([x, y, ground + 50.0], 0.0, 0.0, 0.0)  # looking straight down
    camera = zenmuse_l2_camera(256, 192)
    config = LocalizerConfig.preset("fast")
    tiled = TiledMethod("semcityloc", store, config)
    tiles = tiled.tiles_for(camera, prior, config.prior_uncertainty)
    assert tiles == (1, 2)
    model = store.load(tiles)
    assert len(model.building_ids) == store.tiles[1].buildings + store.tiles[2].buildings


def test_tile_cache_respects_its_budget(tmp_path):
    paths = generate_city(tmp_path / "a", seed=1, lods=(2,))
    model = load_city_model(paths[2], cache=False)
    size = model_nbytes(model)
    cache = TileCache(int(2.5 * size))
    loads = []

    def load(i):
        loads.append(i)
        return model

    for i in (0, 1, 0, 2, 0, 1):
        cache.get(i, load)
        assert cache.held_bytes <= cache.budget_bytes and len(cache) <= 2
    assert loads == [0, 1, 2, 1]  # 2 evicted 1, the least recently used (0 had just been used)
    big = TileCache(size // 2)
    assert big.get(7, load) is model and len(big) == 0 and big.held_bytes == 0  # needed, but not kept


def _cityjson_box(path: Path, crs_epsg: int, x0: float, y0: float) -> Path:
    shell = [[[0, 3, 2, 1]], [[4, 5, 6, 7]], [[0, 1, 5, 4]], [[1, 2, 6, 5]], [[2, 3, 7, 6]], [[3, 0, 4, 7]]]
    box = [[0, 0, 0], [10, 0, 0], [10, 8, 0], [0, 8, 0], [0, 0, 9], [10, 0, 9], [10, 8, 9], [0, 8, 9]]
    doc = {
        "type": "CityJSON",
        "version": "2.0",
        "metadata": {"referenceSystem": f"https://www.opengis.net/def/crs/EPSG/0/{crs_epsg}"},
        "transform": {"scale": [0.001, 0.001, 0.001], "translate": [x0, y0, 40.0]},
        "CityObjects": {
            "B1": {
                "type": "Building",
                "geometry": [
                    {
                        "type": "Solid",
                        "lod": "2",
                        "boundaries": [shell],
                        "semantics": {
                            "surfaces": [
                                {"type": "GroundSurface"},
                                {"type": "RoofSurface"},
                                {"type": "WallSurface"},
                            ],
                            "values": [[0, 1, 2, 2, 2, 2]],
                        },
                    }
                ],
            }
        },
        "vertices": [[v * 1000 for v in p] for p in box],
    }
    path.write_text(json.dumps(doc))
    return path


def test_mixed_formats_one_origin_and_the_cli(tmp_path, capsys, monkeypatch):
    tiles = tmp_path / "tiles"
    gml = generate_city(tmp_path / "gen", seed=2, lods=(2,))[2]
    tiles.mkdir()
    (tiles / "a.gml").write_bytes(gml.read_bytes())
    single = load_city_model(gml, cache=False)
    far = single.origin + [20000.0, 5000.0, 0.0]  # a tile 20 km away
    _cityjson_box(tiles / "b.json", 25832, far[0], far[1])
    assert main(["tiles", "build", str(tiles), "--out", str(tmp_path / "store")]) == 0
    assert "2 tiles" in capsys.readouterr().out
    store = TileStore.open(tmp_path / "store")
    assert [t.format for t in store.tiles] == ["citygml", "cityjson"]
    assert store.num_buildings == len(single.building_ids) + 1
    b = store.load([1])
    np.testing.assert_allclose(b.to_world(b.bounds_local)[0], [far[0], far[1], 40.0], atol=1e-3)
    assert store.tiles_within(b.bounds_local[0, :2], 50.0) == (1,)
    # every command that takes --city takes the store: the merged model
    assert main(["city", "info", str(tmp_path / "store"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["buildings"] == len(single.building_ids) + 1
    assert load_city(tmp_path / "store").num_triangles == single.num_triangles + 12
    # the tile cache's budget: SEMCITYLOC_TILE_BUDGET_MB, for every command and worker alike
    assert TileStore.open(tmp_path / "store").cache.budget_bytes == int(DEFAULT_BUDGET_MB * 1e6)
    monkeypatch.setenv(BUDGET_ENV, "64")
    assert TileStore.open(tmp_path / "store").cache.budget_bytes == 64_000_000
    monkeypatch.setenv(BUDGET_ENV, "lots")
    assert main(["city", "info", str(tmp_path / "store")]) == 2
    assert BUDGET_ENV in capsys.readouterr().err


def test_a_broken_or_empty_tile_is_left_out_naming_it_and_the_rest_is_built(tmp_path, capsys):
    """A geoportal folder with a truncated tile and a tile without buildings (water, forest): the build
    used to stop at the first one; now each is left out with its reason (stderr, store.json) and the
    others make the store. A folder of nothing readable is one typed line."""
    tiles = tmp_path / "tiles"
    tiles.mkdir()
    gml = generate_city(tmp_path / "gen", seed=2, lods=(2,))[2]
    (tiles / "a.gml").write_bytes(gml.read_bytes())
    (tiles / "broken.gml").write_bytes(gml.read_bytes()[:5000])  # cut mid-element
    water = {"type": "CityJSON", "version": "1.1", "transform": {"scale": [1, 1, 1], "translate": [0, 0, 0]}}
    (tiles / "water.json").write_text(json.dumps({**water, "CityObjects": {}, "vertices": []}))
    (tiles / "empty.json").write_bytes(b"")  # a failed download: passed over without a word before stop 50
    (tiles / "notes.txt").write_bytes(b"")  # named like no model: not a tile
    assert main(["tiles", "build", str(tiles), "--out", str(tmp_path / "store")]) == 0
    out, err = capsys.readouterr()
    assert "1 tile, " in out and "3 tiles left out" in out and "1 tiles" not in out
    assert (
        err.count("semcityloc: warning: tile left out:") == 3 and "broken.gml" in err and "water.json" in err
    )
    assert "empty.json: the file is empty" in err and "notes.txt" not in err
    index = json.loads((tmp_path / "store" / "store.json").read_text())
    assert set(index["skipped_tiles"]) == {"broken.gml", "water.json", "empty.json"}
    store = TileStore.open(tmp_path / "store")
    assert [t.name for t in store.tiles] == ["a.gml"]
    assert store.num_buildings == len(load_city_model(gml, cache=False).building_ids)
    assert store.summary()["skipped_tiles"] == ["broken.gml", "empty.json", "water.json"]
    (tiles / "a.gml").unlink()
    assert main(["tiles", "build", str(tiles), "--out", str(tmp_path / "store2")]) == 2
    err = capsys.readouterr().err
    last = err.splitlines()[-1]  # the error on its own line, after the progress line (was appended to it)
    assert last.startswith("semcityloc: error:") and "no tile can be read (3 tried" in last


def test_a_zip_archive_in_the_folder_is_named_not_passed_over(tmp_path, capsys):
    """Geoportals ship tiles zipped. A folder of archives gave "no CityGML or CityJSON files in it", and an
    archive beside extracted tiles was passed over silently: now each is left out naming what it holds."""
    tiles = tmp_path / "tiles"
    tiles.mkdir()
    gml = generate_city(tmp_path / "gen", seed=2, lods=(2,))[2]
    with zipfile.ZipFile(tiles / "east.zip", "w", zipfile.ZIP_DEFLATED) as z:
        z.write(gml, "east/tile.gml")
    assert main(["tiles", "build", str(tiles), "--out", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert "no tile can be read (1 tried" in err and "a ZIP archive" in err and "east/tile.gml" in err
    (tiles / "west.gml").write_bytes(gml.read_bytes())
    assert main(["tiles", "build", str(tiles), "--out", str(tmp_path / "store")]) == 0
    out, err = capsys.readouterr()
    assert "1 tile left out" in out and "tile left out:" in err and "east.zip: a ZIP archive" in err
    assert [t.name for t in TileStore.open(tmp_path / "store").tiles] == ["west.gml"]


def test_merged_tiles_keep_their_readers_warnings_naming_the_file(tmp_path):
    """A skipped roof in one tile must show like one in a single file: the counts were summed, the warnings
    dropped (noticed at stop 45)."""
    gml = generate_city(tmp_path / "gen", seed=2, lods=(2,))[2]
    a, b = load_city_model(gml, cache=False), load_city_model(gml, cache=False)
    a.stats.warnings.append("skipped 6 polygons with NaN coordinates")
    merged = merge_models([a, b])
    assert f"{gml.name}: skipped 6 polygons with NaN coordinates" in merged.stats.warnings
    assert len(merged.stats.warnings) == len(a.stats.warnings) + len(b.stats.warnings)


def _city_and_a_box(tmp_path: Path, seed: int, east_m: float) -> Path:
    """A folder of two tiles: a generated city (``a.gml``) and one CityJSON box ``east_m`` east of it."""
    tiles = tmp_path / "tiles"
    tiles.mkdir()
    gml = generate_city(tmp_path / "gen", seed=seed, lods=(2,))[2]
    (tiles / "a.gml").write_bytes(gml.read_bytes())
    far = load_city_model(gml, cache=False).origin + [east_m, 0.0, 0.0]
    _cityjson_box(tiles / "b.json", 25832, far[0], far[1])
    return tiles


@pytest.mark.slow
def test_benchmark_on_a_store_loads_per_query(tmp_path, capsys, monkeypatch):
    """``semcityloc benchmark --city STORE``: the simulator sees the whole city, the localizer its part;
    the run opens the store once (the simulator's merged city is made from the localizer's store)."""
    tiles = _city_and_a_box(tmp_path, seed=0, east_m=600.0)
    store = tmp_path / "store"
    assert main(["tiles", "build", str(tiles), "--out", str(store)]) == 0
    out = tmp_path / "run"
    opened = []
    real_open = TileStore.open.__func__
    monkeypatch.setattr(
        TileStore, "open", classmethod(lambda cls, *a, **k: opened.append(a) or real_open(cls, *a, **k))
    )
    args = ["benchmark", "--city", str(store), "--queries", "2", "--preset", "fast", "--out", str(out)]
    assert main(args) == 0
    assert len(opened) == 1
    rows = read_results(out / "results.csv")
    assert len(rows) == 2 and all(r["status"] in ("localized", "not_localized") for r in rows)
    assert json.loads((out / "run.json").read_text())["city_sha256"] == TileStore.open(store).sha256


def test_tiles_in_different_crss_are_refused(tmp_path):
    tiles = tmp_path / "tiles"
    tiles.mkdir()
    _cityjson_box(tiles / "a.json", 25832, 390000.0, 5810000.0)
    _cityjson_box(tiles / "b.json", 25833, 390000.0, 5810000.0)
    with pytest.raises(CRSError, match=r"different CRSs.*a\.json: EPSG:25832.*b\.json: EPSG:25833"):
        build_store(tiles, tmp_path / "store")
    assert main(["tiles", "build", str(tiles), "--out", str(tmp_path / "s2")]) == 2


def test_the_same_buildings_in_two_tiles_are_said(tmp_path, capsys):
    """Den Haag's .json beside its .xml (the same area, the same ids) or a copied tile made a store holding
    every building twice (2 tiles, 1688 buildings for 844), without a word."""
    tiles = tmp_path / "tiles"
    tiles.mkdir()
    gml = generate_city(tmp_path / "gen", seed=2, lods=(2,))[2]
    (tiles / "a.gml").write_bytes(gml.read_bytes())
    (tiles / "copy of a.gml").write_bytes(gml.read_bytes())
    assert main(["tiles", "build", str(tiles), "--out", str(tmp_path / "store")]) == 0
    err = capsys.readouterr().err
    n = len(load_city_model(gml, cache=False).building_ids)
    assert (
        f"{n} building ids appear in more than one tile ({n} of them in both a.gml and copy of a.gml)" in err
    )
    (tiles / "copy of a.gml").unlink()
    assert main(["tiles", "build", str(tiles), "--out", str(tmp_path / "store2")]) == 0
    assert "more than one tile" not in capsys.readouterr().err


def test_a_store_is_not_replaced_without_overwrite_and_a_rebuild_leaves_no_old_tiles(tmp_path, capsys):
    """``tiles build`` into a store's folder replaced it silently (an hour's build lost to a typo), and a
    rebuild from fewer tiles left the old build's npz files beside the new index."""
    tiles = _city_and_a_box(tmp_path, seed=2, east_m=20000.0)
    store = tmp_path / "store"
    assert main(["tiles", "build", str(tiles), "--out", str(store)]) == 0
    capsys.readouterr()
    before = (store / "store.json").read_bytes()
    (tiles / "b.json").unlink()
    assert main(["tiles", "build", str(tiles), "--out", str(store)]) == 2
    err = capsys.readouterr().err
    assert "holds a tile store already" in err and "--overwrite" in err and err.count("\n") == 1
    assert (store / "store.json").read_bytes() == before
    with pytest.raises(OutputPathError, match="overwrite=True"):
        build_store(tiles, store)
    assert main(["tiles", "build", str(tiles), "--out", str(store), "--overwrite"]) == 0
    assert [t.name for t in TileStore.open(store).tiles] == ["a.gml"]
    assert sorted(p.name for p in (store / "tiles").iterdir()) == ["00000.npz"]
    for inside in (tiles, tmp_path):  # --out the tiles' own folder or one above: "no files in it" before
        assert main(["tiles", "build", str(tiles), "--out", str(inside)]) == 2
        assert "would hold the tiles it is built from" in capsys.readouterr().err
    (store / "store.json").unlink()  # a build stopped before its index: still refused, said so
    assert main(["tiles", "build", str(tiles), "--out", str(store)]) == 2
    assert "part of a tile store (a build stopped?)" in capsys.readouterr().err
    # ... and given as --city it says so, not "no such city model file or tile store" (batch audit, stop 51)
    for argv in (["benchmark", "--city", str(store), "--queries", "1", "--out", str(tmp_path / "b")],
                 ["city", "info", str(store)]):  # fmt: skip
        assert main(argv) == 2
        assert "a tile store whose build stopped before its store.json" in capsys.readouterr().err

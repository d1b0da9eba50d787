"""A tile store's LoD, its output folder and its damaged files (audit A of stop 56, items 5, 6, 14-17):
small stores of one-box CityJSON tiles, built in well under a second."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from semcityloc.benchmark.spec import open_tile_store
from semcityloc.citymodel.model import CityModel
from semcityloc.citymodel.tiles import TileStore, build_store, load_city, open_store
from semcityloc.cli.main import main
from semcityloc.errors import InputFileError, LodNotHeldError, OutputPathError

SHELL = [[[0, 3, 2, 1]], [[4, 5, 6, 7]], [[0, 1, 5, 4]], [[1, 2, 6, 5]], [[2, 3, 7, 6]], [[3, 0, 4, 7]]]
BOX = [[0, 0, 0], [10, 0, 0], [10, 8, 0], [0, 8, 0], [0, 0, 9], [10, 0, 9], [10, 8, 9], [0, 8, 9]]


def box_tile(path: Path, lod: str, east_m: float = 0.0, name: str = "B1") -> Path:
    """One CityJSON building (a 10 x 8 x 9 m box, EPSG:25832) at LoD ``lod``, ``east_m`` east."""
    geometry = {
        "type": "Solid",
        "lod": lod,
        "boundaries": [SHELL],
        "semantics": {
            "surfaces": [{"type": "GroundSurface"}, {"type": "RoofSurface"}, {"type": "WallSurface"}],
            "values": [[0, 1, 2, 2, 2, 2]],
        },
    }
    doc = {
        "type": "CityJSON",
        "version": "2.0",
        "metadata": {"referenceSystem": "https://www.opengis.net/def/crs/EPSG/0/25832"},
        "transform": {"scale": [0.001, 0.001, 0.001], "translate": [390000.0 + east_m, 5810000.0, 40.0]},
        "CityObjects": {name: {"type": "Building", "geometry": [geometry]}},
        "vertices": [[v * 1000 for v in p] for p in BOX],
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc))
    return path


def cli(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_a_tile_without_the_asked_lod_refuses_the_build_naming_it(tmp_path, capsys):
    """``tiles build --lod 2`` over a geoportal mixing LoD1 and LoD2 tiles left the LoD1 tile out as if it
    were malformed and exited 0: a hole in the city. A tile with buildings at other LoDs is refused, as a
    single file without the LoD is, naming it and the LoDs it holds; malformed tiles are still left out."""
    tiles = tmp_path / "tiles"
    box_tile(tiles / "a.json", "1", name="A")
    box_tile(tiles / "b.json", "2", east_m=50.0, name="B")
    (tiles / "broken.json").write_text("{")
    with pytest.raises(
        LodNotHeldError, match=r"1 tile of 3 holds no LoD 2 building geometry \(a\.json: LoDs 1\)"
    ):
        build_store(tiles, tmp_path / "store", lod=2)
    code, out, err = cli(capsys, "tiles", "build", tiles, "--out", tmp_path / "s2", "--lod", "2")
    last = err.splitlines()[-1]
    assert code == 2 and last.startswith("semcityloc: error:") and "a.json: LoDs 1" in last
    assert "holes in the city" in last and "--lod N" in last and "left out" not in err.replace(last, "")
    assert not (tmp_path / "s2" / "store.json").exists()
    report = build_store(tiles, tmp_path / "s3")  # each building's highest: both, the broken one left out
    assert report.tiles == 2 and list(report.skipped) == ["broken.json"]


def test_a_store_takes_a_cityjson_refinement_as_render_does(tmp_path, capsys):
    """``tiles build --lod`` took whole numbers only (``invalid int value: '2.2'``) though ``--city FILE
    --lod 2.2`` reads a CityJSON file's LoD 2.2: one parser for both."""
    tiles = tmp_path / "tiles"
    box_tile(tiles / "a.json", "2.2")
    code, out, err = cli(capsys, "tiles", "build", tiles, "--out", tmp_path / "store", "--lod", "2.2")
    assert code == 0, err
    assert TileStore.open(tmp_path / "store").lod == "2.2"
    assert cli(capsys, "city", "info", tmp_path / "store", "--lod", "2.2", "--json")[0] == 0
    code, _, err = cli(capsys, "tiles", "build", tiles, "--out", tmp_path / "s2", "--lod", "seven")
    assert code == 2 and "--lod 'seven' is not a LoD" in err


def test_a_store_holds_the_lod_every_tile_was_read_at_one_rule_for_every_command(tmp_path, capsys):
    """A store built at each building's highest LoD refused ``--lod 2`` when every tile is LoD2 (``the store
    was built with lod=None``), and the benchmark's store opener and ``--city`` disagreed. Each tile's LoDs
    are recorded; a LoD every tile holds alone is taken, one no tile holds is refused as a single file
    without it is, a LoD held beside others asks for a build at it: the same by every path."""
    tiles = tmp_path / "tiles"
    box_tile(tiles / "a.json", "2", name="A")
    box_tile(tiles / "b.json", "2", east_m=50.0, name="B")
    store = tmp_path / "store"
    build_store(tiles, store)
    assert [t.lods for t in TileStore.open(store).tiles] == [(2,), (2,)]
    assert open_store(store, lod=2).lod is None and open_tile_store(store, 2) is not None
    assert len(load_city(store, lod=2).building_ids) == 2
    assert cli(capsys, "city", "info", store, "--lod", "2", "--json")[0] == 0
    for opener in (lambda: open_store(store, lod=3), lambda: open_tile_store(store, 3)):
        with pytest.raises(
            LodNotHeldError, match="no LoD 3 building geometry; LoDs present: 2 .*highest LoD"
        ):
            opener()
    code, _, err = cli(capsys, "city", "info", store, "--lod", "1")
    assert code == 2 and "no LoD 1 building geometry; LoDs present: 2" in err and "None" not in err
    box_tile(tiles / "c.json", "1", east_m=100.0, name="C")
    mixed = tmp_path / "mixed"
    build_store(tiles, mixed)
    with pytest.raises(InputFileError, match=r"each building's highest LoD \(its tiles hold LoDs 1, 2\)"):
        open_store(mixed, lod=2)
    code, out, _ = cli(capsys, "tiles", "info", mixed)
    assert code == 0 and "lod:           each building's highest" in out and "lods:          1, 2" in out


def test_a_store_is_not_built_into_a_folder_of_other_files_nor_from_a_file(tmp_path, capsys):
    """``tiles build --out DIR`` wrote into a folder of the user's files (or a benchmark run, with
    ``--overwrite``) without a word, and ``tiles build FILE.gml`` said "no such folder of tiles"."""
    tiles = tmp_path / "tiles"
    box_tile(tiles / "a.json", "2")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    (mine / "results.csv").write_text("")
    for overwrite in (False, True):
        with pytest.raises(OutputPathError, match=r"not empty and not a tile store \(it holds notes\.txt"):
            build_store(tiles, mine, overwrite=overwrite)
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt", "results.csv"]
    code, _, err = cli(capsys, "tiles", "build", tiles, "--out", tmp_path / "mine", "--overwrite")
    assert code == 2 and "results.csv" in err and err.count("\n") == 1
    (tmp_path / "afile").write_text("x")
    with pytest.raises(OutputPathError, match="a file, not a folder"):
        build_store(tiles, tmp_path / "afile")
    code, _, err = cli(capsys, "tiles", "build", tiles / "a.json", "--out", tmp_path / "s")
    assert (
        code == 2 and "a.json: a file, not a folder of tiles" in err and f"--city {tiles / 'a.json'}" in err
    )
    assert cli(capsys, "tiles", "build", tiles, "--out", tmp_path / "store")[0] == 0  # a new folder
    (tmp_path / "hidden").mkdir()
    (tmp_path / "hidden" / ".DS_Store").write_text("")  # a file manager's: no one's work
    assert cli(capsys, "tiles", "build", tiles, "--out", tmp_path / "hidden")[0] == 0
    assert cli(capsys, "tiles", "build", tiles, "--out", tmp_path / "store", "--overwrite")[0] == 0


def test_a_damaged_store_says_what_is_wrong_and_tiles_info_checks_the_tile_files(tmp_path, capsys):
    """A text file in place of a tile was said to hold "pickled objects", a missing one to be "damaged, or
    another program's: [Errno 2]", ``tiles info`` passed both, and printed ``skipped_tiles:2`` unnamed."""
    tiles = tmp_path / "tiles"
    box_tile(tiles / "a.json", "2")
    water = {"type": "CityJSON", "version": "1.1", "transform": {"scale": [1, 1, 1], "translate": [0, 0, 0]}}
    (tiles / "water.json").write_text(json.dumps({**water, "CityObjects": {}, "vertices": []}))
    store = tmp_path / "store"
    build_store(tiles, store)
    code, out, _ = cli(capsys, "tiles", "info", store)
    assert code == 0 and "skipped_tiles: 1 (water.json)" in out
    assert json.loads(cli(capsys, "tiles", "info", store, "--json")[1])["skipped_tiles"] == ["water.json"]
    npz = store / "tiles" / "00000.npz"
    npz.write_text("not a tile\n")
    code, _, err = cli(capsys, "city", "info", store)
    assert code == 2 and "no npz (ZIP) file: text" in err and "pickled" not in err and "a.json" in err
    npz.write_bytes(b"")
    with pytest.raises(InputFileError, match="the file is empty"):
        CityModel.load_npz(npz)  # was numpy's EOFError
    npz.unlink()
    for argv in (["tiles", "info", store], ["city", "info", store]):
        code, _, err = cli(capsys, *argv)
        assert code == 2 and err.count("\n") == 1, err
        assert "1 tile file missing (tiles/00000.npz of a.json)" in err and "--overwrite" in err
        assert "Errno" not in err and "another program" not in err

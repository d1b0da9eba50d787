"""load_city_model: format sniffing and the npz parse cache keyed by file content and options."""

from __future__ import annotations

import hashlib
import zipfile

import numpy as np
import pytest

from semcityloc.citymodel import io
from semcityloc.citymodel.generator import generate_city
from semcityloc.errors import InputFileError, UnsupportedFormatError
from semcityloc.io import stamps


@pytest.fixture(scope="module")
def lod2(tmp_path_factory):
    return generate_city(tmp_path_factory.mktemp("gen"), seed=0, lods=(2,))[2]


def test_second_load_comes_from_the_cache(lod2, tmp_path, monkeypatch):
    first = io.load_city_model(lod2, cache=tmp_path)
    assert len(list(tmp_path.glob("*.npz"))) == 1

    def no_parsing(*args, **kwargs):
        raise AssertionError("parsed again although the cache holds this file")

    monkeypatch.setattr(io, "_read", no_parsing)
    second = io.load_city_model(lod2, cache=tmp_path)
    for name in ("origin", "vertices", "triangles", "classes", "building_index", "lods"):
        np.testing.assert_array_equal(getattr(second, name), getattr(first, name))
    assert second.crs == first.crs and second.source == str(lod2)


def test_a_numpy_integer_lod_is_cached_as_the_same_lod(lod2, tmp_path):
    """A LoD from a numpy array (np.int64) failed to write the cache key (JSON); it is LoD 2's key."""
    io.load_city_model(lod2, lod=np.int64(2), cache=tmp_path)
    io.load_city_model(lod2, lod=2, cache=tmp_path)
    assert len(list(tmp_path.glob("*.npz"))) == 1


def test_other_options_or_content_miss_the_cache(lod2, tmp_path):
    io.load_city_model(lod2, cache=tmp_path)
    io.load_city_model(lod2, cache=tmp_path, crs="EPSG:25833")
    assert len(list(tmp_path.glob("*.npz"))) == 2
    changed = tmp_path / "other" / lod2.name  # same file name, one comment more
    changed.parent.mkdir()
    changed.write_bytes(lod2.read_bytes() + b"<!-- edited -->\n")
    io.load_city_model(changed, cache=tmp_path)
    assert len(list(tmp_path.glob("*.npz"))) == 3


def test_a_corrupt_cache_file_is_replaced(lod2, tmp_path):
    io.load_city_model(lod2, cache=tmp_path)
    (cached,) = tmp_path.glob("*.npz")
    cached.write_bytes(b"not an npz")
    model = io.load_city_model(lod2, cache=tmp_path)
    assert model.num_triangles > 0
    assert io.load_city_model(cached).num_triangles == model.num_triangles  # rewritten, readable


def test_sniffing_errors(tmp_path):
    (tmp_path / "empty.gml").write_bytes(b"")
    with pytest.raises(InputFileError):
        io.load_city_model(tmp_path / "empty.gml", cache=False)
    (tmp_path / "x.bin").write_bytes(b"\x89PNG\r\n")
    with pytest.raises(UnsupportedFormatError):
        io.load_city_model(tmp_path / "x.bin", cache=False)
    with pytest.raises(InputFileError, match="missing.gml: no such file"):
        io.load_city_model(tmp_path / "missing.gml")
    (tmp_path / "tiles").mkdir()  # stop 45's audit: a folder was called "no such file"
    with pytest.raises(InputFileError, match="tiles: a folder, not a city model file"):
        io.load_city_model(tmp_path / "tiles")


def test_a_zip_archive_is_refused_naming_the_city_models_inside(lod2, tmp_path):
    """Geoportals ship tiles as ZIP archives; handed over as they come, one gave "not CityGML, CityJSON or
    OBJ (starts with b'PK...')". Now the message says it is an archive and which model files it holds (its
    listing only: nothing is decompressed), and tells what to do."""
    archive = tmp_path / "tile.zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        z.write(lod2, f"LoD2/{lod2.name}")
        z.writestr(f"__MACOSX/LoD2/._{lod2.name}", b"\x00resource fork")
        z.writestr("LoD2/readme.txt", "terms of use")
    with pytest.raises(
        UnsupportedFormatError,
        match=rf"a ZIP archive, not a city model file; it holds LoD2/{lod2.name}: extract",
    ):
        io.load_city_model(archive, cache=False)
    empty = tmp_path / "docs.zip"
    with zipfile.ZipFile(empty, "w") as z:
        z.writestr("readme.txt", "nothing")
    with pytest.raises(UnsupportedFormatError, match="a ZIP archive without a CityGML, CityJSON or OBJ file"):
        io.load_city_model(empty, cache=False)
    (tmp_path / "cut.zip").write_bytes(b"PK\x03\x04" + b"\x00" * 20)  # a download cut short
    with pytest.raises(UnsupportedFormatError, match="a damaged ZIP archive"):
        io.load_city_model(tmp_path / "cut.zip", cache=False)


def test_a_file_is_hashed_once_until_it_changes(tmp_path, monkeypatch):
    # as a file written a while ago: one written within ``RACY_S`` is read each time (test_io_stamps)
    monkeypatch.setattr(stamps, "RACY_S", 0.0)
    path = tmp_path / "city.gml"
    path.write_bytes(b"<CityModel/>\n")
    first = io.file_sha256(path)
    reads = []
    real_open = open

    def counting_open(file, *args, **kwargs):
        reads.append(file)
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr("builtins.open", counting_open)
    assert io.file_sha256(path) == first and io.file_sha256(str(path)) == first
    assert reads == []  # unchanged: the hash of the first read
    path.write_bytes(b"<CityModel>edited</CityModel>\n")  # new size and modification time
    changed = io.file_sha256(path)
    assert reads == [path] and changed != first
    assert changed == hashlib.sha256(path.read_bytes()).hexdigest()


def test_a_npz_of_pickled_objects_is_named_damaged_not_explained_in_numpys_words(tmp_path):
    """A tile npz of another program (pickled objects) gave numpy's advice on ``allow_pickle``."""
    from semcityloc.citymodel.model import CityModel

    path = tmp_path / "00000.npz"
    np.savez(path, meta=np.array([{"a": 1}], dtype=object))
    with pytest.raises(
        InputFileError,
        match=r"not a semcityloc city-model npz \(damaged, or another program's: it holds pickled objects\)",
    ):
        CityModel.load_npz(path)

"""``benchmark.code_version``: the source fingerprint that keys the tuning scripts' caches."""

from __future__ import annotations

from semcityloc.benchmark import code_version


def test_fingerprint_follows_the_sources_it_covers(tmp_path, monkeypatch):
    (tmp_path / "localization").mkdir()
    (tmp_path / "render").mkdir()
    (tmp_path / "localization" / "refine.py").write_text("a = 1\n")
    (tmp_path / "render" / "raster.py").write_text("b = 1\n")
    monkeypatch.setattr(code_version, "PACKAGE_ROOT", tmp_path)
    full = code_version.code_fingerprint()
    sim = code_version.code_fingerprint(exclude=("localization",))
    assert len(full) == 16 and full != sim
    (tmp_path / "localization" / "refine.py").write_text("a = 2\n")
    assert code_version.code_fingerprint() != full  # any change re-keys the full fingerprint
    assert code_version.code_fingerprint(exclude=("localization",)) == sim  # not the simulation's
    (tmp_path / "render" / "raster.py").write_text("b = 2\n")
    assert code_version.code_fingerprint(exclude=("localization",)) != sim
    (tmp_path / "render" / "raster.py").rename(tmp_path / "render" / "moved.py")
    renamed = code_version.code_fingerprint(exclude=("localization",))
    (tmp_path / "render" / "moved.py").rename(tmp_path / "render" / "raster.py")
    assert renamed != code_version.code_fingerprint(exclude=("localization",))  # paths count too


def test_fingerprint_of_the_installed_package_is_stable():
    assert code_version.code_fingerprint() == code_version.code_fingerprint()

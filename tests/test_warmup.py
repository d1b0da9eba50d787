"""``benchmark/warmup.py``: kernels compiled from older sources are never reused. numba keys a cached kernel
by its own file, so the localizer's scoring kernels kept their inlined copy of an edited rasteriser; the
warm-up stamps the caches with the sources' fingerprint and recompiles everything when it differs."""

from __future__ import annotations

import types

from semcityloc.benchmark import warmup as W


class _FakeKernel:
    """Stands in for a cached numba dispatcher: where its cache lives, and whether it was recompiled."""

    def __init__(self, cache_dir):
        self._cache = types.SimpleNamespace(_cache_path=str(cache_dir))
        self.__name__ = "fake_kernel"
        self.recompiled = 0

    def recompile(self):
        self.recompiled += 1


def test_a_changed_kernel_source_recompiles_every_kernel(monkeypatch, tmp_path):
    fakes = [_FakeKernel(tmp_path), _FakeKernel(tmp_path)]
    monkeypatch.setattr(W, "cached_kernels", lambda groups=None: fakes)
    monkeypatch.setattr(W, "_has_cache_entry", lambda kernel: True)  # every kernel has a cached version
    stamp = tmp_path / W.STAMP_NAME
    assert W.sources_match_cache() is False and not W.kernels_cached()  # compiled outside the warm-up
    stamp.write_text(W.sources_fingerprint() + "\n")
    assert W.sources_match_cache() is True and W.kernels_cached()
    stamp.write_text("the fingerprint of an older rasteriser\n")
    assert not W.kernels_cached()
    W.warm_up()
    assert [k.recompiled for k in fakes] == [1, 1]
    assert stamp.read_text().strip() == W.sources_fingerprint() and W.kernels_cached()
    W.warm_up()  # the sources did not change: nothing is dropped
    assert [k.recompiled for k in fakes] == [1, 1]


def test_the_fingerprint_follows_every_kernel_module_and_the_class_ids(monkeypatch, tmp_path):
    before = W.sources_fingerprint()
    assert before == W.sources_fingerprint() and len(before) == 64
    module = tmp_path / "some_baked_in_constants.py"
    module.write_text("IGNORE = 255\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(W, "BAKED_IN_MODULES", (*W.BAKED_IN_MODULES, "some_baked_in_constants"))
    with_module = W.sources_fingerprint()
    module.write_text("IGNORE = 254\n")
    assert len({before, with_module, W.sources_fingerprint()}) == 3
    assert "semcityloc.classes" in W.BAKED_IN_MODULES
    assert {"semcityloc.render.raster_numba", "semcityloc.localization.kernels"} <= {
        m for ms in W.KERNEL_GROUPS.values() for m in ms
    }

"""The one table of methods by name (``benchmark.methods``): every method is known whatever was imported
before (audit s51, finding 1: the baselines used to join the table only when something imported
``semcityloc.baselines`` first)."""

from __future__ import annotations

import json
import subprocess
import sys
from types import SimpleNamespace

import pytest

from semcityloc.baselines import BASELINES
from semcityloc.benchmark.methods import (
    METHODS,
    available_methods,
    check_method,
    method_factory,
    searched_map,
)
from semcityloc.benchmark.warmup import box_city_obj
from semcityloc.citymodel.io import load_city_model
from semcityloc.errors import BenchmarkError, ParameterError
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.methods import ABLATIONS
from semcityloc.localization.tiled import TiledMethod


def _fresh(code: str) -> str:
    """``code`` run in a new interpreter (so no import of this test session can hide a missing method);
    its stdout. The code imports only the module under test."""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout


def test_a_spec_knows_the_baselines_when_only_the_spec_is_imported(tmp_path):
    city = tmp_path / "x.gml"
    city.write_text("<CityModel/>", encoding="utf-8")  # run_config hashes the file, loads no model
    code = (
        "import json\n"
        "from semcityloc.benchmark.spec import BenchmarkSpec\n"
        "from semcityloc.benchmark.queries import QueryConfig\n"
        "out = {}\n"
        "for m in ('silhouette', 'lodloc-wireframe'):\n"
        f"    out[m] = BenchmarkSpec({str(city)!r}, QueryConfig(), method=m).run_config()['searched_map']\n"
        "print(json.dumps(out))\n"
    )
    searched = json.loads(_fresh(code))
    assert searched["silhouette"] == {"eaves_m": 0.5, "flat_roofs": "auto"}  # the localizer's map
    assert searched["lodloc-wireframe"] == {"eaves_m": 0.0, "flat_roofs": "off"}  # the model as it is


def test_the_table_lists_every_method_when_imported_alone():
    code = (
        "import json\n"
        "from semcityloc.benchmark.methods import available_methods, searched_map\n"
        "from semcityloc.localization.config import LocalizerConfig\n"
        "print(json.dumps([available_methods(), searched_map('lodloc-wireframe', LocalizerConfig())]))\n"
    )
    names, wireframe = json.loads(_fresh(code))
    assert names == [*ABLATIONS, *BASELINES]
    assert wireframe == {"eaves_m": 0.0, "flat_roofs": "off"}


def test_found_map_reads_an_old_wireframe_run_when_imported_alone():
    """A run from before ``searched_map`` was recorded: its method's map, the wireframe's too."""
    code = (
        "from semcityloc.benchmark.found_map import run_searched_map\n"
        "print(run_searched_map({'method': 'lodloc-wireframe', 'localizer': {'map_eaves_m': 0.5}}))\n"
    )
    assert _fresh(code).strip() == "{'eaves_m': 0.0, 'flat_roofs': 'off'}"


def test_unknown_method_is_one_line_naming_every_known_one():
    with pytest.raises(
        BenchmarkError, match="unknown method 'nope'; known: semcityloc, .*, lodloc-wireframe$"
    ):
        check_method("nope")
    with pytest.raises(BenchmarkError, match="unknown method"):
        searched_map("nope", LocalizerConfig())
    assert set(METHODS) == set(available_methods()) == {*ABLATIONS, *BASELINES}


class _Store:
    """What ``TiledMethod.method_for`` reads of a tile store."""

    def __init__(self, model):
        self.model = model
        self.terrain_ring = None

    def load(self, tiles):
        return self.model


def test_a_tiled_run_builds_a_baseline_with_its_factory(tmp_path):
    path = tmp_path / "box.obj"
    path.write_text(box_city_obj(), encoding="utf-8")
    model = load_city_model(path, cache=False)
    built = []

    def factory(name, map_model, config):
        built.append((name, map_model))
        return SimpleNamespace(name=name)

    tiled = TiledMethod("silhouette", _Store(model), LocalizerConfig.preset("fast"), factory=factory)
    assert tiled.method_for((0,)).name == "silhouette" and built == [("silhouette", model)]
    assert TiledMethod("silhouette", _Store(model), factory=method_factory("silhouette")).factory is not None
    with pytest.raises(ParameterError, match="unknown localizer method 'silhouette'; known: semcityloc"):
        TiledMethod("silhouette", _Store(model))  # no factory: SemCityLoc and its ablations only

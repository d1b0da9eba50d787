"""The tuning discipline's cities (``benchmark.calibration``): generated and Fürth may be tuned on,
nothing else; the tuning scripts share it, and its cached measuring of a condition."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest

from conftest import REPO
from semcityloc.benchmark.calibration import (
    FUERTH_FILE,
    calibration_cities,
    condition_rows,
    is_calibration_city,
    require_calibration_cities,
)
from semcityloc.errors import ParameterError


@pytest.fixture
def shared_data(tmp_path):
    """A stand-in shared data folder holding a file where Fürth lives (its content is not read)."""
    fuerth = tmp_path / "data" / FUERTH_FILE
    fuerth.parent.mkdir(parents=True)
    fuerth.write_text("<CityModel/>")
    return tmp_path / "data"


def test_calibration_cities_are_generated_and_fuerth_when_present(shared_data, tmp_path):
    assert calibration_cities(shared_data) == ["generated", str(shared_data / FUERTH_FILE)]
    assert calibration_cities(tmp_path / "nowhere") == ["generated"]


def test_fuerth_counts_by_any_path_to_it_and_other_cities_do_not(shared_data, tmp_path, monkeypatch):
    monkeypatch.chdir(shared_data)
    assert is_calibration_city("generated", shared_data)
    assert is_calibration_city(str(FUERTH_FILE), shared_data)  # relative to the working directory
    link = tmp_path / "fuerth_link.gml"
    os.symlink(shared_data / FUERTH_FILE, link)
    assert is_calibration_city(link, shared_data)
    berlin = tmp_path / "3910_5817.gml"
    shutil.copy(shared_data / FUERTH_FILE, berlin)  # same content, another city: refused
    assert not is_calibration_city(berlin, shared_data)
    assert not is_calibration_city(tmp_path / "missing.gml", shared_data)


def test_require_names_the_city_and_the_purpose(shared_data, tmp_path):
    require_calibration_cities(calibration_cities(shared_data), shared_data, "tune a knob")
    berlin = tmp_path / "berlin.gml"
    berlin.write_text("<x/>")
    with pytest.raises(ParameterError, match=r"berlin\.gml is not a calibration city.*fit the confidence"):
        require_calibration_cities(["generated", berlin], shared_data, "fit the confidence model")


@pytest.mark.parametrize(
    "script, args",
    [
        ("calibrate_segmentation.py", ["--city"]),
        ("calibrate_confidence.py", ["--fit-city"]),
        ("calibrate_covariance.py", ["--fit-city"]),
    ],
)
def test_the_calibration_scripts_refuse_a_reporting_city(script, args, tmp_path):
    berlin = tmp_path / "berlin.gml"
    berlin.write_text("<x/>")
    out = subprocess.run(
        [sys.executable, str(REPO / "benchmarks" / script), *args, str(berlin)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2, out.stderr
    assert "not a calibration city" in out.stderr


_SETUP: dict = {}


def _toy_init(city: str, seed: int, queries: int, condition: str) -> None:
    _SETUP.update(city=city, seed=seed, condition=condition)


def _toy_one(index: int) -> list[dict]:
    return [{"index": index, "condition": _SETUP["condition"], "seed": _SETUP["seed"]}] * (index % 2)


def _must_not_run(index: int) -> list[dict]:
    raise AssertionError("cached rows were measured again")


def test_condition_rows_are_measured_in_workers_and_reused_from_the_cache(tmp_path):
    args = ("x_", "generated", 3, 4, "trained", 2, tmp_path)
    rows = condition_rows(*args, _toy_init, _toy_one)
    assert rows == [{"index": i, "condition": "trained", "seed": 3} for i in (1, 3)]
    (cached,) = tmp_path.glob("x_generated_trained_3_4_*.json")
    assert json.loads(cached.read_text()) == rows
    assert condition_rows(*args, _toy_init, _must_not_run) == rows

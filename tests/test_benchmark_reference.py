"""The benchmark's rows are the same as those the code wrote before the issue-11 restructuring.

``tests/data/reference/*_rows.csv`` were written by the code as it was before the run loop, the method
table and the frame names were reshaped (3 queries, seed 0, every method, the then ``default`` preset,
now ``legacy``: the first design is kept unchanged beside the issue-13 search; timing columns dropped).
A change of any status, reason or number in these rows is a change of behaviour: if it is intended,
regenerate the files and say why in the commit.

Numbers are compared to 1e-9 relative, not to the last bit: the old localizers re-composed a local prior
through a zero shift (``prior.shift_world(np.zeros(3))``, a float64 round trip of R and t), which the
frame-named API no longer does; that moves estimates by up to ~5e-10 relative (measured) and nothing else.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import pytest

from semcityloc.benchmark.dataset_source import DatasetSpec
from semcityloc.benchmark.queries import QueryConfig
from semcityloc.benchmark.results import TIMING_COLUMNS
from semcityloc.benchmark.run import run_benchmark
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.localization.methods import ABLATIONS

REFERENCE = Path(__file__).parent / "data" / "reference"
METHODS = (*ABLATIONS, "silhouette", "lodloc-wireframe")


def reference_rows(name: str) -> dict[tuple[str, str], dict[str, str]]:
    with open(REFERENCE / f"{name}_rows.csv", newline="", encoding="utf-8") as fh:
        return {(r["method"], r["query_id"]): r for r in csv.DictReader(fh)}


def run_rows(city: str, tmp_path: Path) -> dict[tuple[str, str], dict[str, str]]:
    rows = {}
    for method in METHODS:
        spec = BenchmarkSpec(
            city=city, query=QueryConfig(queries=3, seed=0), method=method, preset="legacy", keep_details=0
        )
        outcome = run_benchmark(spec, tmp_path / method, progress=False)
        assert outcome.complete
        rows.update({(method, r["query_id"]): {"method": method, **r} for r in outcome.rows})
    return rows


def same(a: str, b: str) -> bool:
    """Equal strings, two numbers within 1e-9 relative (module docstring), or two JSON documents (the
    ``meta_json`` column) equal but for numbers within that tolerance: numpy's vectorised trigonometry
    may differ by an ulp between CPUs."""
    if a == b:
        return True
    try:
        x, y = float(a), float(b)
    except ValueError:
        try:
            return _same_json(json.loads(a), json.loads(b))
        except (ValueError, TypeError):
            return False
    return math.isclose(x, y, rel_tol=1e-9, abs_tol=1e-9)


def _same_json(x, y) -> bool:
    if isinstance(x, dict) and isinstance(y, dict):
        return x.keys() == y.keys() and all(_same_json(x[k], y[k]) for k in x)
    if isinstance(x, list) and isinstance(y, list):
        return len(x) == len(y) and all(_same_json(u, v) for u, v in zip(x, y, strict=True))
    if isinstance(x, (int, float)) and isinstance(y, (int, float)) and not isinstance(x, bool):
        return math.isclose(x, y, rel_tol=1e-9, abs_tol=1e-9)
    return x == y


def differences(expected: dict, actual: dict) -> list[str]:
    out = [f"{key}: missing" for key in sorted(set(expected) ^ set(actual))]
    for key in sorted(set(expected) & set(actual)):
        for column, value in expected[key].items():
            if column not in TIMING_COLUMNS and not same(value, actual[key].get(column, "")):
                out.append(f"{key} {column}: {value} -> {actual[key].get(column)}")
    return out


def test_generated_city_rows_unchanged(tmp_path):
    expected = reference_rows("generated")
    assert len(expected) == 3 * len(METHODS)
    assert differences(expected, run_rows("generated", tmp_path)) == []


def test_berlin_rows_unchanged(tmp_path, shared):
    berlin = shared("berlin_lod2_citygml2/3910_5817.gml")
    expected = reference_rows("berlin")
    assert differences(expected, run_rows(str(berlin), tmp_path)) == []


@pytest.mark.parametrize("name", ["generated", "berlin"])
def test_reference_rows_cover_every_method_and_status(name):
    rows = reference_rows(name)
    assert {m for m, _ in rows} == set(METHODS)
    assert all(r["status"] in ("localized", "not_localized", "skipped") for r in rows.values())


def test_real_data_set_rows_unchanged(tmp_path, shared):
    """The two real UAV images (oracle and degraded-oracle labels, the first design with a +-30 m height
    grid, preset ``legacy-wide-z``) as before."""
    model = shared("real_uav_lodloc/UAVD4L-LoD1.obj")
    with open(REFERENCE / "real_rows.csv", newline="", encoding="utf-8") as fh:
        expected = {(r["dataset"], r["perception"], r["query_id"]): r for r in csv.DictReader(fh)}
    actual = {}
    for dataset, perception, _ in expected:
        spec = DatasetSpec(
            dataset=str(model.parent.parent / dataset),
            city=str(model),
            perception=perception,
            preset="legacy-wide-z",
            keep_details=0,
        )
        outcome = run_benchmark(spec, tmp_path / f"{dataset}_{perception}", progress=False)
        for r in outcome.rows:
            actual[(dataset, perception, r["query_id"])] = {"dataset": dataset, "perception": perception, **r}
    assert len(expected) == 4
    assert differences(expected, actual) == []

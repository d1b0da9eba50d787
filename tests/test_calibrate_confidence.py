"""``benchmarks/calibrate_confidence.py --cross-city``: judging a confidence feature on the calibration
cities alone (fit on one, check on the other, with and without it)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from helpers import benchmark_script
from semcityloc.localization.confidence import FEATURES_DEPTH, FEATURES_NO_DEPTH


@pytest.fixture(scope="module")
def calibrate():
    return benchmark_script("calibrate_confidence")


def _rows(seed: int, n: int = 300) -> list[dict]:
    """Rows of every variant where only ``building_iou`` tells right from wrong."""
    rng = np.random.default_rng(seed)
    out = []
    for variant in ("semcityloc", "no-depth", "silhouette"):
        names = FEATURES_DEPTH if variant == "semcityloc" else FEATURES_NO_DEPTH
        for _ in range(n):
            right = bool(rng.random() < 0.6)
            feats = {name: float(rng.normal()) for name in names}
            feats["building_iou"] = float(rng.normal(1.5 if right else -1.5))
            out.append({"variant": variant, "right": right, "features": feats})
    return out


def test_cross_city_shows_what_a_feature_is_worth(calibrate, capsys):
    calibrate.cross_city({"a": _rows(0), "b": _rows(1)}, "building_iou")
    out = capsys.readouterr().out.splitlines()
    lines = [line for line in out if "paired bootstrap" not in line]
    paired = [line for line in out if "paired bootstrap" in line]
    assert len(lines) == 3 * 2 * 2  # three models, two directions, with and without
    assert len(paired) == 3 * 2
    for line in paired:  # the feature's worth with an interval: log-loss and Brier lower with it, surely
        for rule in ("log-loss", "brier"):
            mean, low, high = map(float, re.search(rf"{rule} (\S+) \[(\S+), (\S+)\]", line).groups())
            assert low < mean < high < 0
    for with_it, without in zip(lines[::2], lines[1::2], strict=True):
        assert ", all:" in with_it and ", without building_iou:" in without
        loss_with = float(with_it.split("log-loss ")[1].split()[0])
        loss_without = float(without.split("log-loss ")[1].split()[0])
        assert loss_with < 0.3 < 0.6 < loss_without  # informative vs. chance (log 2 = 0.69)


def test_reached_checks_only_the_results_that_reached_the_acceptance(calibrate, capsys):
    edge = [  # stopped on the volume's edge: a pose, every feature missing, refused whatever p says
        {
            "variant": v,
            "right": False,
            "reason": "edge",
            "features": dict.fromkeys(FEATURES_DEPTH, float("nan")),
        }
        for v in ("semcityloc", "no-depth", "silhouette")
        for _ in range(50)
    ]
    assert calibrate.reached_acceptance(edge) == []
    calibrate.cross_city({"a": _rows(0) + edge, "b": _rows(1) + edge}, None, reached=True)
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 3 * 2 * 2  # three models, two directions, fitted on every row and on the reached
    pairs = zip(lines[::2], lines[1::2], strict=True)
    assert all(", fit on every row:" in a and ", fit on the reached:" in b for a, b in pairs)
    checked = {int(line.split("wrong accepted ")[1].split("/")[1]) for line in lines}
    wrong = {
        sum(not r["right"] for r in _rows(s) if r["variant"] == v)
        for s in (0, 1)
        for v in ("semcityloc", "no-depth", "silhouette")
    }
    assert checked <= wrong  # the 50 edge stops of each variant are not checked


def test_check_shipped_reports_the_shipped_models_per_condition(calibrate, capsys, monkeypatch):
    """``--check-shipped`` fits nothing: the models the package ships, one line per condition and one
    over all, for each of the three localizer kinds."""
    by_condition = {cond: _rows(i, n=40) for i, cond in enumerate(calibrate.CONDITIONS)}
    monkeypatch.setattr(calibrate, "condition_rows", lambda city, seed, queries, cond, *a: by_condition[cond])
    monkeypatch.setattr(calibrate, "fit_logistic", None)  # nothing may be fitted
    args = type("Args", (), {"check_seed": 1, "queries": 40, "workers": 1, "cache": None})()
    assert calibrate.check_shipped(["somewhere/berlin.gml"], args) == 0
    lines = capsys.readouterr().out.splitlines()
    heads = [line for line in lines if line.startswith("## berlin seed 1, shipped")]
    assert len(heads) == 3 and "(semcityloc)" in heads[0]
    per = len(calibrate.CONDITIONS) + 1
    assert len(lines) == 3 * (1 + per)
    for cond in (*calibrate.CONDITIONS, "all"):
        assert sum(line.startswith(f"  {cond}: n=") for line in lines) == 3
    assert "  all: n=200 " in lines[per]
    assert calibrate.check_shipped([], args) == 2  # no check city: said, not a traceback


def test_check_without_a_feature_prints_the_paired_difference(calibrate, capsys, monkeypatch):
    """Fitted on a calibration city, checked on another with ``--without NAME``: each model's line and the
    paired bootstrap of (with - without) over the check rows' queries, here surely in favour of the
    feature that carries all the evidence."""

    def rows(city, seed, queries, cond, *args):
        out = _rows(seed + len(cond), n=60)
        return [dict(r, group=f"{city}/q{i % 60:04d}") for i, r in enumerate(out)]

    monkeypatch.setattr(calibrate, "condition_rows", rows)
    argv = ["calibrate_confidence.py", "--fit-city", "generated", "--check-city", "elsewhere.gml"]
    monkeypatch.setattr("sys.argv", [*argv, "--without", "building_iou"])
    assert calibrate.main() == 0
    paired = [line for line in capsys.readouterr().out.splitlines() if "paired bootstrap" in line]
    assert len(paired) == 3  # one per localizer kind
    for line in paired:
        assert "all - without building_iou" in line and "groups)" in line
        mean, low, high = map(float, re.search(r"log-loss (\S+) \[(\S+), (\S+)\]", line).groups())
        assert low <= mean <= high < 0

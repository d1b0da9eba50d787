"""``benchmarks/compare_configs.py``: the paired comparison the localizer's knobs were chosen with."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest

from helpers import benchmark_script
from semcityloc.localization.config import LocalizerConfig

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "compare_configs.py"


@pytest.fixture(scope="module")
def compare():
    return benchmark_script("compare_configs")


def test_variant_overrides_reach_nested_configs(compare):
    name, cfg = compare.parse_variant(
        "v:refine.polish_estimate_top=1,no_depth=true,cascade.local.keep=4", "default"
    )
    base = LocalizerConfig.preset("default")
    assert name == "v"
    assert cfg.refine.polish_estimate_top == 1 and cfg.no_depth is True and cfg.cascade.local.keep == 4
    assert cfg.refine.particles == base.refine.particles  # the rest untouched
    assert compare.parse_variant("plain", "legacy")[1] == LocalizerConfig.preset("legacy")
    _, listed = compare.parse_variant(
        "s:refine.polish_sigma=[0.5,0.5,0.3,0.15],refine.particles=64", "default"
    )
    assert listed.refine.polish_sigma == [0.5, 0.5, 0.3, 0.15] and listed.refine.particles == 64
    with pytest.raises(SystemExit, match="no field 'refin'"):
        compare.parse_variant("bad:refin.particles=3", "default")


def test_summary_pairs_every_variant_with_the_first(compare):
    rows = [
        {"variant": "a", "query": "q0", "status": "localized", "s": 0.2, "err_m": 1.0, "err_deg": 0.5},
        {"variant": "a", "query": "q1", "status": "not_localized", "s": 0.2, "err_m": 4.0, "err_deg": 0.5},
        {"variant": "b", "query": "q0", "status": "localized", "s": 0.4, "err_m": 2.5, "err_deg": 0.5},
        {"variant": "b", "query": "q1", "status": "localized", "s": 0.4, "err_m": 1.5, "err_deg": 1.0},
    ]
    a, b = compare.summarise(rows, ["a", "b"])
    assert a["found_R@2/3/5"] == [50.0, 50.0, 100.0] and a["accepted_R@2/3/5"] == [50.0, 50.0, 50.0]
    assert b["found_R@2/3/5"] == [50.0, 100.0, 100.0] and b["localized"] == 2
    assert (b["gained_2m"], b["lost_2m"]) == (1, 1) and "gained_2m" not in a
    assert (b["gained_3m"], b["lost_3m"]) == (1, 0) and (b["gained_5m"], b["lost_5m"]) == (0, 0)
    assert b["moves"] == {"2m->3m": 1, "5m->2m": 1} and "moves" not in a


def test_moves_name_far_misses_and_poses_not_found(compare):
    inf = math.inf
    rows = [
        {"variant": "a", "query": "q0", "status": "localized", "s": 0.1, "err_m": 0.5, "err_deg": 0.2},
        {"variant": "a", "query": "q1", "status": "localized", "s": 0.1, "err_m": 30.0, "err_deg": 9.0},
        {"variant": "a", "query": "q2", "status": "localized", "s": 0.1, "err_m": 1.0, "err_deg": 2.5},
        {"variant": "b", "query": "q0", "status": "not_localized", "s": 0.1, "err_m": 6.0, "err_deg": 1.0},
        {"variant": "b", "query": "q1", "status": "localized", "s": 0.1, "err_m": 4.0, "err_deg": 4.5},
        {"variant": "b", "query": "q2", "status": "not_localized", "s": 0.1, "err_m": inf, "err_deg": inf},
    ]
    _, b = compare.summarise(rows, ["a", "b"])
    # q2 was within 3 m / 3 deg (2.5 deg is past 2), then no pose at all: "off"
    assert b["moves"] == {"2m->off": 1, "3m->off": 1, "off->5m": 1}
    assert (b["gained_5m"], b["lost_5m"]) == (1, 2) and (b["gained_2m"], b["lost_2m"]) == (0, 1)


def test_a_reporting_city_is_refused_unless_checking(tmp_path):
    berlin = tmp_path / "berlin.gml"
    berlin.write_text("<x/>")
    out = subprocess.run(
        [sys.executable, str(SCRIPT), "--variant", "base", "--city", str(berlin), "--cache", str(tmp_path)],
        capture_output=True,
        text=True,
    )
    assert out.returncode != 0 and "not a calibration city" in out.stderr


def test_cached_queries_of_other_code_are_simulated_again(compare, tmp_path, capsys):
    folder = tmp_path / "generated_s0_realistic"
    folder.mkdir()
    (folder / "q0000.pkl").write_bytes(b"old")
    compare.reset_if_stale(folder, "aaaa")  # no stamp: made by unknown code
    assert not (folder / "q0000.pkl").exists()
    assert "simulating them again" in capsys.readouterr().err
    (folder / "q0000.pkl").write_bytes(b"new")
    compare.reset_if_stale(folder, "aaaa")  # same code: kept
    assert (folder / "q0000.pkl").read_bytes() == b"new"
    compare.reset_if_stale(folder, "bbbb")  # the simulation changed: dropped
    assert not (folder / "q0000.pkl").exists()


def test_set_reaches_nested_and_top_level_knobs(compare):
    spec = compare._spec("generated", 3, 5, {"depth_model.distortion": 0, "prior_translation_m": [1, 2]})
    assert spec.query.depth_model.distortion == 0 and spec.query.prior_translation_m == (1.0, 2.0)
    assert spec.query.seed == 3 and spec.query.queries == 5 and spec.query.reality.overhang_m  # realistic


def test_a_bad_set_value_is_refused_in_one_line(compare, tmp_path, capsys):
    with pytest.raises(SystemExit, match="--set: ") as exc:
        compare.main(["--variant", "base", "--set", "depth_model.distortion=abc", "--cache", str(tmp_path)])
    assert "Traceback" not in str(exc.value)


def test_many_knobs_make_a_short_cache_folder_name(compare, tmp_path):
    many = {f"reality.knob_{i}": 0 for i in range(20)}
    folder = compare._cache_dir(tmp_path, "generated", 0, many)
    assert len(folder.name) < 100 and folder.name.startswith("generated_s0_set-")
    assert folder != compare._cache_dir(tmp_path, "generated", 0, {**many, "reality.knob_0": 1})
    assert compare._cache_dir(tmp_path, "generated", 1, {}).name == "generated_s1_realistic"


def test_every_tuning_condition_is_a_valid_scenario_and_map_faults_joins_three():
    """The named conditions are the scenario's own knobs (a typo would fail in a worker, mid-run), and
    ``map_faults`` is hilly + outdated + map_err2x at once, as its docs say."""
    from semcityloc.benchmark.calibration import TUNING_CONDITIONS, tuning_condition
    from semcityloc.benchmark.scenario import query_config
    from semcityloc.cli.benchmark import parse_settings
    from semcityloc.errors import ParameterError

    for name, knobs in TUNING_CONDITIONS.items():
        cfg = query_config("realistic", parse_settings(list(knobs)))
        assert (cfg == query_config("realistic")) == (name == "realistic"), name
    joined = {*tuning_condition("hilly"), *tuning_condition("outdated"), *tuning_condition("map_err2x")}
    assert set(tuning_condition("map_faults")) == joined
    with pytest.raises(ParameterError, match="unknown tuning condition 'hard'.*map_faults"):
        tuning_condition("hard")


def test_help_says_what_each_condition_sets(compare, capsys):
    """Stop 55 audit: ``--help`` listed the condition names alone ("a named tuning condition"), what each
    sets only in the source. Now each name comes with its knobs, made from ``TUNING_CONDITIONS`` itself."""
    from semcityloc.benchmark.calibration import TUNING_CONDITIONS

    with pytest.raises(SystemExit):
        compare.main(["--help"])
    said = " ".join(capsys.readouterr().out.split())
    for name, knobs in TUNING_CONDITIONS.items():
        assert f"{name} ({', '.join(knobs) or 'the realistic scenario as it is'})" in said, name


def test_conditions_are_run_and_summarised_apart(tmp_path):
    """Two conditions, one query each: one JSON line per (condition, variant), each naming its condition,
    and the rows file tags every row."""
    import json

    out = subprocess.run(
        [
            sys.executable,
            str(SCRIPT),
            "--variant",
            "base",
            "--city",
            "generated",
            "--queries",
            "1",
            "--workers",
            "1",
            "--condition",
            "realistic",
            "--condition",
            "hilly",
            "--cache",
            str(tmp_path / "c"),
            "--rows",
            str(tmp_path / "rows.jsonl"),
        ],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    lines = [json.loads(x) for x in out.stdout.splitlines() if x.startswith("{")]
    assert [(s["condition"], s["variant"]) for s in lines] == [("realistic", "base"), ("hilly", "base")]
    rows = [json.loads(x) for x in (tmp_path / "rows.jsonl").read_text().splitlines()]
    assert {r["condition"] for r in rows} == {"realistic", "hilly"}
    assert len({r["query"] for r in rows}) == len(rows)  # the two conditions' queries are told apart


def test_two_cities_of_one_file_name_get_their_own_cached_queries(compare, tmp_path):
    """Stop 56 audit: the cache was keyed by the city file's stem, so a second city named like the first
    (two generated cities, ``a/generated_lod2.gml`` and ``b/generated_lod2.gml``) was localized with the
    first one's cached queries: 0 % recall where a fresh cache gave 100 %. Now the key holds a digest of the
    city's content and of its reality model; a file edited in place is another key too."""
    a, b = tmp_path / "a" / "m.gml", tmp_path / "b" / "m.gml"
    for path, text in ((a, "<a/>"), (b, "<b/>")):
        path.parent.mkdir()
        path.write_text(text)
    key_a, key_b = compare.city_key(str(a)), compare.city_key(str(b))
    assert key_a != key_b and key_a.startswith("m-") and key_b.startswith("m-")
    assert compare._cache_dir(tmp_path, key_a, 0, {}) != compare._cache_dir(tmp_path, key_b, 0, {})
    a.write_text("<a edited/>")
    assert compare.city_key(str(a)) != key_a
    assert compare.city_key(str(tmp_path / "b" / ".." / "b" / "m.gml")) == key_b  # the content, not the path


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["--seeds", "0,,"], "--seeds takes comma-separated integers"),
        (["--workers", "0"], "--workers must be >= 1"),
        (["--preset", "nope"], "--preset: unknown localizer preset 'nope'"),
        (["--variant", "x:refine.polish_estimate_top=abc"], "RefineConfig.polish_estimate_top takes int"),
        (["--variant", "x:no_depth=3"], "LocalizerConfig.no_depth takes bool"),
        (["--city", "nope.gml"], "--city: nope.gml: no such city model file"),
        (["--cache", "FILE"], "is a file, not a folder"),
    ],
)
def test_bad_arguments_are_refused_in_one_line_before_any_work(compare, tmp_path, args, said):
    """Stop 56 audit: these ended in tracebacks (or, for a variant value of the wrong type, in a worker
    after the queries were simulated; a missing city was called "not a calibration city")."""
    (tmp_path / "FILE").write_text("x")
    args = [str(tmp_path / "FILE") if a == "FILE" else a for a in args]
    cache = [] if "--cache" in args else ["--cache", str(tmp_path / "c")]
    with pytest.raises(SystemExit) as exc:
        compare.main(["--variant", "base", "--city", "generated", "--check-only", *cache, *args])
    assert said in str(exc.value) and "\n" not in str(exc.value)
    assert not (tmp_path / "c").exists()  # nothing simulated

"""Benchmark runner on the generated city: determinism, resume after a kill, workers, files, CLI.

Runs use the real query simulator (``semcityloc.benchmark.queries``) and the "fast" localizer preset.
"""

from __future__ import annotations

import csv
import dataclasses
import errno
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from helpers import deny_reading
from semcityloc.benchmark.code_version import code_fingerprint
from semcityloc.benchmark.methods import available_methods, get_method
from semcityloc.benchmark.queries import QueryConfig, QuerySimulator
from semcityloc.benchmark.report import make_report
from semcityloc.benchmark.results import (
    COLUMNS,
    TIMING_COLUMNS,
    append_row,
    details_depth,
    load_details,
    make_row,
    read_results,
)
from semcityloc.benchmark.run import run_benchmark
from semcityloc.benchmark.runfiles import RESULTS_FILE, Progress
from semcityloc.benchmark.spec import BenchmarkSpec, load_models
from semcityloc.classes import SemanticClass
from semcityloc.errors import (
    ArgumentTypeError,
    BenchmarkError,
    InputFileError,
    OutputPathError,
    ParameterError,
    ResumeMismatchError,
    RunFileError,
    parameter,
)
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.pose import Pose
from semcityloc.localization.result import LocalizationResult

QUERIES = 3


@dataclasses.dataclass
class FakeQuery:
    """A ``BenchmarkQuery`` built by hand (``make_row`` only reads these attributes)."""

    query_id: str
    index: int
    camera: object
    true_pose_local: object
    prior_pose_local: object
    labels: np.ndarray
    depth: np.ndarray | None
    query_miou: float
    meta: dict


@pytest.fixture(scope="module")
def sim():
    """(QueryConfig class, simulator factory) of the real simulator."""
    return QueryConfig, QuerySimulator


def make_spec(sim, **query) -> BenchmarkSpec:
    config_cls, _ = sim
    q = config_cls(**{"queries": QUERIES, "seed": 3, **query})
    return BenchmarkSpec(city="generated", query=q, preset="fast", keep_details=2)


def numbers(rows) -> dict[str, dict[str, str]]:
    """Rows by id without the timing columns (everything else must be reproducible)."""
    return {r["query_id"]: {k: v for k, v in r.items() if k not in TIMING_COLUMNS} for r in rows}


def differences(rows_a, rows_b) -> list[str]:
    """``query column: a != b`` for every reproducible value that differs (empty = same numbers)."""
    a, b = numbers(rows_a), numbers(rows_b)
    out = [f"{q}: missing" for q in sorted(set(a) ^ set(b))]
    for q in sorted(set(a) & set(b)):
        out += [f"{q} {k}: {a[q][k]} != {b[q][k]}" for k in a[q] if a[q][k] != b[q][k]]
    return out


def csv_rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def baseline(sim, tmp_path_factory):
    out = tmp_path_factory.mktemp("baseline")
    return run_benchmark(make_spec(sim), out, progress=False)


# ------------------------------------------------------------------------------------------------ tests
@dataclasses.dataclass(frozen=True)
class _NotingSpec(BenchmarkSpec):
    """A simulated run whose ``finish`` adds a note naming a parameter, as a photo run's exports do."""

    def finish(self, out_dir, rows, summary) -> None:
        summary.setdefault("notes", []).append(f"run again with {parameter('run_prior_sigma', 'z=12')}")


def test_the_summary_returned_keeps_python_words_and_its_file_the_flags(sim, baseline, tmp_path):
    """Stop 55 audit: ``run_benchmark`` turned its summary into the command line's words before returning
    it, so a Python caller read "run again with --prior-sigma z=12", a flag it never passed (the scan of
    the library's strings did not see it: the flag was made at run time, by ``as_flags``). The summary
    returned names the parameter (``prior_sigma='z=12'``); ``summary.json`` keeps the flag."""
    out = tmp_path / "run"
    shutil.copytree(baseline.out_dir, out)  # finished: summarised again, nothing localized
    spec = _NotingSpec(**{f.name: getattr(make_spec(sim), f.name) for f in dataclasses.fields(BenchmarkSpec)})
    outcome = run_benchmark(spec, out, progress=False)
    assert outcome.complete and outcome.new_rows == 0
    assert outcome.summary["notes"] == ["run again with prior_sigma='z=12'"]
    assert json.loads((out / "summary.json").read_text())["notes"] == ["run again with --prior-sigma z=12"]


def test_a_run_writes_one_row_per_query_and_a_summary(baseline):
    assert baseline.complete and baseline.new_rows == QUERIES
    rows = csv_rows(baseline.out_dir / RESULTS_FILE)
    assert tuple(rows[0]) == COLUMNS
    assert sorted(r["query_id"] for r in rows) == [f"q{i:04d}" for i in range(QUERIES)]
    summary = json.loads((baseline.out_dir / "summary.json").read_text())
    for key in (
        "queries",
        "localized",
        "recall_2m2deg",
        "recall_3m3deg",
        "recall_5m5deg",
        "recall_strict",
        "mean_yaw_deg",
        "mean_xyz_m",
        "median_yaw_deg",
        "median_xyz_m",
        "mean_query_miou",
        "sec_per_image",
        "convention",
        "config",
    ):
        assert key in summary, key
    assert summary["queries"] == QUERIES
    assert set(summary["recall_strict"]) == {"recall_2m2deg", "recall_3m3deg", "recall_5m5deg"}
    assert 0 <= summary["recall_2m2deg"] <= summary["recall_3m3deg"] <= summary["recall_5m5deg"] <= 100
    assert summary["sec_per_image"] > 0
    cfg = summary["config"]
    assert cfg["city"] == "generated" and Path(cfg["city_path"]).name == "generated_lod2.gml"
    assert Path(cfg["reality_source"]).name == "generated_lod3.gml"
    assert cfg["method"] == "semcityloc" and cfg["seed"] == 3 and cfg["queries"] == QUERIES
    assert cfg["localizer_preset"] == "fast" and cfg["localizer"]["cascade"]["sweep"]["max_centres"] == 600
    assert cfg["query_config"]["queries"] == QUERIES and "seg_quality" in cfg and "prior_extra_m" in cfg


def test_rows_hold_consistent_poses_errors_and_world_coordinates(baseline):
    origin = run_origin(baseline)
    for r in csv_rows(baseline.out_dir / RESULTS_FILE):
        assert float(r["true_world_x"]) == pytest.approx(float(r["true_x"]) + origin[0])
        assert float(r["true_world_y"]) == pytest.approx(float(r["true_y"]) + origin[1])
        assert float(r["prior_err_m"]) > 0.5 and float(r["t_total_s"]) > 0
        assert r["status"] in ("localized", "not_localized")
        if r["status"] == "localized":
            est = np.array([float(r[f"est_{k}"]) for k in "xyz"])
            true = np.array([float(r[f"true_{k}"]) for k in "xyz"])
            assert float(r["err_xyz_m"]) == pytest.approx(np.linalg.norm(est - true))
            assert float(r["est_world_x"]) == pytest.approx(est[0] + origin[0])
        else:
            assert r["err_xyz_m"] == "inf" and r["est_x"] == "" and r["reason"]


def test_rows_carry_the_acceptance_inputs(baseline):
    """Every query whose search found a pose records what the acceptance read there (stop 42): a
    probability in [0, 1], the class boundaries' distance in pixels, map-agreement shares in [0, 1]."""
    rows = [r for r in csv_rows(baseline.out_dir / RESULTS_FILE) if r["probability"]]
    assert rows
    for r in rows:
        assert 0.0 <= float(r["probability"]) <= 1.0
        assert float(r["boundary_distance_px"]) >= 0.0 or r["boundary_distance_px"] == "nan"
        for c in ("building_fraction", "unmapped_building_share", "unseen_building_share"):
            assert 0.0 <= float(r[c]) <= 1.0, c
        assert float(r["prior_distance"]) >= 0.0 and float(r["depth_cost_agreed"]) >= 0.0


def test_make_row_errors_and_world_coordinates_of_a_known_estimate():
    true = Pose.from_xyz_rpy([10.0, 20.0, 600.0], 0.0, 30.0, 45.0)
    est = Pose.from_xyz_rpy([13.0, 24.0, 600.0], 0.0, 30.0, 47.0)
    prior = Pose.from_xyz_rpy([16.0, 28.0, 600.0], 0.0, 30.0, 50.0)
    q = FakeQuery(
        "q0007",
        7,
        Camera(100, 100, 32, 24, 64, 48),
        true,
        prior,
        np.zeros((48, 64), np.uint8),
        None,
        87.5,
        {"view": "oblique", "height_m": 75.0, "accepted": True},
    )
    origin = np.array([690000.0, 5336000.0, 0.0])
    result = LocalizationResult(
        status="localized",
        pose_local=est,
        score=0.7,
        semantic=0.7,
        timings={"total_s": 1.5, "coarse_s": 1.0, "refine_s": 0.5},
    )
    row = make_row(q, result, origin)
    assert tuple(row) == COLUMNS and row["query_id"] == "q0007" and row["view"] == "oblique"
    assert float(row["err_xyz_m"]) == pytest.approx(5.0) and float(row["err_yaw_deg"]) == pytest.approx(2.0)
    assert float(row["err_rot_deg"]) == pytest.approx(2.0, abs=1e-6)
    assert float(row["prior_err_m"]) == pytest.approx(10.0) and float(
        row["prior_yaw_err_deg"]
    ) == pytest.approx(5.0)
    assert float(row["est_world_x"]) == 690013.0 and float(row["est_world_y"]) == 5336024.0
    assert float(row["est_yaw"]) == pytest.approx(47.0) and row["t_total_s"] == "1.5"
    assert json.loads(row["meta_json"])["height_m"] == 75.0
    failed = make_row(
        q, LocalizationResult(status="not_localized", reason="best score below threshold"), origin
    )
    assert (
        failed["err_xyz_m"] == "inf" and failed["est_world_x"] == "" and failed["reason"].startswith("best")
    )


def run_origin(outcome) -> np.ndarray:
    map_model, _ = load_models(outcome.config)
    return map_model.origin


def test_same_seed_gives_identical_numbers(sim, baseline, tmp_path):
    again = run_benchmark(make_spec(sim), tmp_path / "again", progress=False)
    assert differences(again.rows, baseline.rows) == []
    other = run_benchmark(make_spec(sim, seed=4), tmp_path / "other", progress=False, limit=1)
    assert numbers(other.rows)["q0000"]["true_x"] != numbers(baseline.rows)["q0000"]["true_x"]


def test_a_stopped_run_resumes_without_redoing_queries(sim, baseline, tmp_path):
    out = tmp_path / "stopped"
    first = run_benchmark(make_spec(sim), out, progress=False, limit=2)
    assert not first.complete and first.new_rows == 2 and not (out / "summary.json").exists()
    second = run_benchmark(make_spec(sim), out, progress=False)
    assert second.complete and second.new_rows == QUERIES - 2
    rows = csv_rows(out / RESULTS_FILE)
    assert sorted(r["query_id"] for r in rows) == [f"q{i:04d}" for i in range(QUERIES)]
    assert differences(rows, baseline.rows) == []
    assert (
        json.loads((out / "summary.json").read_text())["recall_5m5deg"] == baseline.summary["recall_5m5deg"]
    )
    third = run_benchmark(make_spec(sim), out, progress=False)  # nothing left to do
    assert third.new_rows == 0 and len(csv_rows(out / RESULTS_FILE)) == QUERIES


def test_a_run_resumed_by_changed_code_says_its_results_mix(sim, baseline, tmp_path, capsys):
    out = tmp_path / "changed"
    run_benchmark(make_spec(sim), out, progress=False, limit=1)
    config = json.loads((out / "run.json").read_text())
    assert config["code"] == code_fingerprint()
    capsys.readouterr()
    run_benchmark(make_spec(sim), out, progress=False, limit=1)  # the same code: nothing to say
    assert "other semcityloc code" not in capsys.readouterr().err
    (out / "run.json").write_text(json.dumps({**config, "code": "0123456789abcdef"}))  # started by older code
    resumed = run_benchmark(make_spec(sim), out, progress=False)  # not refused: the code is not an argument
    err = capsys.readouterr().err
    assert resumed.complete and resumed.new_rows == QUERIES - 2
    assert "started by other semcityloc code (source 0123456789abcdef" in err
    assert "its 2 finished queries" in err and "pass overwrite=True to make them all anew" in err  # Python's
    assert json.loads((out / "run.json").read_text())["code"] == "0123456789abcdef"  # it still says so
    run_benchmark(make_spec(sim), out, progress=False)  # finished: nothing is made, nothing mixes
    assert "other semcityloc code" not in capsys.readouterr().err


def test_a_killed_run_with_a_torn_line_resumes_to_the_same_file(sim, baseline, tmp_path):
    out = tmp_path / "killed"
    out.mkdir()
    (out / "run.json").write_bytes((baseline.out_dir / "run.json").read_bytes())
    shutil.copytree(baseline.out_dir / "details", out / "details")  # written before their rows
    lines = (baseline.out_dir / RESULTS_FILE).read_bytes().splitlines(keepends=True)
    torn = lines[3][: len(lines[3]) // 2]  # the process died in the middle of writing row 3
    (out / RESULTS_FILE).write_bytes(b"".join(lines[:3]) + torn)
    done = run_benchmark(make_spec(sim), out, progress=False)
    assert done.new_rows == QUERIES - 2
    text = (out / RESULTS_FILE).read_text()
    assert text.endswith("\n") and len(text.splitlines()) == QUERIES + 1
    assert torn.decode() not in text.splitlines()  # the fragment was cut, not kept as a row
    rows = csv_rows(out / RESULTS_FILE)
    assert sorted(r["query_id"] for r in rows) == [f"q{i:04d}" for i in range(QUERIES)]
    assert differences(rows, baseline.rows) == []


class RejectingSimulator:
    """Wraps a simulator; query 1 comes back not accepted (as the real one does after MAX_ATTEMPTS)."""

    def __init__(self, inner):
        self.inner = inner

    def query(self, index):
        q = self.inner.query(index)
        if index == 1:
            q.meta = {**q.meta, "accepted": False}
        return q


def test_unaccepted_views_are_skipped_and_left_out_of_the_metrics(sim, baseline, tmp_path):
    _, factory = sim
    out = tmp_path / "skipping"
    spec = dataclasses.replace(
        make_spec(sim), simulator_factory=lambda m, c, r: RejectingSimulator(factory(m, c, r))
    )
    done = run_benchmark(spec, out, progress=False)
    rows = {r["query_id"]: r for r in csv_rows(out / RESULTS_FILE)}
    assert rows["q0001"]["status"] == "skipped" and rows["q0001"]["t_total_s"] == ""
    assert done.summary["skipped"] == 1 and done.summary["queries"] == QUERIES - 1
    assert numbers([rows["q0002"]]) == numbers([r for r in baseline.rows if r["query_id"] == "q0002"])


def test_workers_give_the_same_numbers(sim, baseline, tmp_path):
    _, factory = sim
    out = tmp_path / "workers"
    spec = dataclasses.replace(make_spec(sim), simulator_factory=factory)
    pooled = run_benchmark(spec, out, workers=2, progress=False)
    assert pooled.complete and differences(csv_rows(out / RESULTS_FILE), baseline.rows) == []


def test_other_arguments_in_the_same_folder_are_refused_unless_overwrite(sim, baseline, tmp_path):
    out = tmp_path / "mismatch"
    run_benchmark(make_spec(sim), out, progress=False, limit=1)
    with pytest.raises(ResumeMismatchError, match="seed"):
        run_benchmark(make_spec(sim, seed=9), out, progress=False, limit=0)
    with pytest.raises(ResumeMismatchError, match="method"):
        run_benchmark(dataclasses.replace(make_spec(sim), method="no-depth"), out, progress=False, limit=0)
    (out / "report").mkdir()  # `semcityloc report OUT`'s default: a report of the rows --overwrite deletes
    (out / "report" / "report.md").write_text("# old results\n")
    fresh = run_benchmark(make_spec(sim, seed=9), out, overwrite=True, progress=False, limit=0)
    assert fresh.rows == [] and json.loads((out / "run.json").read_text())["seed"] == 9
    assert not (out / "report").exists()  # it stayed, reporting deleted rows (batch audit, stop 51)
    assert (out / RESULTS_FILE).read_text() == ",".join(COLUMNS) + "\n"
    # keep_details does not change the numbers: not a mismatch.
    run_benchmark(dataclasses.replace(make_spec(sim, seed=9), keep_details=0), out, progress=False, limit=0)
    # A run of other arguments holding no row (here seed 9, started and stopped before its first query; the
    # folders an old version left after a failed setup): nothing to keep, so it is started again, not
    # refused as "another run" (stop 50's weak list, fixed stop 51).
    again = run_benchmark(make_spec(sim), out, progress=False, limit=1)
    assert len(again.rows) == 1 and json.loads((out / "run.json").read_text())["seed"] == 3
    with pytest.raises(ResumeMismatchError, match="seed"):  # now it holds a row: refused as before
        run_benchmark(make_spec(sim, seed=9), out, progress=False, limit=0)


def test_details_hold_the_query_poses_and_cost_volume(baseline):
    files = sorted((baseline.out_dir / "details").glob("*.npz"))
    assert [f.name for f in files] == ["q0000.npz", "q0001.npz"]  # keep_details=2
    d = load_details(files[0])
    row = {r["query_id"]: r for r in baseline.rows}["q0000"]
    assert d["labels"].dtype == np.uint8 and d["labels"].ndim == 2
    assert d["camera"][4:].tolist() == [d["labels"].shape[1], d["labels"].shape[0]]
    axes = d["meta"]["cost_volume"]
    nx, ny, nz, nyaw = axes["shape"]
    assert list(d["cost_scores"].shape) == axes["shape"]  # the fast preset's sweep: <= 600 centres
    assert nx * ny * nz <= 600
    assert len(axes["x"]) == nx and len(axes["yaw"]) == nyaw
    true = Pose.from_cam_from_world(d["true_cam_from_world"])
    assert true.center[0] == pytest.approx(float(row["true_x"]))
    assert np.isfinite(d["prior_cam_from_world"]).all()
    assert d["depth"].shape == d["labels"].shape and d["depth"].dtype == np.float16


def test_details_keep_depth_as_float16_when_it_fits():
    depth = np.array([[0.37, 12.5, np.nan], [250.0, 1234.5, np.inf]], dtype=np.float32)
    kept = details_depth(depth)
    assert kept.dtype == np.float16
    finite = np.isfinite(depth)
    assert np.array_equal(np.isnan(kept), np.isnan(depth)) and np.isinf(kept[1, 2])
    assert np.allclose(kept[finite], depth[finite], rtol=1e-3)
    far = depth.copy()
    far[0, 0] = 70_000.0  # beyond float16: kept as float32, unchanged
    assert details_depth(far).dtype == np.float32 and details_depth(far)[0, 0] == 70_000.0
    assert details_depth(None).shape == (0, 0)


def test_models_map_lod_choice_and_lod3_reality(sim):
    cfg = make_spec(sim).run_config()
    map_model, reality = load_models(cfg)
    assert map_model.lods_present() == [2] and reality.lods_present() == [3]
    assert not np.isin(map_model.classes, [SemanticClass.WINDOW]).any()
    assert np.isin(reality.classes, [SemanticClass.WINDOW]).any()
    np.testing.assert_array_equal(reality.origin, map_model.origin)
    lod1 = load_models(dataclasses.replace(make_spec(sim), lod=1).run_config())[0]
    assert lod1.lods_present() == [1] and lod1.num_buildings == map_model.num_buildings
    lod3 = load_models(dataclasses.replace(make_spec(sim), lod=3).run_config())[0]
    assert lod3.lods_present() == [3]


def test_torn_header_and_bad_files(tmp_path):
    path = tmp_path / RESULTS_FILE
    path.write_text("query_id,ind")  # killed while writing the header
    assert read_results(path) == [] and path.read_text() == ",".join(COLUMNS) + "\n"
    path.write_text("a,b\n1,2\n")
    with pytest.raises(BenchmarkError, match="columns"):
        read_results(path)


def test_a_blank_line_in_the_results_is_no_row(baseline, tmp_path):
    """A blank line added to ``results.csv`` (an editor's, a concatenation's) stopped both resume and report
    with "line 14 has 0 fields, not 67: delete that line" (batch audit, stop 51): it holds no row."""
    text = (baseline.out_dir / RESULTS_FILE).read_text()
    lines = text.splitlines(keepends=True)
    path = tmp_path / RESULTS_FILE
    path.write_text("".join(lines[:2]) + "\n" + "".join(lines[2:]) + "  \t\n" + "\n")
    assert differences(read_results(path), csv_rows(baseline.out_dir / RESULTS_FILE)) == []


def test_method_registry_and_bad_specs(sim, tmp_path):
    assert set(available_methods()) >= {"semcityloc", "no-coarse", "no-refine", "no-depth"}
    with pytest.raises(BenchmarkError, match="unknown method"):
        get_method("nope", None, None)
    with pytest.raises(BenchmarkError, match="unknown method 'nope'; known: semcityloc, no-coarse"):
        dataclasses.replace(make_spec(sim), method="nope")
    with pytest.raises(ParameterError, match="unknown localizer preset .nope.; known: default"):
        dataclasses.replace(make_spec(sim), preset="nope")
    with pytest.raises(BenchmarkError, match="keep_details"):
        dataclasses.replace(make_spec(sim), keep_details=-1)
    with pytest.raises(BenchmarkError, match="lod"):
        dataclasses.replace(make_spec(sim), lod=4)
    with pytest.raises(InputFileError):
        dataclasses.replace(make_spec(sim), city=str(tmp_path / "missing.gml")).run_config()
    with pytest.raises(BenchmarkError, match="workers"):
        run_benchmark(make_spec(sim), tmp_path / "w", workers=0)


def test_a_spec_or_run_given_no_path_is_a_typed_error_naming_the_argument(sim, tmp_path):
    """Stop 56's audit: ``BenchmarkSpec(city=5)`` was made, and its run, like ``run_benchmark(spec, None)``,
    ended in pathlib's ``TypeError: expected str, bytes or os.PathLike object``."""
    for city in (5, None):
        with pytest.raises(
            ArgumentTypeError, match=f"^city must be a city model file.*got {type(city).__name__}"
        ):
            dataclasses.replace(make_spec(sim), city=city)
    with pytest.raises(ArgumentTypeError, match="^out_dir must be the run's folder .*got NoneType"):
        run_benchmark(make_spec(sim), None)
    assert dataclasses.replace(make_spec(sim), city=Path("generated")).city == Path("generated")


def test_a_prior_extra_that_leaves_the_local_frame_is_refused_when_the_spec_is_made(sim):
    """Stop 56: the localizer refuses a prior outside the map's local frame (a world pose given as local);
    an extra offset of 1e6 m ran every query to a miss before, and would stop the run at its first query."""
    with pytest.raises(BenchmarkError, match=r"prior offset of up to 2e\+06 m per axis .* at most 50000 m"):
        make_spec(sim, prior_extra_m=(1e6, 2e6))
    assert make_spec(sim, prior_extra_m=(10.0, 50_000.0)).query.prior_extra_m == (10.0, 50_000.0)


def test_a_python_spec_of_combined_presets_holds_them_in_one_spelling(sim):
    """Two orders of one combination are one run (its ``run.json``, so a resume matches), as on the CLI."""
    a = dataclasses.replace(make_spec(sim), preset="focal-correct, lookalikes")
    b = dataclasses.replace(make_spec(sim), preset="lookalikes,focal-correct")
    assert a.preset == b.preset == "lookalikes,focal-correct"
    assert a.run_config()["localizer_preset"] == b.run_config()["localizer_preset"]


def test_progress_is_a_bar_on_a_tty_and_one_line_otherwise():
    class Tty(io.StringIO):
        def isatty(self):
            return True

    plain, tty = io.StringIO(), Tty()
    for stream in (plain, tty):
        bar = Progress(4, done=1, stream=stream)
        for _ in range(3):
            bar.update()
        bar.close()
    assert plain.getvalue().count("\n") == 1 and "\r" not in plain.getvalue()
    assert "4/4 queries done (3 new" in plain.getvalue()
    assert "\r" in tty.getvalue() and "ETA" in tty.getvalue() and "[" in tty.getvalue()


# -------------------------------------------------------------------------------------------------- CLI
@pytest.fixture
def cli(monkeypatch):
    from semcityloc.cli import benchmark, main, report

    if benchmark not in main.COMMANDS:
        monkeypatch.setattr(main, "COMMANDS", (*main.COMMANDS, benchmark, report))
    return main.main


def test_cli_missing_city_is_a_one_line_error(cli, capsys, tmp_path):
    assert cli(["benchmark", "--city", str(tmp_path / "nope.gml"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("semcityloc: error:") and "nope.gml" in err and err.count("\n") == 1


def test_cli_runs_resumes_and_refuses_other_arguments(sim, cli, capsys, tmp_path):
    out = str(tmp_path / "cli")
    args = ["benchmark", "--city", "generated", "--queries", "2", "--preset", "fast", "--out", out]
    assert cli([*args, "--stop-after", "1"]) == 0
    assert "1/2 queries done" in capsys.readouterr().out
    assert cli(args) == 0
    printed = capsys.readouterr().out
    assert "| method |" in printed and "| semcityloc |" in printed and "R@2m,2° (≤ / <)" in printed
    assert len(csv_rows(Path(out) / RESULTS_FILE)) == 2
    assert cli([*args, "--seed", "5"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("semcityloc: error:") and "seed" in err and err.count("\n") == 1
    assert cli([*args, "--prior-extra", "oops"]) == 2
    assert "--prior-extra" in capsys.readouterr().err
    # More queries grow the finished run: its two rows kept as they are, one localized (was refused, and
    # --overwrite threw the done queries away; query i does not depend on the run's length)
    before = csv_rows(Path(out) / RESULTS_FILE)
    assert cli([*args[:4], "3", *args[5:]]) == 0
    capsys.readouterr()
    after = csv_rows(Path(out) / RESULTS_FILE)
    assert len(after) == 3 and after[:2] == before
    assert json.loads((Path(out) / "summary.json").read_text())["queries"] == 3


def test_prior_extra_parsing():
    from semcityloc.cli.benchmark import parse_prior_extra

    assert parse_prior_extra("10-20") == (10.0, 20.0)
    assert parse_prior_extra("2.5-2.5") == (2.5, 2.5)
    assert parse_prior_extra(None) is None and parse_prior_extra("none") is None
    for bad in ("20-10", "5", "a-b", "1-2-3", "-5-10", "5--10"):
        with pytest.raises(BenchmarkError):
            parse_prior_extra(bad)


@pytest.mark.parametrize(
    "extra, named",
    [
        (["--masks", "some/dir"], "--masks"),
        (["--depth", "d"], "--depth"),
        (["--perception", "masks"], "--perception"),
        (["--allow-lossy-mask"], "--allow-lossy-mask"),
        (["--split", "s.json", "--stage", "test"], "--split, --stage"),
    ],
)
def test_real_data_options_on_simulated_queries_are_refused(cli, capsys, tmp_path, extra, named):
    """A simulated run makes its own masks and depth: --masks & co. would be silently ignored."""
    out = tmp_path / "sim"
    assert cli(["benchmark", "--city", "generated", "--queries", "1", "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("semcityloc: error:") and named in err and "--dataset" in err
    assert err.count("\n") == 1 and not (out / RESULTS_FILE).exists()


@pytest.mark.parametrize(
    "damage",
    ["hello world\n", "q0001,short\n", "header"],
    ids=["garbage-line", "short-line", "changed-header"],
)
def test_a_damaged_results_file_names_remedies_that_work(sim, baseline, tmp_path, damage):
    import shutil

    out = tmp_path / "damaged"
    shutil.copytree(baseline.out_dir, out)
    path = out / RESULTS_FILE
    if damage == "header":
        path.write_text(path.read_text().replace("query_id", "query", 1))
    else:
        with open(path, "a") as fh:
            fh.write(damage)
    with pytest.raises(BenchmarkError) as err:
        run_benchmark(make_spec(sim), out, progress=False)
    message = str(err.value)
    assert "pass overwrite=True to start the run again" in message and "\n" not in message
    if damage != "header":  # the line to delete, keeping the other rows
        assert f"line {QUERIES + 2}" in message and "delete" in message
        lines = path.read_text().splitlines(keepends=True)
        path.write_text("".join(lines[:-1]))
        kept = run_benchmark(make_spec(sim), out, progress=False)
        assert kept.new_rows == 0 and differences(kept.rows, baseline.rows) == []
        with open(path, "a") as fh:
            fh.write(damage)
    fresh = run_benchmark(make_spec(sim), out, overwrite=True, progress=False)  # the advice works
    assert fresh.complete and fresh.new_rows == QUERIES
    assert differences(csv_rows(path), baseline.rows) == []


@pytest.mark.parametrize("damage", ["no-permission", "a-folder", "not-utf8"])
def test_a_results_file_that_cannot_be_read_says_cannot_read_naming_the_file_and_the_fix(
    sim, baseline, tmp_path, monkeypatch, cli, capsys, damage
):
    """A ``results.csv`` that is there but cannot be read at the start of a resume (or by ``report``): one
    typed line, "cannot read", the file and a fix that works; never "cannot write ... make it writable"."""
    out = tmp_path / damage
    shutil.copytree(baseline.out_dir, out)
    path = out / RESULTS_FILE
    if damage == "no-permission":  # made by hand: root reads a file of mode 000
        deny_reading(monkeypatch, path)
    elif damage == "a-folder":
        path.unlink()
        path.mkdir()
    else:
        path.write_bytes(path.read_bytes() + b"q0003,\xff\xfe\n")
    fix = {"no-permission": "make it readable", "a-folder": "move that folder", "not-utf8": "0xff"}[damage]
    for call in (
        lambda: run_benchmark(make_spec(sim), out, progress=False),
        lambda: make_report([out], tmp_path / "report"),
    ):
        with pytest.raises(RunFileError) as err:
            call()
        message = str(err.value)
        assert message.startswith(f"cannot read {path}: ") and fix in message, message
        assert "pass overwrite=True to start the run again" in message and "\n" not in message
        assert "cannot write" not in message and "--overwrite" not in message
    report = ["report", str(out), "--out", str(tmp_path / "cli_report"), "--no-html"]
    assert cli(report) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"semcityloc: error: cannot read {path}: ") and err.count("\n") == 1
    assert "pass --overwrite to start the run again" in err and "overwrite=True" not in err
    if damage == "no-permission":  # the fix named: readable again, the run resumes with its rows
        monkeypatch.undo()
        kept = run_benchmark(make_spec(sim), out, progress=False)
        assert kept.new_rows == 0 and differences(kept.rows, baseline.rows) == []
    fresh = run_benchmark(make_spec(sim), out, overwrite=True, progress=False)  # --overwrite works for all
    assert fresh.complete and differences(csv_rows(path), baseline.rows) == []


def test_a_deleted_details_folder_is_restored_on_resume_and_named_by_the_report(
    sim, baseline, tmp_path, capsys
):
    """The report draws its query figures from ``details/``: deleted, the report says which are missing
    (it drew none, silently), and a resume localizes those queries again, replacing their rows in place
    (the others untouched), saying so once."""
    out = tmp_path / "no_details"
    shutil.copytree(baseline.out_dir, out)
    shutil.rmtree(out / "details")
    before = csv_rows(out / RESULTS_FILE)
    said = "details files of 2 finished queries are missing (q0000, q0001)"
    report = make_report([out], tmp_path / "report", overlays=2)
    assert [n for n in report.notes if said in n and "no figure" in n]
    assert not [p for p in report.plots if p.name.startswith("query_")]
    capsys.readouterr()
    first = run_benchmark(make_spec(sim), out, progress=False, limit=1)  # stopped after one of them
    assert capsys.readouterr().err.count(said) == 1 and first.new_rows == 1 and first.complete
    assert [p.name for p in (out / "details").iterdir()] == ["q0000.npz"]
    resumed = run_benchmark(make_spec(sim), out, progress=False)
    err = capsys.readouterr().err
    assert "details files of 1 finished query are missing (q0001)" in err and "localizing them again" in err
    assert resumed.complete and resumed.new_rows == 1
    assert sorted(p.name for p in (out / "details").iterdir()) == ["q0000.npz", "q0001.npz"]
    rows = csv_rows(out / RESULTS_FILE)
    assert [r["query_id"] for r in rows] == [r["query_id"] for r in before]  # in place, once each
    assert differences(rows, baseline.rows) == [] and rows[2] == before[2]  # q0002 not made again
    summary = json.loads((out / "summary.json").read_text())
    assert summary["recall_5m5deg"] == baseline.summary["recall_5m5deg"]
    again = run_benchmark(make_spec(sim), out, progress=False)
    assert again.new_rows == 0 and "details files" not in capsys.readouterr().err
    report = make_report([out], tmp_path / "report2", overlays=2)
    assert not [n for n in report.notes if "details files" in n]
    assert len([p for p in report.plots if p.name.startswith("query_")]) == 2


def test_a_query_made_again_for_its_details_keeps_its_row_unless_it_made_them(tmp_path):
    """Restoring a query's details never costs its finished row: a new row that made no details (its
    worker died, its source now skips it) leaves the old one; one that did replaces it in place."""
    from semcityloc.benchmark.results import failed_row, skipped_result
    from semcityloc.benchmark.run import _keep_rows

    path = tmp_path / RESULTS_FILE
    old = [{**failed_row(i, ""), "status": "localized", "reason": ""} for i in range(3)]
    for row in old:
        append_row(path, row)
    text = path.read_text()
    skipped = {**failed_row(1, ""), "status": skipped_result().status, "reason": "its mask is gone"}
    died = failed_row(0, "worker died twice")
    rows, written = _keep_rows(iter([died, skipped]), path, old, {"q0000", "q0001"}, None)
    assert rows == old and written == 0 and path.read_text() == text
    new = {**old[1], "score": "0.5"}
    rows, written = _keep_rows(iter([new]), path, old, {"q0001"}, None)
    assert rows == [old[0], new, old[2]] and written == 1
    assert [r["score"] for r in csv_rows(path)] == ["", "0.5", ""]


def test_overwrite_with_the_same_arguments_starts_again(sim, baseline, tmp_path):
    out = tmp_path / "again"
    run_benchmark(make_spec(sim), out, progress=False, limit=1)
    again = run_benchmark(make_spec(sim), out, overwrite=True, progress=False, limit=1)
    assert again.new_rows == 1 and len(csv_rows(out / RESULTS_FILE)) == 1


def _failing_simulator(*_args):
    raise BenchmarkError("setup failed")  # as a backend whose weights are missing fails: before any row


def test_a_run_that_fails_before_its_first_row_leaves_the_folder_as_it_found_it(sim, tmp_path):
    """A run that fails at setup leaves nothing that makes its folder "another run": the corrected command
    (here: other arguments) starts there. What the folder held before stays: its own files, and a resumed
    run's run.json and rows (stop 50)."""
    failing = dataclasses.replace(make_spec(sim), simulator_factory=_failing_simulator)
    fresh = tmp_path / "fresh"
    with pytest.raises(BenchmarkError, match="setup failed"):
        run_benchmark(failing, fresh, progress=False)
    assert not fresh.exists()
    assert run_benchmark(make_spec(sim, seed=9), fresh, progress=False, limit=0).rows == []  # not refused
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine\n")
    with pytest.raises(BenchmarkError, match="setup failed"):
        run_benchmark(failing, mine, progress=False)
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
    started = tmp_path / "started"
    run_benchmark(make_spec(sim), started, progress=False, limit=0)  # run.json and no row: resumed below
    before = {p.name: p.read_bytes() for p in started.iterdir() if p.is_file()}
    with pytest.raises(BenchmarkError, match="setup failed"):
        run_benchmark(failing, started, progress=False)
    assert {p.name: p.read_bytes() for p in started.iterdir()} == before
    run_benchmark(make_spec(sim), started, progress=False, limit=1)  # one row: a run's result, kept whole
    before = {p.name: p.read_bytes() for p in started.rglob("*") if p.is_file()}
    with pytest.raises(BenchmarkError, match="setup failed"):
        run_benchmark(failing, started, progress=False)
    assert {p.name: p.read_bytes() for p in started.rglob("*") if p.is_file()} == before
    assert len(csv_rows(started / RESULTS_FILE)) == 1


def test_two_different_rows_of_one_query_are_refused_naming_the_id_and_lines(sim, baseline, tmp_path):
    import shutil

    out = tmp_path / "conflict"
    shutil.copytree(baseline.out_dir, out)
    path = out / RESULTS_FILE
    lines = path.read_text().splitlines(keepends=True)
    other = lines[2].replace(lines[2].split(",")[6], "1.5", 1)  # q0001 of another run, before ours
    path.write_text(lines[0] + other + "".join(lines[1:]))
    with pytest.raises(BenchmarkError, match=r"q0001 has 2 different rows \(lines 2 and 4\)") as err:
        run_benchmark(make_spec(sim), out, progress=False)
    assert "delete" in str(err.value) and "or pass overwrite=True to start the run again" in str(err.value)
    path.write_text("".join(lines[:2]) + "".join(lines[2:]) + other)  # after ours: refused too
    with pytest.raises(BenchmarkError, match=r"q0001 has 2 different rows \(lines 3 and 5\)"):
        run_benchmark(make_spec(sim), out, progress=False)


def test_an_exact_duplicate_row_is_dropped_and_the_file_rewritten_without_it(sim, baseline, tmp_path):
    import shutil

    out = tmp_path / "duplicate"
    shutil.copytree(baseline.out_dir, out)
    path = out / RESULTS_FILE
    original = path.read_text()
    lines = original.splitlines(keepends=True)
    path.write_text(original + lines[2])
    done = run_benchmark(make_spec(sim), out, progress=False)
    assert done.new_rows == 0 and len(done.rows) == QUERIES
    assert path.read_text() == original


# ------------------------------------------------------------------------- a full disk, a parent killed
def _enospc(*_args, **_kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_a_full_disk_mid_run_keeps_the_finished_rows_and_resumes(sim, baseline, tmp_path, monkeypatch):
    """The second row's write fails half-way (a full disk): one typed error naming the file, the cause, what
    to do and how many rows are kept; the file holds whole rows only, and the same call resumes."""
    from semcityloc.benchmark import results

    out = tmp_path / "full"
    calls = []

    def half_then_full(fd, data):
        calls.append(data)
        if len(calls) == 2:
            os.write(fd, data[: len(data) // 2])
            _enospc()
        os.write(fd, data)

    monkeypatch.setattr(results, "write_all", half_then_full)
    with pytest.raises(OutputPathError) as err:
        run_benchmark(make_spec(sim), out, progress=False)
    message = str(err.value)
    assert message == (
        f"cannot write {out / RESULTS_FILE}: No space left on device; free space and run the same command "
        "again: the 1 finished rows are kept"
    )
    lines = (out / RESULTS_FILE).read_text().splitlines(keepends=True)
    assert len(lines) == 2 and lines[-1].endswith("\n") and lines[-1].startswith("q0000,")
    monkeypatch.undo()
    resumed = run_benchmark(make_spec(sim), out, progress=False)
    assert resumed.complete and resumed.new_rows == QUERIES - 1
    assert differences(csv_rows(out / RESULTS_FILE), baseline.rows) == []


def test_a_full_disk_while_saving_details_leaves_no_temporary_file(sim, tmp_path, monkeypatch, cli, capsys):
    out = tmp_path / "details_full"

    def partial_npz(file, **_arrays):
        Path(file).write_bytes(b"PK" * 1000)  # what fit on the disk
        _enospc()

    args = ["benchmark", "--city", "generated", "--queries", "2", "--preset", "fast", "--out", str(out)]
    assert cli([*args, "--keep-details", "0", "--stop-after", "1"]) == 0  # one finished row, kept below
    monkeypatch.setattr(np, "savez_compressed", partial_npz)
    assert cli([*args, "--keep-details", "1"]) == 2  # q0000's details made again: the disk is full
    err = capsys.readouterr().err
    last = err.splitlines()[-1]  # after the progress line, one line
    assert last.startswith("semcityloc: error: ") and "Traceback" not in err
    assert f"cannot write {out / 'details' / 'q0000.npz'}: No space left on device" in err
    assert "the 1 finished rows are kept" in err and len(csv_rows(out / RESULTS_FILE)) == 1
    assert [p.name for p in (out / "details").iterdir()] == []  # no .q0000.<pid>.tmp.npz keeps it full
    fresh = tmp_path / "fresh_full"  # failed before its first row: nothing of it is left (stop 50)
    assert cli([*args[:-1], str(fresh), "--keep-details", "1"]) == 2 and not fresh.exists()


def test_write_atomic_names_the_file_and_leaves_no_temporary_file(tmp_path, monkeypatch):
    from semcityloc.benchmark import runfiles
    from semcityloc.io import files

    monkeypatch.setattr(files.os, "fsync", _enospc)
    with pytest.raises(OSError) as err:
        files.write_json_atomic(tmp_path / "P059.json", {"a": 1})
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(tmp_path / "P059.json")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(OutputPathError, match=r"P059.json: No space left on device; free space and run"):
        with runfiles.writing():
            runfiles.write_atomic(tmp_path / "P059.json", "x")


def test_a_resumed_run_removes_temporary_files_no_live_process_owns(sim, tmp_path):
    from semcityloc.benchmark.runfiles import remove_stale_temps

    out = tmp_path / "stale"
    run_benchmark(make_spec(sim), out, progress=False, limit=1)
    dead, live = 999_999_999, os.getppid()  # no pid is that large; our parent is alive
    stale = [out / "details" / f".q0001.{dead}.tmp.npz", out / f".summary.json.{dead}.tmp"]
    kept = [out / "details" / f".q0002.{live}.tmp.npz", out / "details" / "q0000.npz", out / "notes.tmp"]
    kept.append(out / ".my-notes.tmp")  # a hidden file of the user's, named like no temp file of ours
    for path in stale + kept[:1] + kept[2:]:
        path.write_bytes(b"x" * 100)
    done = run_benchmark(make_spec(sim), out, progress=False)
    assert done.complete
    assert [p for p in stale if p.exists()] == [] and all(p.exists() for p in kept)
    (out / "estimates").mkdir()
    (out / "estimates" / ".q0001.tmp.json").write_text("{")
    assert remove_stale_temps(out, ("estimates",)) == 1


_GRANDCHILD = """
import sys, time
from semcityloc.benchmark.run import _die_with_parent
_die_with_parent(int(sys.argv[1]))
open(sys.argv[2], "w").close()
time.sleep(120)
"""
_MIDDLE = """
import os, subprocess, sys, time
p = subprocess.Popen([sys.executable, "-c", sys.argv[1], str(os.getpid()), sys.argv[2]])
print(p.pid, flush=True)
time.sleep(120)
"""


def _gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] in "ZX"
    except FileNotFoundError:
        return True


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_a_pool_worker_ends_when_its_parent_is_killed(tmp_path, sig):
    ready = tmp_path / "ready"
    middle = subprocess.Popen(
        [sys.executable, "-c", _MIDDLE, _GRANDCHILD, str(ready)], stdout=subprocess.PIPE, text=True
    )
    worker = int(middle.stdout.readline())
    try:
        deadline = time.monotonic() + 60
        while not ready.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert ready.exists() and not _gone(worker)
        middle.send_signal(sig)
        middle.wait(10)
        deadline = time.monotonic() + 10
        while not _gone(worker) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _gone(worker), "the worker outlived its parent"
    finally:
        if not _gone(worker):
            os.kill(worker, signal.SIGKILL)
        middle.kill()


def test_a_pool_worker_whose_parent_is_already_gone_ends_at_once():
    code = "from semcityloc.benchmark.run import _die_with_parent; _die_with_parent(1); print('alive')"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 1 and "alive" not in done.stdout


def test_a_failed_query_with_a_true_pose_is_a_miss_of_every_recall(baseline):
    """A query whose worker died on every try (Ray) is a miss in the recall's denominator when it has a
    true pose, as a query not localized, and a miss of its own kind in the report; without one (a photo
    run without its truth) it stays out of the errors."""
    from semcityloc.benchmark.miss_kinds import kind_of, summarize_misses
    from semcityloc.benchmark.results import FAILED, failed_row, summarize_rows

    rows = [r for r in baseline.rows if r["query_id"] != "q0001"]
    scored = summarize_rows([*rows, failed_row(1, "worker died 2 times", has_truth=True)], baseline.config)
    unscored = summarize_rows([*rows, failed_row(1, "worker died 2 times")], baseline.config)
    full = summarize_rows(rows, baseline.config)
    truth = full["with_ground_truth"]
    assert scored["with_ground_truth"] == truth + 1 and unscored["with_ground_truth"] == truth
    hits = full["recall_5m5deg"] * truth
    assert np.isclose(scored["recall_5m5deg"] * (truth + 1), hits)  # one more query, no more hits
    assert np.isclose(unscored["recall_5m5deg"], full["recall_5m5deg"])
    assert scored["localized"] == full["localized"]
    assert kind_of(failed_row(1, "", has_truth=True)) == FAILED
    misses = summarize_misses([*rows, failed_row(1, "", has_truth=True)])
    assert misses["count"][FAILED] == 1


def test_an_interrupted_run_says_what_it_keeps_and_how_to_go_on(sim, tmp_path, monkeypatch, capsys):
    """Ctrl-C (or SIGTERM, which the console script turns into the same unwinding) mid-run ended with
    ``semcityloc: interrupted`` and nothing on the finished rows (batch audit, stop 51), where
    ``--stop-after`` says "run again to continue": now the rows kept and the way on are said."""
    from semcityloc.benchmark import run as run_module
    from semcityloc.cli import Terminated

    out = tmp_path / "stopped"
    real = run_module._Worker.run
    calls = []

    def stop_at_the_third(self, index):
        calls.append(index)
        if len(calls) == 3:
            raise Terminated
        return real(self, index)

    monkeypatch.setattr(run_module._Worker, "run", stop_at_the_third)
    with pytest.raises(KeyboardInterrupt):
        run_benchmark(make_spec(sim), out, progress=True)
    err = capsys.readouterr().err
    assert f"semcityloc: note: 2/{QUERIES} done and kept in {out}; the same command again goes on" in err
    monkeypatch.setattr(run_module._Worker, "run", real)
    again = run_benchmark(make_spec(sim), out, progress=False)
    assert again.complete and again.new_rows == QUERIES - 2

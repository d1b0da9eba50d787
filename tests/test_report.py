"""``semcityloc report``: tables grouped by what differs between runs, CSV numbers, plots, CLI."""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

import pytest
from PIL import Image

from semcityloc.benchmark.report import make_report
from semcityloc.benchmark.report_runs import load_run
from semcityloc.benchmark.report_tables import _order_value, markdown_table
from semcityloc.benchmark.results import COLUMNS
from semcityloc.benchmark.run import run_benchmark
from semcityloc.benchmark.runfiles import RESULTS_FILE, RUN_FILE
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.errors import BenchmarkError


# ------------------------------------------------------------------------------ hand-made run folders
def fake_run(root: Path, name: str, errors: list[tuple[float, float]], **config) -> Path:
    """A run folder with the given (xyz m, rot deg) errors; inf = not localized."""
    out = root / name
    out.mkdir(parents=True)
    cfg = {
        "city": "generated",
        "city_path": "/x/generated_lod2.gml",
        "lod": None,
        "method": "semcityloc",
        "seg_quality": "trained",
        "prior_extra_m": None,
        "seed": 0,
        "queries": len(errors),
        "localizer_preset": "default",
        "query_config": {"width": 512},
        **config,
    }
    (out / RUN_FILE).write_text(json.dumps(cfg))
    buf = io.StringIO()
    writer = csv.DictWriter(buf, COLUMNS, lineterminator="\n")
    writer.writeheader()
    for i, (xyz, rot) in enumerate(errors):
        ok = math.isfinite(xyz)
        row = dict.fromkeys(COLUMNS, "")
        row.update(
            query_id=f"q{i:04d}",
            index=str(i),
            status="localized" if ok else "not_localized",
            reason="" if ok else "best score below threshold",
            view="nadir",
            query_miou="80.0",
            err_xyz_m=repr(xyz),
            err_rot_deg=repr(rot),
            err_yaw_deg=repr(rot / 2),
            t_total_s="2.0",
        )
        writer.writerow(row)
    (out / RESULTS_FILE).write_text(buf.getvalue())
    return out


def read_csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_tables_group_runs_by_what_differs(tmp_path):
    inf = math.inf
    runs = [
        fake_run(tmp_path, "lod2_trained", [(2.0, 2.0), (1.0, 1.0), (inf, inf), (4.0, 4.0)], lod=2),
        fake_run(tmp_path, "lod1_trained", [(6.0, 1.0), (1.0, 1.0), (inf, inf), (inf, inf)], lod=1),
        fake_run(
            tmp_path,
            "lod2_zero",
            [(1.0, 1.0), (1.0, 1.0), (1.0, 1.0), (9.0, 9.0)],
            lod=2,
            seg_quality="zero-shot",
        ),
    ]
    report = make_report(runs, tmp_path / "report")
    assert set(report.tables) == {"main", "lod", "seg_quality", "misses"}  # all runs share the prior noise
    misses = {r["run"]: r for r in read_csv(report.tables["misses"][1])}
    assert len(misses) == 3
    m = next(r for label, r in misses.items() if "LoD2" in label and "zero" not in label)
    # 2 m / 2 deg is a hit (<=), 4 m accepted is near, the refusal found nothing near; no map confusion here
    assert (m["hit"], m["near"], m["refused-wrong"], m["wrong"], m["hits_agree"]) == ("2", "1", "1", "0", "–")
    assert any("prior_noise" in n for n in report.notes)

    # LoD table: only the runs that differ in nothing but the LoD (the zero-shot run has no LoD1 partner).
    lod = read_csv(report.tables["lod"][1])
    assert [r["lod"] for r in lod] == ["LoD1", "LoD2"] and "seg_quality" not in lod[0]
    lod2 = lod[1]
    assert float(lod2["recall_2m2deg"]) == 50.0 and float(lod2["strict_recall_2m2deg"]) == 25.0  # tie at 2/2
    assert float(lod2["recall_5m5deg"]) == 75.0 and lod2["not_localized"] == "1"
    assert float(lod2["median_xyz_m"]) == 2.0 and float(lod2["sec_per_image"]) == 2.0
    assert float(lod[0]["recall_5m5deg"]) == 25.0  # 6 m is outside 5 m; two not localized
    md = report.tables["lod"][0].read_text()
    assert "| lod | queries | localized | not loc. | skipped |" in md
    assert "| LoD2 | 4 | 3 | 1 | 0 | 50.0 / 25.0 |" in md
    # Over all queries, the not-localized one at the 50 m cap; all 3 accepted poses within 5 m / 5 deg.
    assert float(lod2["mean_xyz_m_capped"]) == pytest.approx((50.0 + 3 * float(lod2["mean_xyz_m"])) / 4)
    assert float(lod2["acceptance_precision"]) == 100.0 and float(lod2["coverage"]) == 75.0

    seg = read_csv(report.tables["seg_quality"][1])
    assert [r["seg_quality"] for r in seg] == ["trained", "zero-shot"]
    assert float(seg[1]["recall_2m2deg"]) == 75.0 and float(seg[1]["strict_recall_2m2deg"]) == 75.0
    # No two runs differ only in the method: the main table lists every run with what differs.
    main = read_csv(report.tables["main"][1])
    assert len(main) == 3 and {"lod", "seg_quality"} <= set(main[0])
    text = report.markdown.read_text()
    assert "Map level of detail" in text and "strict `<`" in text
    for png in report.plots:
        assert png.suffix == ".png" and Image.open(png).size[0] > 100
    assert len(report.plots) == 3  # no details saved: no query figures


def test_an_unfinished_run_is_reported_as_incomplete(tmp_path):
    run = fake_run(tmp_path, "partial", [(1.0, 1.0)], queries=5)
    data = load_run(run)
    assert not data.complete and data.summary["queries"] == 1
    report = make_report([run], tmp_path / "r")
    assert "(incomplete 1/5)" in report.tables["main"][0].read_text()


def test_markdown_table_shape():
    assert markdown_table(["a", "b"], [["1", "2"]]) == "| a | b |\n|---|---|\n| 1 | 2 |\n"


def test_bad_run_folders_are_typed_errors(tmp_path):
    with pytest.raises(BenchmarkError, match="no run.json"):
        make_report([tmp_path], tmp_path / "r")
    with pytest.raises(BenchmarkError):
        make_report([], tmp_path / "r")


# ------------------------------------------------------------------------------ two real small runs
@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    from semcityloc.benchmark.queries import QueryConfig

    root = tmp_path_factory.mktemp("runs")
    a = BenchmarkSpec(city="generated", query=QueryConfig(queries=2, seed=1), preset="fast", keep_details=2)
    b = BenchmarkSpec(
        city="generated",
        query=QueryConfig(queries=2, seed=1),
        method="no-refine",
        preset="fast",
        keep_details=1,
    )
    return [
        run_benchmark(a, root / "full", progress=False),
        run_benchmark(b, root / "ablation", progress=False),
    ]


def test_report_from_two_real_runs(two_runs, tmp_path):
    report = make_report([o.out_dir for o in two_runs], tmp_path / "report", overlays=2)
    # the runs differ only in the method; both have calibrated probabilities: an acceptance table
    assert set(report.tables) == {"main", "acceptance", "misses"} and len(report.notes) == 3
    for row, outcome in zip(read_csv(report.tables["misses"][1]), two_runs, strict=True):
        kinds = ("hit", "near", "refused-near", "refused-wrong", "wrong", "unreadable-input")
        assert sum(int(row[k]) for k in kinds) == len(outcome.rows) == 2
    main = read_csv(report.tables["main"][1])
    assert [r["method"] for r in main] == ["semcityloc", "no-refine"]
    for row, outcome in zip(main, two_runs, strict=True):
        s = json.loads((outcome.out_dir / "summary.json").read_text())
        for key in ("recall_2m2deg", "recall_5m5deg", "queries", "localized"):
            assert float(row[key]) == float(s[key])
    names = sorted(p.name for p in report.plots)
    assert {
        "cumulative_translation.png",
        "cumulative_rotation.png",
        "recall_vs_prior_noise.png",
        "risk_coverage.png",
    } <= set(names)
    acceptance = read_csv(report.tables["acceptance"][1])
    assert [r["run"] for r in acceptance] == ["semcityloc", "no-refine"]
    for row, outcome in zip(acceptance, two_runs, strict=True):
        probs = [float(r["probability"]) for r in outcome.rows if r["probability"]]
        assert int(row["poses"]) == len(probs) == 2  # every query found a pose with a probability
        assert float(row["cov_0.3"]) == pytest.approx(sum(p >= 0.3 for p in probs) / 2)
        assert 0.0 <= float(row["ece"]) <= 1.0
    queries = [n for n in names if n.startswith("query_")]
    assert queries == ["query_00_full_q0000.png", "query_00_full_q0001.png", "query_01_ablation_q0000.png"]
    for png in report.plots:
        with Image.open(png) as im:
            assert im.format == "PNG" and im.size[0] >= 400
    assert "![query_00_full_q0000](plots/query_00_full_q0000.png)" in report.markdown.read_text()


def test_overlay_marks_true_and_estimated_boundaries():
    import numpy as np

    from semcityloc.benchmark.report_plots import overlay_image

    q = np.zeros((20, 30), np.uint8)
    true = q.copy()
    true[5:15, 5:15] = 3
    est = q.copy()
    est[5:15, 8:18] = 3
    rgb = overlay_image(q, est, true)
    assert (rgb[10, 4] == (0, 200, 255)).all() or (rgb[10, 5] == (0, 200, 255)).all()  # true edge: cyan
    assert (rgb[10, 17] == (255, 0, 255)).all()  # estimate edge: magenta
    assert (rgb[0, 0] != (255, 0, 255)).any()


def test_cli_report(two_runs, tmp_path, monkeypatch, capsys):
    from semcityloc.cli import benchmark, main, report

    if report not in main.COMMANDS:
        monkeypatch.setattr(main, "COMMANDS", (*main.COMMANDS, benchmark, report))
    out = tmp_path / "cli_report"
    assert (
        main.main(["report", *(str(o.out_dir) for o in two_runs), "--out", str(out), "--overlays", "0"]) == 0
    )
    printed = capsys.readouterr().out
    assert (
        "table main:" in printed and (out / "tables" / "main.md").is_file() and (out / "report.md").is_file()
    )
    assert main.main(["report", str(tmp_path / "nothing"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("semcityloc: error:") and err.count("\n") == 1
    # Without --out: one run's report goes into the run (as a run's closing hint says), several runs' into
    # ./benchmark_report (it was ./benchmark_report for one run too)
    monkeypatch.chdir(tmp_path)
    one = two_runs[0].out_dir
    assert main.main(["report", str(one), "--overlays", "0", "--no-html"]) == 0
    assert (one / "report" / "report.md").is_file() and not (tmp_path / "benchmark_report").exists()
    assert main.main(["report", *(str(o.out_dir) for o in two_runs), "--overlays", "0", "--no-html"]) == 0
    assert (tmp_path / "benchmark_report" / "report.md").is_file()


# ------------------------------------------------------------------------------ real-data runs (issue 14)
@pytest.fixture(scope="module")
def real_data_runs(tmp_path_factory):
    """Two runs over a small LoD-Loc-layout data set (box city, photos): oracle and degraded-oracle labels,
    whose masks hold IGNORE (255) at class boundaries, as every real-data run's do."""
    import numpy as np

    from semcityloc.benchmark.dataset_source import DatasetSpec
    from semcityloc.benchmark.warmup import box_city_obj
    from semcityloc.datasets.lodloc import LodLocQuery, write_lodloc_scene
    from semcityloc.geometry.camera import Camera
    from semcityloc.geometry.pose import Pose

    root = tmp_path_factory.mktemp("realdata")
    scene = root / "scene"
    cam = Camera.from_fov(160, 120, 60.0)
    truth = Pose.from_xyz_rpy(np.array([5.0, -4.0, 90.0]), 0.5, 20.0, 30.0)
    prior = Pose.from_xyz_rpy(np.array([8.0, -2.0, 92.0]), 0.0, 19.0, 33.0)
    write_lodloc_scene(scene, [LodLocQuery("DJI_0001_W.JPG", "scene", cam, None, truth, prior)])
    (scene / "Query_image").mkdir()
    Image.new("RGB", (cam.width, cam.height), (100, 100, 100)).save(scene / "Query_image" / "DJI_0001_W.JPG")
    (scene / "city.obj").write_text(box_city_obj())
    outs = []
    for perception in ("oracle", "oracle-degraded"):
        spec = DatasetSpec(dataset=str(scene), perception=perception, preset="fast", keep_details=1)
        outs.append(run_benchmark(spec, root / perception, progress=False).out_dir)
    return outs


def test_report_on_real_data_runs_draws_overlays_and_labels_by_perception(real_data_runs, tmp_path):
    import numpy as np

    from semcityloc.benchmark.results import load_details

    assert (load_details(real_data_runs[0] / "details" / "q0000.npz")["labels"] == 255).any()
    report = make_report(real_data_runs, tmp_path / "report", overlays=1)  # IndexError: index 255 before
    text = report.markdown.read_text()
    assert "semcityloc [oracle]" in text and "semcityloc [oracle-degraded (trained)]" in text
    assert "None" not in text.split("## Figures")[0]
    assert "perception" in report.tables and not any("lod" in n or "prior_noise" in n for n in report.notes)
    rows = read_csv(report.tables["perception"][1])
    assert [r["perception"] for r in rows] == ["oracle", "oracle-degraded (trained)"]
    figures = [p for p in report.plots if p.name.startswith("query_")]
    assert len(figures) == 2
    with Image.open(figures[0]) as im:
        assert im.size[0] > 1500  # mask, photo with model edges, two cost-volume slices
        pixels = np.asarray(im.convert("RGB"))
    assert (np.all(pixels == (255, 0, 255), axis=-1)).any()  # the estimate's edges are drawn


def test_overlay_of_a_mask_with_ignore_pixels():
    import numpy as np

    from semcityloc.benchmark.report_plots import overlay_image

    q = np.full((10, 10), 255, np.uint8)
    q[:5] = 3
    rgb = overlay_image(q, None, None)  # no estimate, no true pose (a user's photo not localized)
    assert (rgb[9, 9] == 255).all() and not (rgb[0, 0] == 255).all()


def test_report_reads_results_of_an_earlier_version(tmp_path):
    """A run written before a column was added is still reported on (missing columns empty); resuming it
    is refused."""
    from semcityloc.benchmark.results import COLUMNS, parse_results

    old = [c for c in COLUMNS if c not in ("probability", "found_err_xyz_m", "found_err_rot_deg")]
    values = {c: "" for c in old} | {"query_id": "q0000", "index": "0", "status": "localized"}
    data = (",".join(old) + "\n" + ",".join(values[c] for c in old) + "\n").encode()
    (row,) = parse_results(data, tmp_path / "results.csv", strict=False)
    assert row["status"] == "localized" and row["probability"] == "" and set(row) == set(COLUMNS)
    with pytest.raises(BenchmarkError, match="columns differ"):
        parse_results(data, tmp_path / "results.csv")
    with pytest.raises(BenchmarkError, match="columns differ"):
        parse_results(b"a,b\n1,2\n", tmp_path / "results.csv", strict=False)  # not a results file at all


@pytest.mark.parametrize(
    "dropped",
    [
        ("sigma_xy_m", "sigma_z_m", "sigma_yaw_deg"),
        ("warnings", "sigma_z_m"),
        ("boundary_distance_px", "depth_cost_agreed", "unseen_building_share"),  # before stop 42
        ("flat_roof_eaves_used",),  # before the drawings followed the map a pose was found on
    ],
)
def test_results_without_columns_added_since_resume(tmp_path, dropped):
    """The versions before the warnings and the covariance's sigma columns: read strictly (to resume),
    the missing columns empty."""
    from semcityloc.benchmark.results import ADDED_COLUMNS, COLUMNS, parse_results

    assert set(dropped) <= set(ADDED_COLUMNS)
    old = [c for c in COLUMNS if c not in dropped]
    values = {c: "" for c in old} | {"query_id": "q0000", "index": "0", "status": "localized"}
    data = (",".join(old) + "\n" + ",".join(values[c] for c in old) + "\n").encode()
    (row,) = parse_results(data, tmp_path / "results.csv")
    assert row["status"] == "localized" and all(row[c] == "" for c in dropped) and set(row) == set(COLUMNS)


def test_results_with_columns_out_of_order_do_not_resume(tmp_path):
    """Only this version's order resumes (rows are appended in it): a swapped pair is another layout."""
    from semcityloc.benchmark.results import COLUMNS, parse_results

    cols = list(COLUMNS)
    i, j = cols.index("boundary_distance_px"), cols.index("prior_distance")
    cols[i], cols[j] = cols[j], cols[i]
    line = ",".join("q0000" if c == "query_id" else "" for c in cols)
    data = (",".join(cols) + "\n" + line + "\n").encode()
    with pytest.raises(BenchmarkError, match="columns differ"):
        parse_results(data, tmp_path / "results.csv")


@pytest.mark.parametrize(
    "key", ["method", "seg_quality", "prior_extra", "lod", "sweep_value", "perception", "seed"]
)
def test_a_setting_one_run_lacks_sorts_last_instead_of_failing(key):
    """A real-data run reported beside simulated ones has no ``prior_extra``, ``lod``, ...: it sorts last
    (``semcityloc report SIM_RUN REAL_RUN`` used to end in a ValueError from ``float('None')``)."""
    present = {"method": "semcityloc", "seg_quality": "trained", "prior_extra": "10-20", "lod": "LoD2",
               "sweep_value": "2", "perception": "oracle", "seed": 0}[key]  # fmt: skip
    values = sorted([None, present], key=lambda v: _order_value(key, v))
    assert values == [present, None]


def test_mixed_simulated_and_real_runs_are_labelled_by_what_tells_them_apart(tmp_path):
    """A real-data run has none of the simulation's settings (``q.*``, ``lod``, ...): those are compared
    among the simulated runs only, not listed as ``None`` in the real run's label and as every value in
    the others' (stop 29: a page-long label per run)."""
    sim_a = fake_run(tmp_path, "sim_a", [(0.5, 0.2), (1.0, 0.3)])
    sim_b = fake_run(tmp_path, "sim_b", [(0.5, 0.2), (9.0, 0.3)], seg_quality="medium")
    real = fake_run(
        tmp_path, "real", [(0.4, 0.1)], mode="dataset", dataset="/d/real_uav", perception="oracle",
        city_path="/d/UAVD4L-LoD1.obj", query_config=None,
    )  # fmt: skip
    report = make_report([sim_a, sim_b, real], tmp_path / "report")
    labels = {
        line.split("`")[1]: line.split("`: ")[1]
        for line in report.markdown.read_text(encoding="utf-8").splitlines()
        if line.startswith("- `")
    }
    assert labels[str(sim_a)] == "semcityloc, city=generated, seg_quality=trained, queries=2"
    assert labels[str(sim_b)] == "semcityloc, city=generated, seg_quality=medium, queries=2"
    assert labels[str(real)] == "semcityloc [oracle], city=UAVD4L-LoD1.obj, queries=1"


def test_every_number_the_query_browser_gets_has_a_label():
    """``report_views.NUMBERS`` reach the page; ``report.js`` shows only those it has a label for."""
    import re

    from semcityloc.benchmark import report_views

    script = (Path(report_views.__file__).parent / "report_assets" / "report.js").read_text()
    block = script.split("const NUMBER_LABELS = {", 1)[1].split("};", 1)[0]
    labelled = set(re.findall(r"(\w+):\s*\"", block))
    assert set(report_views.NUMBERS) <= labelled, set(report_views.NUMBERS) - labelled


def test_rows_of_queries_the_run_does_not_have_are_left_out_and_counted(tmp_path):
    run = fake_run(tmp_path, "extra", [(1.0, 1.0), (2.0, 2.0), (30.0, 20.0)])
    lines = (run / RESULTS_FILE).read_text().splitlines(keepends=True)
    stray = lines[1].replace("q0000,0,", "q0035,35,", 1)  # a row of a longer run's query
    (run / RESULTS_FILE).write_text("".join(lines) + stray)
    data = load_run(run)
    assert sorted(r["query_id"] for r in data.rows) == ["q0000", "q0001", "q0002"]
    assert data.complete and data.summary["queries"] == 3 and data.ignored == ["q0035"]
    report = make_report([run], tmp_path / "r", overlays=0)
    note = [n for n in report.notes if "q0035" in n]
    assert len(note) == 1 and "1 row" in note[0] and "left out" in note[0]


@pytest.mark.parametrize(
    ("text", "match"),
    [("[1, 2]", "not a JSON object"), ('{"queries": "abc"}', "queries"), ('{"queries": -1}', "queries")],
)
def test_a_run_json_that_is_no_run_config_is_a_typed_error(tmp_path, text, match):
    run = fake_run(tmp_path, "bad", [(1.0, 1.0)])
    (run / RUN_FILE).write_text(text)
    with pytest.raises(BenchmarkError, match=match):
        load_run(run)


def test_an_unreadable_details_file_skips_only_its_figure_with_a_note(two_runs, tmp_path):
    import shutil

    run = tmp_path / "torn"
    shutil.copytree(two_runs[0].out_dir, run)
    details = run / "details" / "q0000.npz"
    details.write_bytes(details.read_bytes()[:100])
    report = make_report([run], tmp_path / "r", overlays=2)
    assert [p.name for p in report.plots if p.name.startswith("query_")] == ["query_00_torn_q0001.png"]
    note = [n for n in report.notes if "q0000.npz" in n]
    assert len(note) == 1 and "\n" not in note[0] and "no figure" in note[0]
    from semcityloc.benchmark.report_html import make_html_report

    html = make_html_report([run], tmp_path / "h")  # the query browser shows q0000 without its details
    assert html.queries == 2 and any("q0000.npz" in n and "q0000 shown without them" in n for n in html.notes)


def _write_rows(run: Path, rows: list[dict[str, str]]) -> Path:
    """``run`` with its ``results.csv`` holding exactly ``rows``."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    (run / RESULTS_FILE).write_text(buf.getvalue())
    return run


def _with_reason(run: Path, reasons: dict[str, str]) -> Path:
    """``run`` with the reasons of some of its rows replaced (query id -> reason)."""
    rows = read_csv(run / RESULTS_FILE)
    for row in rows:
        row["reason"] = reasons.get(row["query_id"], row["reason"])
    return _write_rows(run, rows)


def test_a_query_whose_input_could_not_be_read_is_its_own_kind_of_miss_not_a_refusal(tmp_path):
    """A data-set query whose mask cannot be read (``results.unreadable_result``) was never searched: the
    misses table counts it as ``unreadable-input``, not as ``refused-wrong`` ("refused, rightly"), the
    note says what it is, and the recall still counts it as a miss."""
    from semcityloc.benchmark.results import REASON_UNREADABLE

    inf = math.inf
    run = fake_run(tmp_path, "torn_mask", [(0.5, 0.2), (inf, inf), (inf, inf)], mode="dataset")
    _with_reason(run, {"q0002": f"{REASON_UNREADABLE}: /d/masks/DJI_0003.png: truncated PNG"})
    report = make_report([run], tmp_path / "r", overlays=0)
    (row,) = read_csv(report.tables["misses"][1])
    assert (row["hit"], row["refused-wrong"], row["unreadable-input"]) == ("1", "1", "1")
    assert row["queries"] == "3"
    (main,) = read_csv(report.tables["main"][1])
    assert float(main["recall_2m2deg"]) == pytest.approx(100 / 3)  # the unreadable query is a miss
    text = report.markdown.read_text(encoding="utf-8")
    assert "unreadable-input: the query's mask or depth file could not be read" in text


def test_the_query_browser_bins_a_query_whose_input_could_not_be_read_apart():
    """The HTML report's error bins: an unreadable query is not "not localized" (nothing was refused)."""
    from semcityloc.benchmark.report_views import NOT_LOCALIZED, UNREADABLE, error_bin, error_bins
    from semcityloc.benchmark.results import REASON_UNREADABLE

    row = {"status": "not_localized", "reason": f"{REASON_UNREADABLE}: /d/depth/x.npy: not a .npy file"}
    assert error_bin(row) == UNREADABLE and UNREADABLE in error_bins()
    assert error_bin({"status": "not_localized", "reason": "best score below threshold"}) == NOT_LOCALIZED


# ------------------------------------------------------------------------------ the map at the estimate
def _record_flat_eaves_look(run: Path, used: bool) -> Path:
    """``run`` as if ``map_eaves_flat_roofs="auto"``'s second look had (``used``) or had not taken every
    pose from the map with eaves on its flat roofs: its details files and rows say so (the poses as
    they are)."""
    _edit_details_meta(run, lambda meta: meta.update(flat_roof_eaves={"gain_at_found": 0.01, "used": used}))
    rows = read_csv(run / RESULTS_FILE)
    for row in rows:
        if "flat_roof_eaves_used" in row:  # the column of this version
            row["flat_roof_eaves_used"] = "1" if used else "0"
    return _write_rows_as_read(run, rows)


def _edit_details_meta(run: Path, edit) -> None:
    """Every details file of ``run`` with ``edit(meta)`` applied to its ``meta``."""
    import numpy as np

    for path in (run / "details").glob("q*.npz"):
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files}
        meta = json.loads(bytes(arrays["meta"]).decode("utf-8"))
        edit(meta)
        arrays["meta"] = np.frombuffer(json.dumps(meta).encode("utf-8"), dtype=np.uint8)
        np.savez_compressed(path, **arrays)


def _write_rows_as_read(run: Path, rows: list[dict[str, str]]) -> Path:
    """``run`` with its ``results.csv`` holding ``rows`` under their own header (as read)."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, list(rows[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    (run / RESULTS_FILE).write_text(buf.getvalue())
    return run


def _page_entries(html_path: Path) -> list[dict]:
    """The query browser's entries of a ``report.html``."""
    text = html_path.read_text(encoding="utf-8")
    data = text.split('<script type="application/json" id="report-data">', 1)[1].split("</script>", 1)[0]
    return json.loads(data)["entries"]


def test_an_estimate_found_on_the_flat_eaves_map_is_drawn_on_that_map_and_said_so(two_runs, tmp_path):
    """The figures and the query browser draw the map at an estimate the localizer took from the map with
    eaves on its flat roofs (``Localizer.map_of``) on that map, as its details and row record, and name it;
    the truth stays on the map as it is."""
    import shutil

    import numpy as np

    from semcityloc.benchmark.report_html import make_html_report

    runs = {}
    for used in (False, True):
        run = tmp_path / f"flat_{used}"
        shutil.copytree(two_runs[0].out_dir, run)
        runs[used] = _record_flat_eaves_look(run, used)
    assert json.loads((runs[True] / RUN_FILE).read_text())["localizer"]["map_eaves_flat_roofs"] == "auto"
    figures, entries = {}, {}
    for used, run in runs.items():
        report = make_report([run], tmp_path / f"r_{used}", overlays=1)
        (png,) = [p for p in report.plots if p.name.startswith("query_")]
        with Image.open(png) as im:
            figures[used] = np.asarray(im.convert("RGB"))
        entries[used] = _page_entries(make_html_report([run], tmp_path / f"h_{used}").path)
    assert figures[False].shape == figures[True].shape and not np.array_equal(figures[False], figures[True])
    localized = [i for i, e in enumerate(entries[True]) if "estimate" in e["layers"]]
    assert localized, "no query of the run was localized"
    for i in localized:
        plain, flat = entries[False][i], entries[True][i]
        assert plain["layers"]["truth"] == flat["layers"]["truth"]  # the truth: the map as it is
        assert plain["layers"]["estimate"]["edges"] != flat["layers"]["estimate"]["edges"]
        assert plain.get("estimate_map") is None
        assert flat.get("estimate_map") == "the map with eaves on its flat roofs"
    # Without details (not kept), the row says which map.
    rows_only = {}
    for used, run in runs.items():
        shutil.rmtree(run / "details")
        rows_only[used] = _page_entries(make_html_report([run], tmp_path / f"rows_{used}").path)
    for i in localized:
        plain, flat = rows_only[False][i], rows_only[True][i]
        assert plain["layers"]["truth"] == flat["layers"]["truth"]
        assert plain["layers"]["estimate"]["edges"] != flat["layers"]["estimate"]["edges"]
        assert flat["estimate_map"] == "the map with eaves on its flat roofs"


def _record_focal_scale(run: Path, scale: float) -> Path:
    """``run`` as if the focal check's correction had re-found every localized pose with the focal
    lengths times ``scale``: its details files and rows say so (the poses as they are)."""
    _edit_details_meta(
        run, lambda meta: meta.update(focal_scale=scale if meta["status"] == "localized" else None)
    )
    rows = read_csv(run / RESULTS_FILE)
    for row in rows:
        row["focal_scale"] = str(scale) if row["status"] == "localized" else ""
    return _write_rows_as_read(run, rows)


def test_an_estimate_re_found_with_a_scaled_focal_length_is_drawn_with_that_camera(
    two_runs, tmp_path, monkeypatch
):
    """(stop 55) The report's figures and query browser drew a pose the focal check's correction re-found
    with the focal lengths times s (``focal_scale`` in its row and details) with the stated camera, where
    the pose does not hold. Now the estimate is drawn with the scaled camera (``focal_check.found_camera``)
    and the figure says so; the truth and the prior with the stated one."""
    import shutil

    import numpy as np

    from semcityloc.benchmark import report_plots, report_views
    from semcityloc.benchmark.report_html import make_html_report
    from semcityloc.localization.focal_check import with_focal_scale

    plain = two_runs[0].out_dir
    scaled = _record_focal_scale(shutil.copytree(plain, tmp_path / "scaled"), 0.976)
    cameras: dict[str, list] = {"plain": [], "scaled": []}
    figures: dict[str, list] = {"plain": [], "scaled": []}
    layers = report_views._pose_layers

    def spy_layers(renderer, camera, pose, color):  # the query browser: the camera of each pose
        cameras[current].append((color, camera))
        return layers(renderer, camera, pose, color)

    overlay = report_plots.overlay_image

    def spy_overlay(labels, est, true):  # the figures: the estimate's and the truth's label renders
        figures[current].append((est, true))
        return overlay(labels, est, true)

    monkeypatch.setattr(report_views, "_pose_layers", spy_layers)
    monkeypatch.setattr(report_plots, "overlay_image", spy_overlay)
    for current, run in (("plain", plain), ("scaled", scaled)):
        make_html_report([run], tmp_path / f"h_{current}")
        make_report([run], tmp_path / f"r_{current}", overlays=1)
    estimate, truth = report_views.POSES["estimate"][1], report_views.POSES["truth"][1]
    assert len(cameras["plain"]) == len(cameras["scaled"]) > 0
    seen_estimate = 0
    for (color, before), (again, after) in zip(cameras["plain"], cameras["scaled"], strict=True):
        assert color == again
        if color == estimate:  # the estimate: the stated camera times the row's focal_scale
            assert after == with_focal_scale(before, 0.976) and after != before
            seen_estimate += 1
        else:  # the truth, the prior: the stated camera
            assert after == before
    assert seen_estimate > 0 and any(c == truth for c, _ in cameras["scaled"])
    (est_plain, true_plain), (est_scaled, true_scaled) = figures["plain"][0], figures["scaled"][0]
    assert est_plain is not None and np.array_equal(true_plain, true_scaled)
    assert not np.array_equal(est_plain, est_scaled)


def test_the_truth_of_a_simulated_focal_error_is_drawn_with_the_camera_the_query_was_made_with(
    tmp_path, monkeypatch
):
    """(stop 56) A simulated run with ``--set focal_error=0.05`` renders its queries with the true camera
    and tells the localizer one with focal lengths 1.05 times longer; the report drew the truth with the
    stated one, so that the truth did not lie on the query mask. Now the truth (query browser, figure, 3D
    frusta) is drawn with the true camera, read from the run's query config (``report_views.true_camera``);
    the prior and the estimate with the stated one; a run without the error in its query config (older
    runs) with the stated one."""
    import shutil

    import numpy as np

    from semcityloc.benchmark import report_html, report_plots, report_views
    from semcityloc.benchmark.queries import QueryConfig
    from semcityloc.localization.focal_check import with_focal_scale

    spec = BenchmarkSpec(
        city="generated",
        query=QueryConfig(queries=1, seed=1, focal_error=0.05),
        preset="fast",
        keep_details=1,
    )
    erred = run_benchmark(spec, tmp_path / "erred", progress=False).out_dir
    old = shutil.copytree(erred, tmp_path / "old")  # as a run folder that does not say it
    config = json.loads((old / RUN_FILE).read_text())
    del config["query_config"]["focal_error"]
    (old / RUN_FILE).write_text(json.dumps(config))
    drawn: dict[str, dict] = {"erred": {}, "old": {}}
    layers, overlay, frustum = (
        report_views._pose_layers,
        report_plots.overlay_image,
        report_html.frustum_lines,
    )

    def spy_layers(renderer, camera, pose, color):  # the query browser: the camera of each pose
        drawn[current][color] = camera
        return layers(renderer, camera, pose, color)

    def spy_overlay(labels, est, true):  # the figure: the truth's label render
        drawn[current]["figure truth"] = true
        return overlay(labels, est, true)

    def spy_frustum(pose, camera, depth):  # the 3D view: the frusta, in the order prior, estimate, truth
        drawn[current].setdefault("frusta", []).append(camera)
        return frustum(pose, camera, depth)

    monkeypatch.setattr(report_views, "_pose_layers", spy_layers)
    monkeypatch.setattr(report_plots, "overlay_image", spy_overlay)
    monkeypatch.setattr(report_html, "frustum_lines", spy_frustum)
    for current, run in (("erred", erred), ("old", old)):
        report_html.make_html_report([run], tmp_path / f"h_{current}")
        make_report([run], tmp_path / f"r_{current}", overlays=1)
    prior, truth = report_views.POSES["prior"][1], report_views.POSES["truth"][1]
    stated = drawn["erred"][prior]
    assert drawn["erred"][truth] == with_focal_scale(stated, 1 / 1.05) != stated
    assert drawn["old"][truth] == drawn["old"][prior] == stated  # no error recorded: the stated camera
    assert not np.array_equal(drawn["erred"]["figure truth"], drawn["old"]["figure truth"])
    frusta = drawn["erred"]["frusta"]
    assert frusta[-1].fx == pytest.approx(frusta[0].fx / 1.05) and drawn["old"]["frusta"][-1] == frusta[0]


# ------------------------------------------------------------------------------ no ground truth (stop 50)
def blind_run(root: Path, name: str = "photos") -> Path:
    """A photo run without ``--truth``: three photos localized, each moved from its prior by a known
    amount, one refused, one whose mask could not be read, one skipped; no row has an error."""
    from semcityloc.benchmark.results import REASON_UNREADABLE
    from semcityloc.localization.result import REASON_LOW_CONFIDENCE

    run = fake_run(root, name, [(0.0, 0.0)] * 6, mode="photos", truth=None, images="/p", perception="masks")
    # (status, probability, est - prior: dx, dy, dz, dyaw, sigma xy / z / yaw)
    moves = [
        ("localized", "0.99", (3.0, 4.0, 1.0, 359.0), ("0.5", "0.8", "0.2")),
        ("localized", "0.95", (0.0, 1.0, -2.0, 2.0), ("0.7", "1.0", "0.4")),
        ("localized", "0.90", (6.0, 8.0, 4.0, -3.0), ("1.0", "2.0", "0.6")),
    ]
    rows = read_csv(run / RESULTS_FILE)
    for row in rows:
        row.update(err_xyz_m="", err_rot_deg="", err_yaw_deg="", query_miou="")
        row.update(prior_x="10.0", prior_y="20.0", prior_z="100.0", prior_yaw="1.0")
    for row, (status, p, (dx, dy, dz, dyaw), (sxy, sz, syaw)) in zip(rows, moves, strict=False):
        row.update(status=status, reason="", probability=p, sigma_xy_m=sxy, sigma_z_m=sz, sigma_yaw_deg=syaw)
        row.update(est_x=repr(10 + dx), est_y=repr(20 + dy), est_z=repr(100 + dz), est_yaw=repr(1 + dyaw))
    rows[3].update(status="not_localized", reason=REASON_LOW_CONFIDENCE, probability="0.2")
    rows[4].update(status="not_localized", reason=f"{REASON_UNREADABLE}: /p/masks/P4.png: truncated PNG")
    rows[5].update(status="skipped", reason="no intrinsics for P5.JPG")
    return _write_rows(run, rows)


def test_a_run_without_ground_truth_reports_what_it_says_of_itself_not_zero_recall(tmp_path):
    """``semcityloc run`` without ``--truth``: no recall cells of "-" and no error curves flat at 0 %
    (which read as a run that failed), but the counts with the reasons, the calibrated probability, the
    stated sigmas and the shift from the prior (stop 50)."""
    report = make_report([blind_run(tmp_path)], tmp_path / "report", overlays=0)
    assert set(report.tables) == {"main", "self"}  # no acceptance or misses table: both need the truth
    assert sorted(p.name for p in report.plots) == ["self_assessment.png"]  # no error curves
    main_md = report.tables["main"][0].read_text(encoding="utf-8")
    assert "R@" not in main_md and "med. xyz" not in main_md and "| 5 | 3 | 2 | 1 |" in main_md
    (row,) = read_csv(report.tables["self"][1])
    assert (row["queries"], row["localized"], row["not_localized"], row["skipped"]) == ("5", "3", "2", "1")
    assert row["reasons"] == "confidence below the acceptance probability 1; input file cannot be read 1"
    assert float(row["probability_median_localized"]) == pytest.approx(0.95)
    assert float(row["probability_median_refused"]) == pytest.approx(0.2)
    assert [float(row[f"sigma_{k}_median"]) for k in ("xy_m", "z_m", "yaw_deg")] == [0.7, 1.0, 0.4]
    assert (float(row["shift_xy_m_median"]), float(row["shift_xy_m_max"])) == (5.0, 10.0)
    assert (float(row["shift_z_m_median"]), float(row["shift_z_m_max"])) == (2.0, 4.0)
    assert (float(row["shift_yaw_deg_median"]), float(row["shift_yaw_deg_max"])) == (2.0, 3.0)  # 359: 1
    text = report.markdown.read_text(encoding="utf-8")
    assert "No ground truth" in text and "Recall cells" not in text and "- 1.00 / -" not in text
    # Its notes in a Python caller's words, report.md in the command line's (as a run folder's files).
    assert any("no ground truth (a run without truth=...)" in n for n in report.notes)
    assert (
        "No ground truth (no run has `--truth`)" in text and "no ground truth (a run without --truth)" in text
    )
    assert "truth=" not in text
    with Image.open(tmp_path / "report" / "plots" / "self_assessment.png") as im:
        assert im.format == "PNG" and im.size[0] >= 1000


def test_a_run_without_ground_truth_beside_one_with_it_says_no_truth_in_its_cells(tmp_path):
    """Beside a run with ground truth, the run without it has ``no truth`` in the columns that need it
    (not "-"), and the error curves hold the run with truth alone (stop 50)."""
    truth = fake_run(
        tmp_path, "truth", [(0.5, 0.2), (9.0, 0.3)], mode="photos", images="/p", perception="oracle"
    )
    report = make_report([blind_run(tmp_path), truth], tmp_path / "report", overlays=0)
    rows = report.tables["main"][0].read_text(encoding="utf-8").splitlines()[4:]
    cells = {r[1]: r for r in ([c.strip() for c in row.strip("|").split("|")] for row in rows)}
    blind_cells, truth_cells = cells["masks"], cells["oracle"]  # told apart by their perception
    assert blind_cells.count("no truth") == 11 and "no truth" not in truth_cells
    assert "50.0 / 50.0" in truth_cells  # its recall as always
    assert {"cumulative_translation.png", "self_assessment.png"} <= {p.name for p in report.plots}


def test_the_html_report_draws_no_error_curves_of_a_run_without_ground_truth(tmp_path):
    """report.html: no cumulative error curves (empty axes) for a run without ground truth, but its
    probability against the shift from the prior, a point per localized photo that opens it (stop 50)."""
    pytest.importorskip("plotly")
    from semcityloc.benchmark.report_html import _figures

    figures = _figures([load_run(blind_run(tmp_path))], [])
    assert set(figures) == {"self"}
    (trace,) = figures["self"][1].data
    assert list(trace.customdata) == ["0:q0000", "0:q0001", "0:q0002"]
    assert list(trace.y) == pytest.approx([5.0, 1.0, 10.0]) and list(trace.x) == [0.99, 0.95, 0.9]
    # The tables' hint says there is no ground truth, not how recall cells count (there are none)
    from semcityloc.benchmark.report_html import make_html_report

    page = make_html_report([blind_run(tmp_path, "again")], tmp_path / "h").path.read_text(encoding="utf-8")
    assert "Recall cells" not in page and "No ground truth (no run has --truth)" in page


def test_a_run_whose_city_changed_since_is_not_drawn_on_the_new_city(tmp_path):
    """Stop 56 audit: a store rebuilt from other tiles after a run (or a city file edited in place) was
    drawn under the run's queries as if it were the run's map: no word, the 3D view another city. Now
    ``run.json``'s ``city_sha256`` is compared, as a resumed run compares it: the drawings are left out,
    saying so in one note."""
    from semcityloc.benchmark.report_runs import city_changed, map_renderer
    from semcityloc.io.stamps import file_sha256

    city = tmp_path / "city.gml"
    city.write_text("<the city of the run/>")
    run = load_run(fake_run(tmp_path, "r", [(1.0, 1.0)], city_path=str(city), city_sha256=file_sha256(city)))
    assert city_changed(run.config) is None
    city.write_text("<another city/>")
    said = city_changed(run.config)
    assert said is not None and "changed since the run" in said
    notes: list[str] = []
    assert map_renderer(run, {}, notes, "no query figures") is None  # nothing loaded: the file is no model
    assert len(notes) == 1 and "no query figures: its city model" in notes[0] and "\n" not in notes[0]


def test_a_reused_report_folder_holds_the_new_report_alone(tmp_path):
    """Stop 56 audit: a second report into one --out left the first one's tables and figures (a sweep's
    table and plot beside a one-run report). Now an earlier report's files are removed first; other files
    are kept."""
    a = fake_run(tmp_path, "a", [(1.0, 1.0)], method="semcityloc", sweep_knob="k", sweep_value=1)
    b = fake_run(tmp_path, "b", [(1.0, 1.0)], method="no-refine", sweep_knob="k", sweep_value=2)
    out = tmp_path / "rep"
    first = make_report([a, b], out)
    assert (out / "tables" / "sweep_k.csv").is_file() and (out / "plots" / "recall_vs_k.png").is_file()
    (out / "notes.txt").write_text("mine")
    (out / "report.html").write_text("an earlier page")
    second = make_report([fake_run(tmp_path, "c", [(1.0, 1.0)])], out)
    tables = sorted(p.name for p in (out / "tables").iterdir())
    assert tables == sorted(f.name for pair in second.tables.values() for f in pair)
    assert sorted((out / "plots").iterdir()) == sorted(second.plots)
    assert "sweep_k.csv" not in tables and not (out / "plots" / "recall_vs_k.png").exists()
    assert len(first.plots) > len(second.plots)
    assert (out / "notes.txt").read_text() == "mine" and not (out / "report.html").exists()


def test_a_run_named_twice_is_reported_once_and_a_folder_of_runs_says_so(tmp_path, capsys):
    """Stop 56 audit: ``report R R`` listed the run twice; ``report SWEEP`` said only "no run.json";
    ``--overlays=-1`` was taken as 0."""
    from semcityloc.cli.main import main

    a = fake_run(tmp_path / "sw", "k=1", [(1.0, 1.0)])
    fake_run(tmp_path / "sw", "k=2", [(2.0, 1.0)])
    report = make_report([a, tmp_path / "sw" / ".." / "sw" / "k=1"], tmp_path / "rep")
    assert report.markdown.read_text().count(f"- `{a}`") == 1
    assert main(["report", str(tmp_path / "sw"), "--no-html", "--out", str(tmp_path / "r2")]) == 2
    err = capsys.readouterr().err
    assert f"a folder of 2 runs (k=1, k=2): give the run folders themselves ({tmp_path / 'sw'}/* when" in err
    assert main(["report", str(a), "--overlays=-1", "--out", str(tmp_path / "r3")]) == 2
    assert "--overlays must be >= 0, got -1" in capsys.readouterr().err and not (tmp_path / "r3").exists()

"""``report.html``: one self-contained page of runs, checked as a file and in a real browser (Debian's
chromium driven by Playwright; screenshots under build/test-artifacts/report_html/)."""

from __future__ import annotations

import base64
import io
import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from semcityloc.benchmark.queries import QueryConfig
from semcityloc.benchmark.report import make_report
from semcityloc.benchmark.report_html import make_html_report, markdown_tables
from semcityloc.benchmark.report_views import data_uri, error_bin
from semcityloc.benchmark.results import row_pose
from semcityloc.benchmark.run import run_benchmark
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.errors import BenchmarkError, OptionalDependencyError
from semcityloc.geometry.pose import Pose
from test_report import fake_run
from test_run_photos import box_flight, private_cache  # noqa: F401  (a small photo run's inputs)

CHROMIUM = Path("/usr/bin/chromium")
ARTIFACTS = Path(__file__).resolve().parents[1] / "build" / "test-artifacts" / "report_html"
BROWSER_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    """Two small real runs of the same 3 queries (details kept for the first 2 of the first run, 1 of the
    second), their Markdown report and the HTML page."""
    root = tmp_path_factory.mktemp("html")
    runs = []
    for method, keep in (("semcityloc", 2), ("no-refine", 1)):
        spec = BenchmarkSpec(
            city="generated",
            query=QueryConfig(queries=3, seed=2),
            method=method,
            preset="fast",
            keep_details=keep,
        )
        runs.append(run_benchmark(spec, root / method, progress=False).out_dir)
    report = make_report(runs, root / "report", overlays=0)
    html = make_html_report(runs, root / "report", [md for md, _ in report.tables.values()], report.notes)
    return html.path, runs


def _data(html_path: Path) -> dict:
    text = html_path.read_text(encoding="utf-8")
    m = re.search(r'<script type="application/json" id="report-data">(.*?)</script>', text, re.S)
    return json.loads(m.group(1))


def test_page_is_one_file_with_every_query_and_no_network_reference(page):
    html, runs = page
    text = html.read_text(encoding="utf-8")
    assert html.name == "report.html" and html.parent.name == "report"
    markup = re.sub(r"<script[^>]*>.*?</script>", "", text, flags=re.S)  # plotly.js names its site
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", markup)  # no CDN, no remote file
    assert text.count("<script") == 3  # plotly.js, the data, the page's script: all inline
    data = _data(html)
    assert [e["key"] for e in data["entries"]] == [f"{r}:q000{i}" for r in (0, 1) for i in range(3)]
    first = data["entries"][0]
    assert set(first["layers"]) == {"prior", "estimate", "truth"} and first["cost"] is not None
    assert first["mask"].startswith("data:image/png;base64,") and first["background_kind"] == "query mask"
    no_details = data["entries"][2]  # q0002 of the first run: poses rendered, no mask or cost volume
    assert no_details["mask"] is None and no_details["cost"] is None and no_details["layers"]
    assert {"cum-xyz", "cum-rot", "city"} <= set(data["figures"])
    assert "Methods and ablations" in text and html.stat().st_size < 8e6


def test_overlays_are_drawn_where_the_poses_are(page):
    """The estimate's rendered mask of a well-localized query agrees with the query mask far more than the
    prior's does (the images are the run's, not decorations)."""
    html, _ = page
    entry = _data(html)["entries"][0]

    def decode(uri):
        return np.asarray(Image.open(io.BytesIO(base64.b64decode(uri.split(",")[1]))).convert("RGBA"))[
            ..., :3
        ]

    mask = decode(entry["mask"]).astype(int)
    agree = {
        k: (np.abs(decode(entry["layers"][k]["fill"]).astype(int) - mask).sum(-1) < 30).mean()
        for k in entry["layers"]
    }
    assert entry["numbers"]["err_xyz_m"] < entry["numbers"]["prior_err_m"]
    assert agree["estimate"] > agree["prior"] and agree["truth"] > agree["prior"]


def test_views_helpers():
    row = {"status": "localized", "err_xyz_m": "1.5", "err_rot_deg": "2.5"}
    assert error_bin(row) == "≤3 m, 3°"
    assert error_bin({**row, "err_xyz_m": "9"}) == "worse"
    assert error_bin({**row, "err_xyz_m": ""}) == "no truth"
    assert error_bin({"status": "not_localized"}) == "not localized"
    pose = Pose.from_xyz_rpy(np.array([1.0, 2.0, 80.0]), 1.0, 30.0, -40.0)
    names = ["p_x", "p_y", "p_z", "p_roll", "p_pitch", "p_yaw"]
    cols = dict(zip(names, map(repr, pose.to_xyz_rpy().tolist()), strict=True))
    assert np.allclose(row_pose(cols, "p").cam_from_world, pose.cam_from_world)
    assert row_pose({**cols, "p_yaw": ""}, "p") is None
    rgba = np.zeros((4, 6, 4), np.uint8)
    rgba[1, 2] = (255, 0, 255, 255)
    back = np.asarray(Image.open(io.BytesIO(base64.b64decode(data_uri(rgba).split(",")[1]))).convert("RGBA"))
    assert (back == rgba).all()  # the palette PNG keeps label colours and transparency exactly


def test_page_of_a_photo_run(box_flight, tmp_path):  # noqa: F811
    """``semcityloc run`` folders: the photo as background with the model drawn where the run kept the
    camera, the run's own overlay elsewhere, and the flight path in the 3D view."""
    from semcityloc.cli.main import main

    out = tmp_path / "out"
    assert main([str(a) for a in (*box_flight["argv"], "--out", out, "--keep-details", "1")]) == 0
    html = make_html_report([out], tmp_path / "report")
    entries = _data(html.path)["entries"]
    assert [e["name"] for e in entries] == ["P0.JPG", "P1.JPG", "P2.JPG"] and html.rendered == 1
    assert entries[2]["status"] == "not_localized" and "estimate" not in entries[2]["layers"]  # P2: its mask
    assert entries[0]["background_kind"] == "photo" and entries[0]["background"].startswith("data:image/jpeg")
    assert set(entries[0]["layers"]) == {"prior", "estimate", "truth"}
    assert entries[1]["background_kind"].startswith("photo with the model") and not entries[1]["layers"]
    names = [t.get("name", "") for t in _data(html.path)["figures"]["city"]["figure"]["data"]]
    assert any(n.startswith("flight path") for n in names)


def test_markdown_tables_and_bad_input(tmp_path):
    md = tmp_path / "t.md"
    md.write_text("## Title `x`\n\n| a | b |\n|---|---|\n| 1 | 2.5 / 3 |\n")
    assert markdown_tables(md) == ("Title `x`", ["a", "b"], [["1", "2.5 / 3"]])
    with pytest.raises(BenchmarkError):
        make_html_report([], tmp_path / "r")
    with pytest.raises(BenchmarkError, match="not a benchmark run folder"):
        make_html_report([tmp_path], tmp_path / "r")


def test_report_of_a_path_that_is_no_folder_says_what_it_is(tmp_path, capsys):
    """Stop 50's audit: ``semcityloc report nonexist/`` said "not a benchmark run folder (no run.json)" of a
    path that does not exist; a file given for the folder likewise."""
    from semcityloc.cli.main import main

    assert main(["report", str(tmp_path / "nonexist"), "--out", str(tmp_path / "r"), "--no-html"]) == 2
    assert capsys.readouterr().err == f"semcityloc: error: {tmp_path / 'nonexist'}: no such run folder\n"
    (tmp_path / "results.csv").write_text("query_id\n")
    with pytest.raises(BenchmarkError, match="results.csv: is a file, not a benchmark run folder"):
        make_html_report([tmp_path / "results.csv"], tmp_path / "r")


def test_a_run_without_rows_or_map_still_gets_a_page(tmp_path):
    """A run folder whose map is gone and which finished no query (crashed at once): a page, with notes."""
    run = fake_run(tmp_path, "empty", [])
    html = make_html_report([run], tmp_path / "r")
    data = _data(html.path)
    assert html.queries == 0 and data["entries"] == [] and "city" not in data["figures"]
    assert any("map cannot be loaded" in n for n in html.notes)


def test_missing_plotly_is_a_one_line_install_hint(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "plotly.graph_objects", None)  # import fails as if not installed
    with pytest.raises(OptionalDependencyError, match=r"pip install 'semcityloc\[plots\]'"):
        make_html_report([fake_run(tmp_path, "one", [(1.0, 1.0)])], tmp_path / "r")


def test_cli_report_writes_the_page(page, tmp_path, capsys):
    from semcityloc.cli import main

    _, runs = page
    out = tmp_path / "cli"
    args = ["report", *map(str, runs), "--out", str(out), "--overlays", "0", "--html-queries", "1"]
    assert main.main(args) == 0
    assert f"wrote {out / 'report.html'} (2 queries" in capsys.readouterr().out
    assert len(_data(out / "report.html")["entries"]) == 2
    assert main.main([*args[:-2], "--no-html"]) == 0 and "report.html" not in capsys.readouterr().out


# ----------------------------------------------------------------------------------------- in a browser
def _browser_or_skip():
    if not CHROMIUM.is_file():
        pytest.skip(f"no browser: {CHROMIUM} is missing (Debian: apt-get install chromium; .ci/run does)")
    return pytest.importorskip("playwright.sync_api", reason="playwright is in the dev extra")


def test_page_in_chromium(page):
    """Open the page from disk with every network request refused, click through the query browser,
    toggle the overlay and move the pose slider, rotate the 3D view; no console error."""
    sync_api = _browser_or_skip()
    html, _ = page
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    errors, requests = [], []
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=BROWSER_ARGS)
        try:
            tab = browser.new_page(viewport={"width": 1400, "height": 1000})
            tab.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            tab.on("pageerror", lambda exc: errors.append(str(exc)))

            def route(r):
                url = r.request.url
                if url.startswith(("file:", "data:")):
                    r.continue_()
                else:
                    requests.append(url)
                    r.abort()

            tab.route("**/*", route)
            tab.goto(html.as_uri())
            tab.wait_for_selector("body[data-ready='1']", timeout=60_000)
            canvas = tab.locator("#q-canvas")
            drawn = lambda: canvas.get_attribute("data-drawn")  # noqa: E731
            tab.wait_for_function("document.getElementById('q-canvas').dataset.drawn", timeout=20_000)
            assert drawn() == "0:q0000|estimate|on"
            assert tab.locator("#q-list tbody tr").count() == 6
            tab.screenshot(path=str(ARTIFACTS / "page.png"), full_page=True)

            # click through the query browser: a row, next, a filter
            tab.locator("#q-list tbody tr").nth(4).click()
            tab.wait_for_function("document.getElementById('q-canvas').dataset.drawn.startsWith('1:q0001')")
            assert "no-refine" in tab.locator("#q-title").inner_text()
            tab.locator("#q-next").click()
            tab.wait_for_function("document.getElementById('q-canvas').dataset.drawn.startsWith('1:q0002')")
            assert "no cost volume" in tab.locator("#q-cost-xy").inner_text()
            tab.select_option("#f-run", "0")
            assert tab.locator("#q-list tbody tr").count() == 3
            tab.wait_for_function("document.getElementById('q-canvas').dataset.drawn.startsWith('0:q0000')")
            assert tab.locator("#q-cost-xy .main-svg").count() > 0  # the cost slices are plotted

            # the overlay: on at the estimate, at the prior (slider), off; each draws other pixels
            pixels = lambda: tab.evaluate("document.getElementById('q-canvas').toDataURL()")  # noqa: E731
            at_estimate = pixels()
            tab.locator("#q-canvas").screenshot(path=str(ARTIFACTS / "overlay_estimate.png"))
            tab.eval_on_selector("#o-pose", "el => { el.value = '0'; el.dispatchEvent(new Event('input')); }")
            tab.wait_for_function("document.getElementById('q-canvas').dataset.drawn === '0:q0000|prior|on'")
            at_prior = pixels()
            tab.locator("#q-canvas").screenshot(path=str(ARTIFACTS / "overlay_prior.png"))
            tab.locator("#o-on").uncheck()
            tab.wait_for_function("document.getElementById('q-canvas').dataset.drawn === '0:q0000|prior|off'")
            assert len({at_estimate, at_prior, pixels()}) == 3
            tab.locator("#browser").screenshot(path=str(ARTIFACTS / "query_browser.png"))

            # rotate the 3D view by dragging it
            scene = "document.getElementById('plot-city')._fullLayout.scene._scene"
            eye = f"JSON.stringify({scene}.getCamera().eye)"
            before = tab.evaluate(eye)
            tab.locator("#plot-city").scroll_into_view_if_needed()
            box = tab.locator("#plot-city .gl-container").bounding_box()
            x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
            tab.mouse.move(x, y)
            tab.mouse.down()
            for k in range(1, 11):
                tab.mouse.move(x + 20 * k, y + 5 * k)
            tab.mouse.up()
            tab.wait_for_timeout(300)
            assert tab.evaluate(eye) != before
            tab.locator("#city").screenshot(path=str(ARTIFACTS / "city_3d.png"))
        finally:
            browser.close()
    assert not requests, f"the page asked the network for {requests}"
    assert not errors, f"console errors: {errors}"


def test_browser_test_says_why_it_skips(monkeypatch):
    """Where no chromium is installed the browser test skips, naming what to install (never passes)."""
    monkeypatch.setattr(f"{__name__}.CHROMIUM", Path("/nonexistent/chromium"))
    with pytest.raises(pytest.skip.Exception, match="apt-get install chromium"):
        _browser_or_skip()


def test_a_big_model_is_drawn_near_the_cameras_and_by_its_largest_triangles(generated_lod2):
    from semcityloc.benchmark.report_plotly import mesh_selection

    model = generated_lod2
    n = model.num_triangles
    assert (mesh_selection(model, []) == np.arange(n)).all()  # small enough: everything
    areas = model.triangle_areas()
    keep = mesh_selection(model, [], limit=n // 4)
    assert len(keep) == n // 4 and areas[keep].min() >= np.delete(areas, keep).max()
    corner = model.vertices[:, :2].min(axis=0)
    near = mesh_selection(model, [np.array([*corner, model.vertices[:, 2].min() + 10.0])], limit=n - 1)
    mid = model.triangle_corners().mean(axis=1)[near, :2]
    assert 0 < len(near) < n - 1 and (mid <= corner + 50.0 + 1e-6).all()


def test_a_run_json_that_does_not_say_where_its_map_is_gets_a_note_not_a_traceback(tmp_path):
    """A hand-made (or other code's) run.json with a readable city but no ``map_source``: its figures are
    left out with a note naming the key; the page is written."""
    from semcityloc.benchmark.warmup import box_city_obj

    city = tmp_path / "city.obj"
    city.write_text(box_city_obj())
    run = fake_run(tmp_path, "handmade", [(1.0, 1.0)], city_path=str(city), lod=2)
    html = make_html_report([run], tmp_path / "r")
    assert any("does not say where its map is" in n and "map_source" in n for n in html.notes), html.notes

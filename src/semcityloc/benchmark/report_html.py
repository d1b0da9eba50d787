"""One self-contained HTML page of benchmark runs (``report.html`` beside ``report.md``).

Why: people judge a localizer by looking - does the projected model line up with the view, where do the
failures sit. The page opens from disk with no server and no network: plotly.js, the figures, the query
images (``benchmark.report_views``) and the page's own script (``report_assets/``) are all embedded.

It shows
- the tables of the Markdown report (``report.make_report`` wrote them; click a header to sort);
- a query browser: every query of every run (at most ``max_queries`` per run), filtered by run, status,
  error bin and view; the photo or simulated view with the model projected at the prior, the estimate or
  the truth (slider; overlay on/off and opacity), the query mask beside the rendered mask, the coarse
  cost volume's xy and yaw slices, the scores, the acceptance probability and the status with its reason;
- a 3D view of the city mesh (label palette) with the camera frusta at prior, estimate and truth (one
  legend group per run; the selected query in black) and, for a run of photos, the flight path;
- the cumulative error curves (hover: the query; click: opens it), recall against the prior noise and
  against each sweep's values, and the acceptance's risk-coverage curves, of the runs with ground truth;
  of a run without it (a user's photos without ``--truth``) the calibrated probability of each localized
  query against how far its pose moved from the prior (hover, click likewise) instead.
"""

from __future__ import annotations

import html
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from semcityloc.benchmark.found_map import FoundMaps
from semcityloc.benchmark.report_plotly import (
    POSE_COLORS,
    city_figure,
    cumulative_figure,
    frustum_depth,
    frustum_lines,
    graph_objects,
    lines_trace,
    mesh_selection,
    recall_lines_figure,
    risk_coverage_figure,
    self_figure,
)
from semcityloc.benchmark.report_runs import (
    NO_TRUTH_LINE,
    RunData,
    acceptance_data,
    has_truth,
    label_runs,
    load_run,
    map_renderer,
    noise_x,
    photo_of,
    prior_noise_groups,
    readable_details,
    sweep_x,
    unique_runs,
)
from semcityloc.benchmark.report_views import POSES, error_bins, pose_camera, query_camera, query_view
from semcityloc.benchmark.results import row_pose
from semcityloc.benchmark.runfiles import DETAILS_DIR
from semcityloc.citymodel.model import CityModel
from semcityloc.errors import BenchmarkError, as_flags
from semcityloc.geometry.camera import Camera
from semcityloc.io.files import json_safe, write_atomic
from semcityloc.localization.confidence import risk_coverage

HTML_FILE = "report.html"
NOMINAL_CAMERA = Camera.from_fov(640, 480, 70.0)  # frusta of photos whose camera the run did not keep


@dataclass
class HtmlReport:
    """What the HTML report wrote: the page, how many queries its browser holds and how many of them have the
    model drawn at their poses, and the notes printed to the user.
    """

    path: Path
    queries: int  # queries in the browser
    rendered: int  # of them, with the model drawn at their poses
    notes: list[str]


# The tables' hint on recall cells (runs with ground truth; ``NO_TRUTH_LINE`` when none has it).
RECALL_HINT = (
    "Recall cells: <code>≤</code> (LoD-Loc v1) / strict\n    <code>&lt;</code>; not-localized queries "
    "count as failures."
)


def markdown_tables(path: Path) -> tuple[str, list[str], list[list[str]]]:
    """(title, headers, rows) of a table file the Markdown report wrote (``## title`` + a pipe table)."""
    title, lines = path.stem, []
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("## "):
            title = line[3:].strip()
        elif line.startswith("|"):
            lines.append([c.strip() for c in line.strip().strip("|").split(" | ")])
    if len(lines) < 2:
        return title, [], []
    return title, lines[0], lines[2:]


def _table_html(title: str, headers: list[str], rows: list[list[str]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows)
    return (
        f"<h3>{html.escape(title.replace('`', ''))}</h3><div class='scroll'><table class='sortable'>"
        f"<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>"
    )


def _maps(runs: list[RunData], notes: list[str]) -> list[tuple[CityModel, FoundMaps] | None]:
    """Per run, its map model and the renderers of its drawings (``found_map.FoundMaps``; shared between
    runs of one map), or None."""
    cache: dict = {}
    return [map_renderer(run, cache, notes, "its queries show no model") for run in runs]


def _entries(runs, maps, max_queries: int | None, notes: list[str]) -> list[dict[str, Any]]:
    entries = []
    for n, (run, pair) in enumerate(zip(runs, maps, strict=True)):
        maps = pair[1] if pair is not None else None
        rows = sorted(run.rows, key=lambda r: int(r["index"]))[:max_queries]
        fallback = None
        for row in rows:
            path = run.path / DETAILS_DIR / f"{row['query_id']}.npz"
            shown = f"{row['query_id']} shown without them"
            details = readable_details(path, notes, shown) if path.is_file() else None
            meta = details["meta"].get("query_meta") if details is not None else None
            meta = meta or json.loads(row.get("meta_json") or "{}")
            view = query_view(run.path, run.config, row, details, maps, photo_of(run.config, meta))
            camera = query_camera(run.config, details)
            fallback = camera if fallback is None else fallback
            view.update(key=f"{n}:{row['query_id']}", run=n, camera=camera)
            entries.append(view)
        for e in entries:
            if e["run"] == n and e["camera"] is None:
                e["camera"] = NOMINAL_CAMERA if fallback is None else fallback
    return entries


def _city(runs, maps, entries, notes) -> tuple[Any, dict] | None:
    """The 3D figure (the first run's map) and each entry's frusta (key -> [x, y, z] lists)."""
    first = next((p for p in maps if p is not None), None)
    if first is None:
        return None
    model = first[0]
    if any(p is not None and p[0] is not model for p in maps):
        notes.append("the 3D view shows the first run's map; the runs' maps differ")
    by_key = {f"{n}:{r['query_id']}": r for n, run in enumerate(runs) for r in run.rows}
    poses = {e["key"]: {k: row_pose(by_key[e["key"]], POSES[k][0]) for k in POSES} for e in entries}
    centers = [p.center for d in poses.values() for p in d.values() if p is not None]
    depth = frustum_depth(centers, model)
    frusta: dict[str, dict] = {}
    traces = []
    for n, run in enumerate(runs):
        mine = [e for e in entries if e["run"] == n]
        for kind, color in POSE_COLORS.items():
            xyz: list[list] = [[], [], []]
            keys: list = []
            texts: list = []
            for e in mine:
                pose = poses[e["key"]][kind]
                if pose is None:
                    continue
                camera = pose_camera(kind, e["camera"], run.config, by_key[e["key"]])
                lines = frustum_lines(pose, camera, depth)
                frusta.setdefault(e["key"], {})[kind] = lines
                for axis in range(3):
                    xyz[axis] += lines[axis]
                keys += [e["key"]] * len(lines[0])
                texts += [e["qid"]] * len(lines[0])
            if keys:
                visible = True if n == 0 else "legendonly"
                traces.append(
                    lines_trace(
                        xyz,
                        f"{kind}: {run.label}",
                        color,
                        keys,
                        texts,
                        legendgroup=f"run{n}",
                        visible=visible,
                    )
                )
        if run.config.get("mode") == "photos":
            est_or_prior = [(poses[e["key"]]["estimate"], poses[e["key"]]["prior"]) for e in mine]
            path = [est if est is not None else prior for est, prior in est_or_prior]
            pts = np.array([p.center for p in path if p is not None])
            if len(pts) > 1:
                xyz = [np.round(pts[:, a], 1).tolist() for a in range(3)]
                keys = [e["key"] for e, p in zip(mine, path, strict=True) if p is not None]
                texts = [e["qid"] for e, p in zip(mine, path, strict=True) if p is not None]
                traces.append(lines_trace(xyz, f"flight path: {run.label}", "rgb(20,20,20)", keys, texts, 3))
    keep = mesh_selection(model, centers)
    title = f"city model: {len(keep)} of {model.num_triangles} triangles"
    if len(keep) < model.num_triangles:
        notes.append(
            f"the 3D view draws {len(keep)} of the map's {model.num_triangles} triangles (near the cameras, "
            "the largest first)"
        )
    return city_figure(model, keep, traces, title), frusta


def _figures(all_runs: list[RunData], entries: list[dict]) -> dict[str, Any]:
    """The page's curves. Error curves and recall of the runs with ground truth only (none when no run has
    it: curves at 0 % would read as a run that failed); the runs without it get the calibrated probability
    against the shift from the prior (``self_figure``)."""
    keys = {id(run): [f"{n}:{r['query_id']}" for r in run.rows] for n, run in enumerate(all_runs)}
    runs = [r for r in all_runs if has_truth(r)]
    blind = [r for r in all_runs if not has_truth(r)]
    figs: dict[str, Any] = {}
    if runs:
        keys_by_run = [keys[id(r)] for r in runs]
        figs["cum-xyz"] = (
            "Cumulative camera-centre error",
            cumulative_figure(runs, keys_by_run, "err_xyz_m", "camera-centre error (m)", 10.0),
        )
        figs["cum-rot"] = (
            "Cumulative rotation error",
            cumulative_figure(runs, keys_by_run, "err_rot_deg", "rotation error (deg)", 10.0),
        )
    if blind:
        figs["self"] = (
            "Without ground truth: calibrated probability against the shift from the prior",
            self_figure(blind, [keys[id(r)] for r in blind]),
        )
    groups = prior_noise_groups(runs) if runs else {}
    if len({noise_x(r) for g in groups.values() for r in g}) > 1:
        figs["prior-noise"] = (
            "Recall against the extra prior noise",
            recall_lines_figure(groups, noise_x, "extra prior noise per axis (m, bin centre)"),
        )
    for k, knob in enumerate(sorted({r.config.get("sweep_knob") for r in runs} - {None})):
        by_method: dict[str, list[RunData]] = {}
        for r in runs:
            if r.config.get("sweep_knob") == knob:
                by_method.setdefault(str(r.settings["method"]), []).append(r)
        figs[f"sweep-{k}"] = (
            f"Sweep of {knob}",
            recall_lines_figure(by_method, lambda r: sweep_x(r.settings["sweep_value"])[0], knob),
        )
    curves = {}
    for r in runs:
        data = acceptance_data(r)
        if data is not None:
            curves[r.label] = risk_coverage(*data)
    if curves:
        figs["risk-coverage"] = ("Acceptance: precision against coverage", risk_coverage_figure(curves))
    return figs


def _asset(name: str) -> str:
    return resources.files("semcityloc.benchmark").joinpath("report_assets", name).read_text(encoding="utf-8")


def _plotly_js() -> str:
    graph_objects()  # the install hint when plotly is missing
    from plotly.offline import get_plotlyjs  # optional dependency, loaded only when used

    return get_plotlyjs()


def _script_json(value: Any) -> str:
    """JSON for a ``<script type="application/json">`` (no ``</`` that would end the element)."""
    return json.dumps(json_safe(value), separators=(",", ":")).replace("</", "<\\/")


def make_html_report(
    run_dirs: list[str | Path],
    out_dir: str | Path,
    tables: Sequence[Path] = (),
    notes: Sequence[str] = (),
    max_queries: int | None = None,
) -> HtmlReport:
    """Write ``out_dir/report.html`` of ``run_dirs`` (module docstring). ``tables``: the Markdown table
    files of the report (``ReportOutput.tables``); ``notes``: the report's notes, shown on the page."""
    if not run_dirs:
        raise BenchmarkError("name at least one benchmark run folder")
    if max_queries is not None and max_queries < 0:
        raise BenchmarkError(f"max_queries must be >= 0, got {max_queries}")
    runs = [load_run(p) for p in unique_runs(run_dirs)]
    label_runs(runs)
    notes = list(notes)
    maps = _maps(runs, notes)
    entries = _entries(runs, maps, max_queries, notes)
    figures = _figures(runs, entries)
    city = _city(runs, maps, entries, notes)
    frusta = {}
    if city is not None:
        figures["city"] = ("3D view", city[0])
        frusta = city[1]
    for e in entries:
        e["frusta"] = frusta.get(e["key"], {})
        del e["camera"]
    data = {
        "runs": [{"label": r.label, "path": str(r.path)} for r in runs],
        "entries": entries,
        "bins": error_bins(),
        "poses": list(POSES),
        "figures": {k: {"title": t, "figure": json.loads(f.to_json())} for k, (t, f) in figures.items()},
    }
    table_html = "".join(_table_html(*markdown_tables(Path(t))) for t in tables)
    run_list = "".join(
        f"<li><b>{html.escape(r.label)}</b> <code>{html.escape(str(r.path))}</code></li>" for r in runs
    )
    note_list = "".join(f"<li>{html.escape(as_flags(n))}</li>" for n in notes)
    parts = {
        "STYLE": _asset("report.css"),
        "PLOTLY": _plotly_js().replace("</script", "<\\/script"),
        "RUNS": run_list,
        "TABLES": table_html or "<p>No tables.</p>",
        "HINT": RECALL_HINT
        if any(has_truth(r) for r in runs)
        else html.escape(as_flags(NO_TRUTH_LINE).replace("`", "")),
        "NOTES": note_list or "<li>none</li>",
        "DATA": _script_json(data),
        "SCRIPT": _asset("report.js"),
    }
    # One pass over the template: what is put in is never searched for markers again.
    page = re.sub(
        r"/\*([A-Z]+)\*/|<!--([A-Z]+)-->", lambda m: parts[m.group(1) or m.group(2)], _asset("report.html")
    )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / HTML_FILE
    write_atomic(path, page)
    rendered = sum(bool(e["layers"]) for e in entries)
    return HtmlReport(path, len(entries), rendered, notes)

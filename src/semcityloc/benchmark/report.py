"""The paper's tables and figures from several benchmark run folders (``semcityloc report DIR...``).

Why: every experiment of the paper is one ``semcityloc benchmark`` run; this module puts runs side by
side by what differs in their ``run.json``:

- tables (Markdown + CSV): ``main`` (methods and ablations), ``prior_noise`` (``prior_extra_m``),
  ``lod`` (LoD1/LoD2/LoD3 maps), ``seg_quality`` (segmentation preset). A table of factor F holds the
  runs whose group - runs agreeing on every setting but F - has two or more values of F (so the LoD
  table compares LoD1 with LoD2 at the same method, noise and segmentation); it is skipped when there
  is no such group, except ``main``, which then lists every run. One row per run: F first, then the
  settings that differ between the table's runs, then the metrics. Recall cells show both conventions,
  ``<=`` / ``<`` (see ``evaluation.metrics``);
- plots (matplotlib, Agg): cumulative position and rotation error curves (one line per run,
  ``not_localized`` never reaches the curve), recall vs prior noise, and per run a figure for its first
  saved queries (``details/``): the query mask with the label boundaries of the map rendered at the
  estimated and true poses (the estimate on the map it was found on: ``found_map``), an xy slice and a
  yaw slice of the coarse cost volume.

Runs are read only (an unfinished run is reported with its finished rows and marked incomplete).
"""

from __future__ import annotations

import csv
import io
import json
import math
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from semcityloc.benchmark.found_map import FoundMaps
from semcityloc.benchmark.miss_kinds import MISS_KINDS, summarize_misses
from semcityloc.benchmark.queries import query_id
from semcityloc.benchmark.results import (
    SKIPPED,
    load_details,
    missing_details,
    missing_details_phrase,
    parse_results,
    summarize_rows,
)
from semcityloc.benchmark.runfiles import DETAILS_DIR, RESULTS_FILE, RUN_FILE, SUMMARY_FILE, read_run_file
from semcityloc.benchmark.spec import load_map
from semcityloc.citymodel.model import CityModel
from semcityloc.citymodel.tiles import load_city
from semcityloc.datasets.lodloc import FRAME_ECEF, IMAGE_DIR, enu_from_ecef, rotate_model
from semcityloc.errors import BenchmarkError, OptionalDependencyError, SemCityLocError
from semcityloc.evaluation.metrics import CAP_XYZ_M, THRESHOLDS, cumulative_curve, threshold_key
from semcityloc.geometry.camera import Camera
from semcityloc.geometry.conventions import wrap_deg
from semcityloc.geometry.pose import Pose
from semcityloc.io.images import load_image, scaled_size
from semcityloc.localization.confidence import calibration_error, risk_coverage
from semcityloc.localization.methods import ABLATIONS
from semcityloc.localization.result import LOCALIZED
from semcityloc.render import Renderer
from semcityloc.render.overlay import (
    class_boundaries,
    draw_edges,
    label_colors,
    resize_nearest,
    visible_edges,
)

# name -> (config key shown, title). "main" is always written; the others when their key varies.
TABLES: dict[str, tuple[str, str]] = {
    "main": ("method", "Methods and ablations"),
    "perception": ("perception", "Perception (oracle labels, degraded, masks, backends) on real data"),
    "prior_noise": ("prior_extra", "Prior-noise sensitivity"),
    "lod": ("lod", "Map level of detail (LoD1 / LoD2 / LoD3)"),
    "seg_quality": ("seg_quality", "Segmentation-quality sensitivity"),
}
SEG_ORDER = ("perfect", "trained", "medium", "zero-shot")
REAL_MODES = ("dataset", "photos")  # runs over real images (``mode`` in run.json); others are simulated
FIGURE_MAX_WIDTH = 1024  # query figures are drawn at most this wide
# Query-config fields already shown under their own name.
_SHOWN_QUERY_FIELDS = {"seg_quality", "prior_extra_m", "seed", "queries", "scenario"}


@dataclass
class RunData:
    path: Path
    config: dict
    rows: list[dict[str, str]]
    summary: dict
    complete: bool
    settings: dict[str, Any] = field(default_factory=dict)  # the describable settings (``describe``)
    label: str = ""
    ignored: list[str] = field(default_factory=list)  # ids of rows left out: no query of this run


def load_run(path: str | Path) -> RunData:
    """A run folder of ``semcityloc benchmark`` (its ``run.json`` and ``results.csv``)."""
    path = Path(path)
    run_file = path / RUN_FILE
    if not run_file.is_file():
        raise BenchmarkError(f"{path}: not a benchmark run folder (no {RUN_FILE})")
    try:
        config = json.loads(run_file.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise BenchmarkError(f"{run_file}: unreadable ({exc})") from exc
    if not isinstance(config, dict):
        raise BenchmarkError(
            f"{run_file}: not a JSON object but {type(config).__name__}; not a run's {RUN_FILE}"
        )
    queries = config.get("queries", 0)
    if isinstance(queries, bool) or not isinstance(queries, int) or queries < 0:
        raise BenchmarkError(f"{run_file}: 'queries' is {queries!r}, not a count of queries")
    results = path / RESULTS_FILE
    rows = parse_results(read_run_file(results), results, strict=False)
    ignored: list[str] = []
    if "queries" in config:  # rows of ids that are not this run's queries (q0000 ... q{queries-1}) left out
        wanted = {query_id(i) for i in range(int(config["queries"]))}
        ignored = [r["query_id"] for r in rows if r["query_id"] not in wanted]
        rows = [r for r in rows if r["query_id"] in wanted]
    complete = len(rows) == int(config.get("queries", -1))
    summary = summarize_rows(rows, config)  # from the rows: the same numbers as summary.json
    return RunData(path, config, rows, summary, complete, describe(config), ignored=ignored)


def ignored_note(run: RunData) -> str:
    """The rows of a run's ``results.csv`` that are no query of the run (another run's, an edit), left out."""
    n, shown = len(run.ignored), ", ".join(run.ignored[:5]) + (", ..." if len(run.ignored) > 5 else "")
    return (
        f"{run.path}: {n} row{'s' * (n != 1)} of {RESULTS_FILE} left out, not queries of this "
        f"{run.config.get('queries')}-query run: {shown}"
    )


def missing_details_note(run: RunData) -> str | None:
    """The finished queries whose details file a run should hold (its first ``keep_details``) but does not
    (a deleted ``details/``): no figure of them, and a resume restores them; None when none is missing."""
    keep = run.config.get("keep_details", 0)
    keep = keep if isinstance(keep, int) and not isinstance(keep, bool) else 0
    missing = missing_details(run.path, run.rows, min(keep, int(run.config.get("queries", 0))))
    if not missing:
        return None
    again = "run the command that made the run again to restore them"
    return f"{missing_details_phrase(run.path, missing)}: no figure of them; {again}"


def incomplete_note(run: RunData) -> str:
    """What is missing from an unfinished (stopped or crashed) run: its rows reported, the rest named."""
    total = int(run.config.get("queries", 0))
    missing = [query_id(i) for i in range(total) if query_id(i) not in {r["query_id"] for r in run.rows}]
    shown = ", ".join(missing[:5]) + (", ..." if len(missing) > 5 else "")
    return (
        f"{run.path}: incomplete run, {len(run.rows)} of {total} queries have a row; missing {shown}"
        f"{'' if (run.path / SUMMARY_FILE).is_file() else f' and {SUMMARY_FILE}'} (run the same command "
        "again to finish it); the tables use the rows there are"
    )


def _prior_label(extra) -> str:
    if not extra:
        return "none"
    a, b = extra
    return f"{a:g}-{b:g} m"


def perception_of(config: dict) -> str:
    """Short perception label of a real-data run: ``oracle``, ``oracle-degraded (trained)``, ``masks``,
    ``dinov3-dpt + moge2``, ..."""
    perception = str(config.get("perception"))
    if perception == "oracle-degraded":
        return f"{perception} ({config.get('seg_quality')})"
    return perception


def _data_name(value: Any) -> str:
    values = value if isinstance(value, list) else [value]
    return " + ".join(Path(str(v)).name for v in values)


def is_real(config: dict) -> bool:
    """Is this run (its ``run.json``) over real images (a data set, a user's photos), not simulated?"""
    return config.get("mode") in REAL_MODES


def describe(config: dict) -> dict[str, Any]:
    """The settings of a run that a reader tells runs apart by (display values). Real-data runs (a data
    set, a user's photos) are told apart by method, data, perception, preset and their number of queries;
    simulated runs by the simulation's settings."""
    if is_real(config):
        return {
            "method": config.get("method"),
            "data": _data_name(config.get("dataset") or config.get("images")),
            "perception": perception_of(config),
            "city": Path(config.get("city_path", "?")).name,
            "preset": config.get("localizer_preset"),
            "seed": config.get("seed"),
            "queries": config.get("queries"),
        }
    lod = config.get("lod")
    out: dict[str, Any] = {
        "method": config.get("method"),
        "city": "generated" if config.get("city") == "generated" else Path(config.get("city_path", "?")).name,
        "lod": f"LoD{lod}" if lod else "highest",
        "scenario": (config.get("query_config") or {}).get("scenario", "clean"),
        "seg_quality": config.get("seg_quality"),
        "prior_extra": _prior_label(config.get("prior_extra_m")),
        "seed": config.get("seed"),
        "queries": config.get("queries"),
        "preset": config.get("localizer_preset"),
    }
    for k, v in sorted((config.get("query_config") or {}).items()):
        if k not in _SHOWN_QUERY_FIELDS:
            out[f"q.{k}"] = json.dumps(v, sort_keys=True) if isinstance(v, list | dict) else v
    if config.get("sweep_knob") is not None:
        out["sweep_knob"] = config["sweep_knob"]
        out["sweep_value"] = json.dumps(config.get("sweep_value"))
    return out


def differing_keys(runs: list[RunData]) -> list[str]:
    """The settings whose values differ between ``runs``. When simulated and real-data runs are mixed,
    a setting only one kind has (the simulation's ``q.*``, a data set's ``data``) is compared among the
    runs that have it: that the other kind lacks it says nothing the method, city and perception do not."""
    keys: list[str] = []
    for run in runs:
        keys += [k for k in run.settings if k not in keys]
    mixed = len({is_real(r.config) for r in runs}) > 1
    out = []
    for k in keys:
        having = [r for r in runs if k in r.settings] if mixed else runs
        if len({json.dumps(r.settings.get(k), default=str) for r in having}) > 1:
            out.append(k)
    return out


def _order_value(key: str, value: Any):
    if value is None:  # a setting this run does not have (a real-data run beside simulated ones): last
        return (math.inf, "")
    if key == "method":
        return (ABLATIONS.index(value), "") if value in ABLATIONS else (len(ABLATIONS), str(value))
    if key == "seg_quality":
        return (SEG_ORDER.index(value), "") if value in SEG_ORDER else (len(SEG_ORDER), str(value))
    if key == "prior_extra":
        return (0.0, "") if value == "none" else (float(str(value).split("-")[0]), str(value))
    if key == "lod":
        return (int(value[3:]), "") if str(value).startswith("LoD") else (9, str(value))
    if key == "sweep_value":
        return sweep_x(value)
    if key == "perception":
        order = ("oracle", "oracle-degraded", "masks")
        head = str(value).split(" ")[0]
        return (order.index(head), str(value)) if head in order else (len(order), str(value))
    return (0, str(value))


def sweep_x(value: Any) -> tuple[float, str]:
    """A sweep value's place on the x axis: the number, the mean of a pair, or 0 for anything else."""
    try:
        v = json.loads(value) if isinstance(value, str) else value
    except ValueError:
        v = value
    if isinstance(v, list) and v and all(isinstance(x, int | float) for x in v):
        return (float(np.mean(v)), str(value))
    if isinstance(v, int | float) and not isinstance(v, bool):
        return (float(v), str(value))
    return (0.0, str(value))


def label_runs(runs: list[RunData]) -> None:
    """Short labels: the method (with ``[perception]`` on real data), plus ``key=value`` of every other
    setting that differs (``differing_keys``) and that the run has."""
    keys = differing_keys(runs)
    for run in runs:
        method = str(run.settings["method"])
        perception = run.settings.get("perception")
        parts = [f"{method} [{perception}]" if perception is not None else method]
        parts += [
            f"{k}={run.settings[k]}" for k in keys if k not in ("method", "perception") and k in run.settings
        ]
        run.label = ", ".join(parts) + (
            "" if run.complete else f" (incomplete {len(run.rows)}/{run.config['queries']})"
        )


# ----------------------------------------------------------------------------------------------- tables
def _num(v: Any, digits: int = 1) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, float) and math.isinf(v):
        return "inf"
    return f"{v:.{digits}f}"


def markdown_table(headers: list[str], rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(out) + "\n"


def metric_headers() -> list[str]:
    recall = [f"R@{m:g}m,{d:g}° (≤ / <)" for m, d in THRESHOLDS]
    return [
        "queries",
        "localized",
        "not loc.",
        "skipped",
        *recall,
        "med. xyz m",
        "med. yaw °",
        "mean xyz m",
        "mean yaw °",
        f"all: mean / med. xyz m (cap {CAP_XYZ_M:g})",
        "precision %",
        "s/img",
    ]


def metric_cells(s: dict) -> list[str]:
    cells = [
        str(s.get("queries", "-")),
        str(s.get("localized", "-")),
        str(s.get("not_localized", "-")),
        str(s.get("skipped", 0)),
    ]
    strict = s.get("recall_strict", {})
    for m, d in THRESHOLDS:
        key = threshold_key(m, d)
        cells.append(f"{_num(s.get(key))} / {_num(strict.get(key))}")
    cells += [
        _num(s.get("median_xyz_m"), 2),
        _num(s.get("median_yaw_deg"), 2),
        _num(s.get("mean_xyz_m"), 2),
        _num(s.get("mean_yaw_deg"), 2),
        f"{_num(s.get('mean_xyz_m_capped'), 2)} / {_num(s.get('median_xyz_m_capped'), 2)}",
        _num(s.get("acceptance_precision")),
        _num(s.get("sec_per_image"), 2),
    ]
    return cells


def summary_markdown(summaries: list[dict], labels: list[str], label_header: str = "method") -> str:
    """A Markdown table of run summaries (the CLI prints it after a run)."""
    rows = [[lab, *metric_cells(s)] for lab, s in zip(labels, summaries, strict=True)]
    return markdown_table([label_header, *metric_headers()], rows)


CSV_METRICS = (
    "queries",
    "localized",
    "not_localized",
    "skipped",
    *(threshold_key(m, d) for m, d in THRESHOLDS),
    *(f"strict_{threshold_key(m, d)}" for m, d in THRESHOLDS),
    "mean_xyz_m",
    "median_xyz_m",
    "mean_rot_deg",
    "median_rot_deg",
    "mean_yaw_deg",
    "median_yaw_deg",
    "median_xyz_m_all",
    "median_yaw_deg_all",
    "mean_xyz_m_capped",
    "median_xyz_m_capped",
    "mean_rot_deg_capped",
    "coverage",
    "acceptance_precision",
    "mean_query_miou",
    "map_miou_pooled",
    "map_miou_per_image",
    "sec_per_image",
)


def _csv_metrics(s: dict) -> list[Any]:
    out = []
    for k in CSV_METRICS:
        v = s.get("recall_strict", {}).get(k[7:]) if k.startswith("strict_") else s.get(k)
        out.append("" if v is None else v)
    return out


def comparable_runs(runs: list[RunData], factor: str) -> list[RunData]:
    """The runs that form a comparison along ``factor``: those whose group (runs agreeing on every other
    setting) holds two or more values of ``factor``. Empty when no group does."""
    groups: dict[str, list[RunData]] = {}
    for r in runs:
        other = {k: v for k, v in r.settings.items() if k != factor}
        groups.setdefault(json.dumps(other, sort_keys=True, default=str), []).append(r)
    keep = {
        id(r)
        for members in groups.values()
        if len({json.dumps(m.settings.get(factor), default=str) for m in members}) > 1
        for r in members
    }
    return [r for r in runs if id(r) in keep]


def build_table(runs: list[RunData], factor: str, hide: tuple[str, ...] = ()) -> tuple[str, str]:
    """(Markdown, CSV) of one table: a row per run, ``factor`` first, then the other settings that differ
    between these runs (rows sorted by those, then by ``factor``) except those starting with ``hide`` and
    ``queries`` (a metric column of its own)."""
    context = [
        k for k in differing_keys(runs) if k not in (factor, "queries") and not (hide and k.startswith(hide))
    ]
    ordered = sorted(
        runs,
        key=lambda r: (
            [_order_value(k, r.settings.get(k)) for k in context],
            _order_value(factor, r.settings.get(factor)),
        ),
    )
    headers = [factor, *context]
    md_rows, csv_rows = [], []
    for r in ordered:
        keys = [str(r.settings.get(k)) for k in headers]
        if not r.complete:
            keys[0] += f" (incomplete {len(r.rows)}/{r.config['queries']})"
        miou = f"{_num(r.summary.get('map_miou_pooled'))} / {_num(r.summary.get('map_miou_per_image'))}"
        md_rows.append([*keys, *metric_cells(r.summary), f"{_num(r.summary.get('mean_query_miou'))}", miou])
        csv_rows.append([*keys, *_csv_metrics(r.summary), str(r.path)])
    md = markdown_table(
        [*headers, *metric_headers(), "query mIoU % (vs reality)", "mIoU % vs map: pooled / per image"],
        md_rows,
    )
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow([*headers, *CSV_METRICS, "run_dir"])
    writer.writerows(csv_rows)
    return md, buf.getvalue()


# ------------------------------------------------------------------------------------------------ plots
def _pyplot():
    try:
        import matplotlib  # optional dependency, loaded only when used
    except ImportError as exc:
        raise OptionalDependencyError("matplotlib", "plots", "the report's plots") from exc
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # optional dependency, loaded only when used

    return plt


def _errors(run: RunData, column: str) -> np.ndarray:
    """Per evaluated query (skipped ones left out), inf where not localized."""
    rows = [r for r in run.rows if r["status"] != SKIPPED]
    return np.array([float(r[column]) if r["status"] == LOCALIZED and r[column] else math.inf for r in rows])


def plot_cumulative(runs: list[RunData], column: str, xlabel: str, path: Path, x_max: float = 10.0) -> Path:
    plt = _pyplot()
    grid = np.linspace(0.0, x_max, 401)
    fig, ax = plt.subplots(figsize=(6, 4))
    for run in runs:
        ax.plot(grid, cumulative_curve(_errors(run, column), grid), label=run.label)
    for m, _ in THRESHOLDS:
        ax.axvline(m, color="0.8", lw=0.8, ls=":")
    ax.set_xlim(0, x_max)
    ax.set_ylim(0, 100)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("queries with error ≤ x (%)")
    return _save_figure(plt, fig, ax, path, legend_loc="lower right")


def _save_figure(plt, fig, ax, path: Path, legend_loc: str = "best") -> Path:
    """Grid, legend, tight layout, PNG at 120 dpi; the figure is closed."""
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc=legend_loc)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def noise_x(run: RunData) -> float:
    extra = run.config.get("prior_extra_m")
    return 0.0 if not extra else 0.5 * (float(extra[0]) + float(extra[1]))


def plot_recall_vs_prior(runs: list[RunData], path: Path) -> Path:
    """Recall (≤) at each threshold against the extra prior noise (bin centre, 0 = base noise only);
    one colour per group of runs that agree on everything but the prior noise (only the runs of such
    comparisons when there are any, else every run)."""
    groups = prior_noise_groups(runs)
    return plot_recall_lines(groups, noise_x, "extra prior noise per axis (m, bin centre)", path)


def prior_noise_groups(runs: list[RunData]) -> dict[str, list[RunData]]:
    """The runs of the recall-vs-prior-noise lines by group (everything but the prior noise)."""
    runs = comparable_runs(runs, "prior_extra") or runs
    context = [k for k in differing_keys(runs) if k != "prior_extra"]
    groups: dict[str, list[RunData]] = {}
    for run in runs:
        name = ", ".join(f"{run.settings.get(k)}" for k in context) or str(run.settings["method"])
        groups.setdefault(name, []).append(run)
    return groups


def plot_recall_lines(groups: dict[str, list[RunData]], x_of, xlabel: str, path: Path) -> Path:
    """Recall (≤) at each threshold against ``x_of(run)``, one colour per group of runs."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    styles = ("-", "--", ":")
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for g, (name, members) in enumerate(groups.items()):
        members = sorted(members, key=x_of)
        x = [x_of(r) for r in members]
        for (m, d), ls in zip(THRESHOLDS, styles, strict=False):
            y = [r.summary.get(threshold_key(m, d), math.nan) for r in members]
            ax.plot(x, y, ls, marker="o", color=colors[g % len(colors)], label=f"{name} {m:g}m,{d:g}°")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("recall (%)")
    ax.set_ylim(0, 100)
    return _save_figure(plt, fig, ax, path)


def plot_recall_vs_sweep(runs: list[RunData], knob: str, path: Path) -> Path:
    """Recall (≤) at each threshold against the values of a sweep (one line per method)."""
    groups: dict[str, list[RunData]] = {}
    for run in runs:
        groups.setdefault(str(run.settings["method"]), []).append(run)
    return plot_recall_lines(groups, lambda r: sweep_x(r.settings["sweep_value"])[0], knob, path)


TRUE_COLOR, EST_COLOR = (0, 200, 255), (255, 0, 255)


def overlay_image(
    query_labels: np.ndarray, est_labels: np.ndarray | None, true_labels: np.ndarray | None
) -> np.ndarray:
    """RGB uint8: the query mask (palette, faded; IGNORE white) with the label boundaries of the render at
    the true pose (cyan, when there is one) and at the estimated pose (magenta) drawn on top."""
    rgb = (0.55 * label_colors(query_labels) + 0.45 * 255).astype(np.uint8)
    if true_labels is not None:
        rgb[class_boundaries(true_labels)] = TRUE_COLOR
    if est_labels is not None:
        rgb[class_boundaries(est_labels)] = EST_COLOR
    return rgb


def photo_overlay(
    photo: np.ndarray, renderer: Renderer, camera: Camera, true, est, est_renderer: Renderer | None = None
) -> np.ndarray:
    """RGB uint8: the photo (at ``camera``'s size) with the model's visible edges at the true pose (cyan)
    and at the estimate (magenta; drawn by ``est_renderer``, the map it was found on, when given)."""
    out = photo
    for pose, color, r in ((true, TRUE_COLOR, renderer), (est, EST_COLOR, est_renderer or renderer)):
        if pose is not None:
            view = r.render(camera, pose, depth=True, face_ids=True)
            out = draw_edges(out, visible_edges(view.face_ids[0], view.depth[0], r.scene), color)
    return out


def _pose(matrix: np.ndarray):
    return None if not np.all(np.isfinite(matrix)) else Pose.from_cam_from_world(matrix)


def plot_details(
    details: dict, map_model, path: Path, title: str, photo_path: Path | None = None, maps=None
) -> Path:
    """One query: overlay (``overlay_image``), the photo with the model's edges (``photo_overlay``, when
    ``photo_path`` is given: real-data runs), xy slice at the best (z, yaw) and yaw slice at the best
    (x, y, z) of the coarse cost volume, with the true (green), prior (blue) and estimated (red) poses.
    Drawn at most ``FIGURE_MAX_WIDTH`` wide; a query without a true pose (a user's photo) shows the
    estimate alone. ``maps``: the run's ``found_map.FoundMaps`` (default: the model as it is), so that the
    poses are drawn on the map the run searched (with its eaves) and an estimate found on the map with
    eaves on its flat roofs on that map, and the caption says so."""

    plt = _pyplot()
    fx, fy, cx, cy, w, h = details["camera"]
    camera = Camera(fx, fy, cx, cy, int(w), int(h))
    camera = camera.scaled(*scaled_size(camera.width, camera.height, FIGURE_MAX_WIDTH))
    labels = resize_nearest(details["labels"], camera.width, camera.height)
    true, prior, est = (_pose(details[f"{k}_cam_from_world"]) for k in ("true", "prior", "est"))
    maps = maps or FoundMaps(map_model, Renderer(map_model, engine="numba"))
    renderer = maps.searched()
    est_renderer, est_map = maps.for_estimate(details["meta"].get("flat_roof_eaves"))
    true_lab = renderer.render(camera, true).labels[0] if true is not None else None
    est_lab = est_renderer.render(camera, est).labels[0] if est is not None else None
    est_note = f"\nestimate drawn on {est_map}" if est is not None and est_map else ""
    scores = details["cost_scores"]
    axes_info = details["meta"].get("cost_volume")
    has_volume = scores.size > 0 and axes_info is not None
    photo = load_image(photo_path, max_width=camera.width) if photo_path is not None else None
    if photo is not None and photo.shape[:2] != (camera.height, camera.width):
        photo = None  # not the photo of these details (its size differs): no photo panel

    n_panels = 1 + (photo is not None) + 2 * has_volume
    fig, axes = plt.subplots(1, n_panels, figsize=(5 * n_panels, 4.2), squeeze=False)
    panels = iter(axes[0])
    ax = next(panels)
    ax.imshow(overlay_image(labels, est_lab, true_lab))
    status = details["meta"].get("status")
    truth_note = "cyan = true pose, " if true is not None else "(no true pose) "
    ax.set_title(f"{title}: {status}\nmask; boundaries: {truth_note}magenta = estimate{est_note}", fontsize=8)
    ax.axis("off")
    if photo is not None:
        ax = next(panels)
        ax.imshow(photo_overlay(photo, renderer, camera, true, est, est_renderer))
        ax.set_title(f"photo; model edges: {truth_note}magenta = estimate{est_note}", fontsize=8)
        ax.axis("off")
    if has_volume:
        xs, ys, zs, yaws = (np.asarray(axes_info[k]) for k in ("x", "y", "z", "yaw"))
        bi, bj, bk, bl = np.unravel_index(int(np.argmax(scores)), scores.shape)
        poses = {"true": (true, "g", "x"), "prior": (prior, "b", "+"), "estimate": (est, "r", "o")}
        ax = next(panels)
        hx = (xs[-1] - xs[0]) / max(len(xs) - 1, 1) / 2  # cells centred on the samples
        hy = (ys[-1] - ys[0]) / max(len(ys) - 1, 1) / 2
        ext = (xs[0] - hx, xs[-1] + hx, ys[0] - hy, ys[-1] + hy)
        im = ax.imshow(scores[:, :, bk, bl].T, origin="lower", extent=ext, aspect="equal", cmap="viridis")
        fig.colorbar(im, ax=ax, fraction=0.046)
        for name, (pose, color, marker) in poses.items():
            if pose is not None:
                c = pose.center
                ax.plot(c[0], c[1], marker, color=color, mfc="none", ms=9, mew=2, label=name)
        ax.set_title(f"cost volume xy slice (z = {zs[bk]:.1f} m, yaw = {yaws[bl]:.1f}°)", fontsize=8)
        ax.set_xlabel("x (local m)")
        ax.set_ylabel("y (local m)")
        ax.legend(fontsize=7)
        ax = next(panels)
        ax.plot(yaws, scores[bi, bj, bk, :], "k.-")
        mid = yaws[len(yaws) // 2]
        for name, (pose, color, _) in poses.items():
            if pose is not None:
                yaw = float(pose.to_xyz_rpy()[5])
                ax.axvline(mid + wrap_deg(yaw - mid), color=color, ls="--", label=name)
        ax.set_title(f"yaw slice at x = {xs[bi]:.1f}, y = {ys[bj]:.1f}, z = {zs[bk]:.1f}", fontsize=8)
        ax.set_xlabel("yaw (deg)")
        ax.set_ylabel("score (mean class IoU)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ----------------------------------------------------------------------------------------------- report
@dataclass
class ReportOutput:
    out_dir: Path
    tables: dict[str, tuple[Path, Path]]  # name -> (markdown, csv)
    plots: list[Path]
    markdown: Path
    notes: list[str]


ACCEPT_THRESHOLDS = (0.3, 0.5, 0.7, 0.9)
RIGHT_M, RIGHT_DEG = 5.0, 5.0  # "right" for the acceptance: the calibrated probability's own event
MISSES_NOTE = (
    "near: accepted within 5 m / 5° but beyond 2 m / 2°; refused-near: refused though the pose found was "
    "within 5 m / 5°; refused-wrong: refused, rightly; wrong: accepted beyond 5 m / 5°; unreadable-input: "
    "the query's mask or depth file could not be read, so nothing was searched or refused (a miss all the "
    "same, counted in the recall); failed: the query's worker died on every try (Ray). Map agreement: the "
    "query mask's building IoU against the map's labels at the true pose (simulated runs): low where the "
    "map differs from the world in view (`python benchmarks/miss_causes.py RUN` lists every miss). "
    "Outdated-map warning: results that said the image and the map disagree about buildings at the pose "
    "found (the evidence a run on real photos has)."
)


def acceptance_data(run: RunData) -> tuple[np.ndarray, np.ndarray] | None:
    """(probability, right) of the queries with a found pose and a calibrated probability, or None."""
    p, right = [], []
    for row in run.rows:
        prob, e_m, e_deg = (row.get(k, "") for k in ("probability", "found_err_xyz_m", "found_err_rot_deg"))
        if not (prob and e_m and e_deg):
            continue
        try:
            prob_f, e_m_f, e_deg_f = float(prob), float(e_m), float(e_deg)
        except ValueError:
            continue
        if np.isfinite(prob_f) and np.isfinite(e_m_f) and np.isfinite(e_deg_f):
            p.append(prob_f)
            right.append(e_m_f <= RIGHT_M and e_deg_f <= RIGHT_DEG)
    return (np.array(p), np.array(right, dtype=float)) if p else None


def risk_coverage_table(runs: list[RunData]) -> tuple[str, str]:
    """Per run: coverage and precision (found pose within 5 m / 5 deg) when accepting at each threshold,
    and the expected calibration error of the probability."""
    headers = ["run", "poses", "right %", "ECE"] + [
        f"p ≥ {t}: coverage / precision %" for t in ACCEPT_THRESHOLDS
    ]
    rows, csv_rows = (
        [],
        [["run", "poses", "right", "ece"] + [f"{k}_{t}" for t in ACCEPT_THRESHOLDS for k in ("cov", "prec")]],
    )
    for run in runs:
        p, y = acceptance_data(run)
        cells, values = [], []
        for t in ACCEPT_THRESHOLDS:
            acc = p >= t
            prec = float(y[acc].mean()) if acc.any() else float("nan")
            cells.append(f"{100 * acc.mean():.0f} / {_num(100 * prec)}")
            values += [float(acc.mean()), prec]
        ece = calibration_error(p, y)
        rows.append([run.label, str(len(p)), f"{100 * y.mean():.0f}", f"{ece:.3f}"] + cells)
        csv_rows.append([run.label, len(p), float(y.mean()), ece] + values)
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(csv_rows)
    return markdown_table(headers, rows), buf.getvalue()


def misses_table(runs: list[RunData]) -> tuple[str, str]:
    """Per run: the hits and each kind of miss at 2 m / 2 deg (``miss_kinds``), the map's median building
    agreement at the truth of the hits and of the misses, the hits where the map agrees (>= 0.6), and the
    hits and misses that carried an outdated-map warning."""
    headers = ["run", "queries", "hits", *MISS_KINDS, "map agreement at truth: hits / misses",
               "hits where the map agrees ≥ 0.6", "outdated-map warning: hits / misses"]  # fmt: skip
    rows, csv_rows = [], [["run", "queries", "hit", *MISS_KINDS, "agree_hit", "agree_miss", "hits_agree",
                           "warned_hit", "warned_miss"]]  # fmt: skip
    for run in runs:
        m = summarize_misses([r for r in run.rows if r["status"] != SKIPPED])
        med = {k: float("nan") if v is None else v for k, v in m["median_map_building_iou"].items()}
        agrees = m["hits_where_map_agrees"]
        hits_agree = f"{agrees[0]} / {agrees[1]}" if agrees else "–"
        counts = [m["count"][k] for k in MISS_KINDS]
        warned = m["map_warned"]
        rows.append(
            [run.label, str(m["queries"]), str(m["count"]["hit"]), *map(str, counts),
             f"{_num(med['hit'], 2)} / {_num(med['misses'], 2)}", hits_agree, f"{warned[0]} / {warned[1]}"]
        )  # fmt: skip
        csv_rows.append([run.label, m["queries"], m["count"]["hit"], *counts, med["hit"], med["misses"],
                         hits_agree, *warned])  # fmt: skip
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(csv_rows)
    return markdown_table(headers, rows), buf.getvalue()


def plot_risk_coverage(runs: list[RunData], path: Path) -> Path:
    """Precision of the accepted poses against the share accepted, as the threshold falls."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4))
    for run in runs:
        p, y = acceptance_data(run)
        curve = risk_coverage(p, y)
        ax.plot([c for _, c, _ in curve], [100 * pr for _, _, pr in curve], label=run.label)
    ax.set_xlabel("coverage (share of queries accepted)")
    ax.set_ylabel("precision of accepted poses (%; within 5 m / 5°)")
    ax.set_xlim(0, 1)
    return _save_figure(plt, fig, ax, path)


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in text).strip("_")[:60] or "run"


def _write_table(
    out: Path, tables: dict, name: str, title: str, md: str, csv_text: str, preface: str = ""
) -> list[str]:
    """Write ``tables/<name>.md`` and ``.csv``, record them in ``tables``; the report's lines for it."""
    md_path, csv_path = out / "tables" / f"{name}.md", out / "tables" / f"{name}.csv"
    md_path.write_text(f"## {title}\n\n{md}", encoding="utf-8")
    csv_path.write_text(csv_text, encoding="utf-8")
    tables[name] = (md_path, csv_path)
    return [f"## {title}", "", *([preface, ""] if preface else []), md]


def make_report(run_dirs: list[str | Path], out_dir: str | Path, overlays: int = 2) -> ReportOutput:
    """Tables, plots and ``report.md`` from benchmark run folders (module docstring)."""
    if not run_dirs:
        raise BenchmarkError("name at least one benchmark run folder")
    runs = [load_run(p) for p in run_dirs]
    label_runs(runs)
    out = Path(out_dir)
    (out / "tables").mkdir(parents=True, exist_ok=True)
    (out / "plots").mkdir(parents=True, exist_ok=True)
    differ = differing_keys(runs)
    notes: list[str] = [incomplete_note(r) for r in runs if not r.complete]
    notes += [ignored_note(r) for r in runs if r.ignored]
    notes += [n for n in map(missing_details_note, runs) if n is not None]
    doc = ["# SemCityLoc benchmark report", "", f"Runs: {len(runs)}", ""]
    doc += [f"- `{r.path}`: {r.label}" for r in runs]
    doc += [
        "",
        "Recall cells: `≤` convention (LoD-Loc v1) / strict `<`; not_localized queries count as failures.",
        "",
    ]
    tables: dict[str, tuple[Path, Path]] = {}
    sweep_plots: list[Path] = []
    for name, (factor, title) in TABLES.items():
        if name != "main" and not any(factor in r.settings for r in runs):
            continue  # a setting none of these runs has (perception of simulated runs, LoD of real ones)
        members = comparable_runs(runs, factor)
        if not members and name == "main":
            members = runs  # no methods to compare: the main table lists every run
        if not members:
            why = "all runs share" if factor not in differ else "no two runs differ only in"
            notes.append(f"table {name}: skipped, {why} {factor}")
            continue
        doc += _write_table(out, tables, name, title, *build_table(members, factor))

    for knob in sorted({r.config.get("sweep_knob") for r in runs} - {None}):
        members = [r for r in runs if r.config.get("sweep_knob") == knob]
        table = build_table(members, "sweep_value", hide=("q.",))
        doc += _write_table(out, tables, f"sweep_{_slug(knob)}", f"Sweep of `{knob}`", *table)
        sweep_plots.append(
            plot_recall_vs_sweep(members, knob, out / "plots" / f"recall_vs_{_slug(knob)}.png")
        )

    plots = [
        plot_cumulative(
            runs, "err_xyz_m", "camera-centre error (m)", out / "plots" / "cumulative_translation.png"
        ),
        plot_cumulative(
            runs, "err_rot_deg", "rotation error (deg)", out / "plots" / "cumulative_rotation.png"
        ),
        plot_recall_vs_prior(runs, out / "plots" / "recall_vs_prior_noise.png"),
    ]
    plots += sweep_plots
    acceptance = [r for r in runs if acceptance_data(r) is not None]
    if acceptance:
        title = "Acceptance: coverage and precision by probability threshold"
        doc += _write_table(out, tables, "acceptance", title, *risk_coverage_table(acceptance))
        plots.append(plot_risk_coverage(acceptance, out / "plots" / "risk_coverage.png"))
    with_truth = [r for r in runs if any(row.get("err_xyz_m", "") != "" for row in r.rows)]
    if with_truth:
        title = "Misses at 2 m / 2°, by kind, and the map's agreement with the world at the truth"
        doc += _write_table(out, tables, "misses", title, *misses_table(with_truth), preface=MISSES_NOTE)
    plots += _detail_figures(runs, out / "plots", overlays, notes)
    doc += ["## Figures", ""] + [f"![{p.stem}](plots/{p.name})" for p in plots]
    if notes:
        doc += ["", "## Notes", ""] + [f"- {n}" for n in notes]
    md_file = out / "report.md"
    md_file.write_text("\n".join(doc) + "\n", encoding="utf-8")
    return ReportOutput(out, tables, plots, md_file, notes)


def run_map(config: dict) -> CityModel:
    """The map model a run localized against, in its queries' frame: a simulated run's (``spec.load_map``),
    a data set's model (rotated into ENU for Swiss-EPFL's ECEF frame, as ``read_lodloc`` does) or a photo
    run's city model."""
    mode = config.get("mode")
    if mode == "photos":  # a model file or a tile store (merged whole)
        return load_city(config["city_path"], lod=config.get("lod"), crs=config.get("crs"))
    if mode == "dataset":
        model = load_city(config["city_path"])
        if config.get("frame") == FRAME_ECEF:
            model = rotate_model(model, enu_from_ecef(*config["ecef_origin_llh"]))
        return model
    return load_map(config)


def photo_of(config: dict, query_meta: dict) -> Path | None:
    """The photo of a real-data query, when it is still where the run found it."""
    candidates = []
    if query_meta.get("image"):
        candidates.append(Path(query_meta["image"]))
    name, scene = query_meta.get("name"), query_meta.get("scene")
    if config.get("mode") == "dataset" and name:
        roots = config["dataset"] if isinstance(config["dataset"], list) else [config["dataset"]]
        for root in map(Path, roots):
            candidates += [root / IMAGE_DIR / name, root / str(scene) / IMAGE_DIR / name]
    return next((c for c in candidates if c.is_file()), None)


def map_renderer(run: RunData, cache: dict, notes: list[str], consequence: str):
    """(map model, the renderers of its drawings: ``found_map.FoundMaps`` on a numba renderer) of a run,
    shared through ``cache`` by runs of one map (and one map's eaves); None (and a note: its map cannot be
    loaded, ``consequence``) when the map is gone."""
    keys = ("mode", "city_path", "lod", "map_source", "crs", "frame", "ecef_origin_llh")
    key = json.dumps([run.config.get(k) for k in keys])
    if key not in cache:
        try:
            model = run_map(run.config)
            cache[key] = (model, Renderer(model, engine="numba"))
        except SemCityLocError as exc:
            cache[key] = None
            notes.append(f"{run.path}: {consequence}, its map cannot be loaded ({exc})")
    if cache[key] is None:
        return None
    model, renderer = cache[key]
    maps = FoundMaps.of_run(model, renderer, run.config)
    return model, cache.setdefault(json.dumps([key, maps.eaves_m, maps.flat_roofs]), maps)


def readable_details(path: Path, notes: list[str], consequence: str) -> dict | None:
    """``load_details`` of ``path``; None with a note saying ``consequence`` when the file cannot be read
    (truncated, not an npz, a part missing): one damaged file costs its query's figure, not the report."""
    try:
        return load_details(path)
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        notes.append(f"{path}: unreadable details ({type(exc).__name__}: {exc}); {consequence}")
        return None


def _detail_figures(runs: list[RunData], plot_dir: Path, overlays: int, notes: list[str]) -> list[Path]:
    figures: list[Path] = []
    cache: dict[str, Any] = {}
    for n, run in enumerate(runs):
        files = sorted((run.path / DETAILS_DIR).glob("q*.npz"))[: max(0, overlays)]
        if not files:
            continue
        pair = map_renderer(run, cache, notes, "no query figures")
        if pair is None:
            continue
        model, maps = pair
        for f in files:
            details = readable_details(f, notes, f"no figure of {f.stem}")
            if details is None:
                continue
            photo = photo_of(run.config, details["meta"].get("query_meta") or {})
            name = f"query_{n:02d}_{_slug(run.path.name)}_{f.stem}.png"
            title = f"{run.label} {f.stem}"
            figures.append(plot_details(details, model, plot_dir / name, title, photo, maps))
    return figures

"""A benchmark run folder as the report reads it, and how runs are told apart, labelled and grouped.

Why its own module: the Markdown report (``benchmark.report``, with ``report_tables`` and
``report_plots``) and the HTML page (``report_html``, ``report_plotly``) read runs the same way.
``load_run`` reads a run folder, never writing to it (its ``run.json`` and the rows of ``results.csv``;
an unfinished run is reported with its finished rows and marked incomplete), and the notes say what is
missing from it; ``describe``, ``differing_keys`` and ``label_runs`` name the settings that tell runs
apart; ``comparable_runs``, ``prior_noise_groups``, ``noise_x`` and ``sweep_x`` group runs and place
them on a plot's axis; ``acceptance_data`` takes each query's calibrated probability and whether its
pose was right from the rows; ``has_truth`` tells a run whose queries have true poses from one that has
none (a user's photos run without ``--truth``), whose report shows instead what the run says of itself
(``self_assessment``: the probability, the stated sigmas, the shift from the prior); ``run_map``,
``map_renderer``, ``photo_of`` and ``readable_details`` find what a query's drawing needs beyond the rows:
the run's map, the query's photo, its details file; ``city_changed`` keeps a run's drawings off a city model
that changed since the run (its recorded ``city_sha256``).
"""

from __future__ import annotations

import json
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from semcityloc.benchmark.found_map import FoundMaps
from semcityloc.benchmark.queries import query_id
from semcityloc.benchmark.results import (
    REASON_SKIPPED_MISS,
    SKIPPED,
    cell_float,
    counted_as,
    load_details,
    missing_details,
    missing_details_phrase,
    parse_results,
    skipped_miss_row,
    summarize_rows,
)
from semcityloc.benchmark.runfiles import RESULTS_FILE, RUN_FILE, SUMMARY_FILE, read_run_file
from semcityloc.benchmark.spec import load_map
from semcityloc.citymodel.model import CityModel
from semcityloc.citymodel.tiles import city_sha256, load_city
from semcityloc.datasets.lodloc import FRAME_ECEF, IMAGE_DIR, enu_from_ecef, rotate_model
from semcityloc.errors import BenchmarkError, SemCityLocError, counted, parameter
from semcityloc.evaluation.metrics import is_right
from semcityloc.geometry.conventions import wrap_deg
from semcityloc.localization.result import LOCALIZED
from semcityloc.render import Renderer

REAL_MODES = ("dataset", "photos")  # runs over real images (``mode`` in run.json); others are simulated
# Query-config fields already shown under their own name.
_SHOWN_QUERY_FIELDS = {"seg_quality", "prior_extra_m", "seed", "queries", "scenario"}


@dataclass
class RunData:
    """One run folder as the report reads it: its ``run.json`` config, its ``results.csv`` rows and summary,
    whether every query has a row, the settings that describe it, its label and the rows left out. Read
    once (``load_run``) and shared by the Markdown and HTML reports, so both read runs alike.
    """

    path: Path
    config: dict
    rows: list[dict[str, str]]
    summary: dict
    complete: bool
    settings: dict[str, Any] = field(default_factory=dict)  # the describable settings (``describe``)
    label: str = ""
    ignored: list[str] = field(default_factory=list)  # ids of rows left out: no query of this run


def _run_folder(path: str | Path) -> Path:
    """``path`` when it is a folder holding a ``run.json``; else ``BenchmarkError`` saying what it is: no
    such folder (a typo), a file, or a folder that is no run's."""
    path = Path(path)
    if not path.exists():
        raise BenchmarkError(f"{path}: no such run folder")
    if not path.is_dir():
        raise BenchmarkError(f"{path}: is a file, not a benchmark run folder (the folder holding {RUN_FILE})")
    if not (path / RUN_FILE).is_file():
        inside = sorted(p.name for p in path.iterdir() if (p / RUN_FILE).is_file())
        if inside:  # a sweep's folder, or a demo's: the runs are its subfolders
            shown = ", ".join(inside[:3]) + (", ..." if len(inside) > 3 else "")
            raise BenchmarkError(
                f"{path}: not a benchmark run folder (no {RUN_FILE}) but a folder of "
                f"{counted(len(inside), 'run')} ({shown}): give the run folders themselves ({path}/* when it "
                "holds nothing else, as a sweep's folder does)"
            )
        raise BenchmarkError(f"{path}: not a benchmark run folder (no {RUN_FILE})")
    return path


def unique_runs(run_dirs: list[str | Path]) -> list[Path]:
    """``run_dirs`` with a folder named twice (the same folder, however spelled) kept once, first spelling."""
    seen: dict[Path, Path] = {}
    for p in run_dirs:
        seen.setdefault(Path(p).resolve(), Path(p))
    return list(seen.values())


def load_run(path: str | Path) -> RunData:
    """A run folder of ``semcityloc benchmark`` (its ``run.json`` and ``results.csv``)."""
    path = _run_folder(path)
    run_file = path / RUN_FILE
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
        f"{run.path}: incomplete run, {len(run.rows)} of {counted(total, 'query')} "
        f"{'has' if len(run.rows) == 1 else 'have'} a row; missing {shown}"
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


def noise_x(run: RunData) -> float:
    """A run's place on the recall-versus-prior-noise axis: the middle of its extra prior error range in
    metres (0 for a run without extra prior noise).
    """
    extra = run.config.get("prior_extra_m")
    return 0.0 if not extra else 0.5 * (float(extra[0]) + float(extra[1]))


def prior_noise_groups(runs: list[RunData]) -> dict[str, list[RunData]]:
    """The runs of the recall-vs-prior-noise lines by group (everything but the prior noise)."""
    runs = comparable_runs(runs, "prior_extra") or runs
    context = [k for k in differing_keys(runs) if k != "prior_extra"]
    groups: dict[str, list[RunData]] = {}
    for run in runs:
        name = ", ".join(f"{run.settings.get(k)}" for k in context) or str(run.settings["method"])
        groups.setdefault(name, []).append(run)
    return groups


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
            right.append(is_right(e_m_f, e_deg_f))
    return (np.array(p), np.array(right, dtype=float)) if p else None


# What a report says in place of the recall conventions when no run has ground truth (``has_truth``).
NO_TRUTH_LINE = (
    f"No ground truth (no run has `{parameter('truth')}`): no errors or recall; the counts, the calibrated "
    "probability, the stated sigmas and the shift from the prior are what the runs say of themselves."
)


def has_truth(run: RunData) -> bool:
    """Can the run's errors be measured: a query of it has a true pose, or it has no query to judge yet
    (reported as always)? A run of photos without ``--truth`` has none: its recall would read 0 %, so the
    report leaves the errors out and shows ``self_assessment`` instead."""
    evaluated = any(r["status"] != SKIPPED for r in run.rows)
    return bool(run.summary.get("with_ground_truth")) or not evaluated


def no_truth_note(run: RunData) -> str:
    """The report's note on a run without ground truth (``has_truth``): what is left out and why."""
    return (
        f"{run.path}: no ground truth (a run without {parameter('truth')}), so no errors, recall or error "
        "curves of it; "
        "the table 'Without ground truth' shows what the run says of itself"
    )


def skipped_misses_note(run: RunData) -> str | None:
    """The report's note on a run whose photos of the truth were skipped before it ran
    (``results.skipped_miss_result``): they are misses in its recall, said with their reasons; None when
    it has none."""
    rows = [r for r in run.rows if skipped_miss_row(r)]
    if not rows:
        return None
    names = run.config.get("query_names") or []
    shown = [
        f"{names[int(r['index'])] if int(r['index']) < len(names) else r['query_id']} "
        f"({r['reason'].removeprefix(REASON_SKIPPED_MISS + ': ')})"
        for r in rows[:3]
    ]
    more = f"; {len(rows) - 3} more" if len(rows) > 3 else ""
    return (
        f"{run.path}: {len(rows)} skipped, counted as {counted_as(len(rows))} (photos with a true pose "
        f"that could not run, in 'not loc.' and the misses table's 'skipped'): {'; '.join(shown)}{more}"
    )


def self_assessment(run: RunData) -> dict[str, np.ndarray]:
    """What a run says of its poses, readable without ground truth, as arrays over its evaluated queries:
    ``probability`` (the calibrated acceptance probability of the pose found, accepted or not) with
    ``accepted`` (was the query localized); and over the localized ones the stated 1-sigma
    (``sigma_xy_m``, ``sigma_z_m``, ``sigma_yaw_deg``) and how far the pose moved from the prior
    (``shift_xy_m``, ``shift_z_m``, ``shift_yaw_deg``, absolute). NaN where a row lacks the value."""
    rows = [r for r in run.rows if r["status"] != SKIPPED]
    localized = [r for r in rows if r["status"] == LOCALIZED]

    def column(chosen: list[dict[str, str]], name: str) -> np.ndarray:
        return np.array([cell_float(r.get(name, "")) for r in chosen], dtype=np.float64)

    found = [r for r in rows if np.isfinite(cell_float(r.get("probability", "")))]
    est = {k: column(localized, f"est_{k}") for k in ("x", "y", "z", "yaw")}
    prior = {k: column(localized, f"prior_{k}") for k in ("x", "y", "z", "yaw")}
    return {
        "probability": column(found, "probability"),
        "accepted": np.array([r["status"] == LOCALIZED for r in found], dtype=bool),
        **{name: column(localized, name) for name in ("sigma_xy_m", "sigma_z_m", "sigma_yaw_deg")},
        "shift_xy_m": np.hypot(est["x"] - prior["x"], est["y"] - prior["y"]),
        "shift_z_m": np.abs(est["z"] - prior["z"]),
        "shift_yaw_deg": np.abs(wrap_deg(est["yaw"] - prior["yaw"])),
    }


def finite_max(values: np.ndarray, empty: float = float("nan")) -> float:
    """The largest of the finite ``values`` (a ``self_assessment`` array); ``empty`` when there are none."""
    finite = values[np.isfinite(values)]
    return float(finite.max()) if finite.size else empty


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


def city_changed(config: dict) -> str | None:
    """What a run's map drawings would get wrong, or None: its city model file or tile store
    (``city_path``) is no longer the one it ran on, by the ``city_sha256`` its ``run.json`` recorded (as a
    resumed run compares it, ``runfiles.prepare_output``). A run that recorded none is not checked; a city
    that is gone is left to ``run_map``'s own error."""
    recorded, path = config.get("city_sha256"), config.get("city_path")
    if not recorded or not path or not Path(path).exists():
        return None
    try:
        now = city_sha256(path)
    except OSError:
        return None  # unreadable: run_map says so
    if now == recorded:
        return None
    return (
        f"its city model {path} changed since the run (city_sha256 {str(recorded)[:12]}... in its "
        f"{RUN_FILE}, {now[:12]}... now): drawn on it, the map would be another city's"
    )


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
    keys = ("mode", "city_path", "city_sha256", "lod", "map_source", "crs", "frame", "ecef_origin_llh")
    key = json.dumps([run.config.get(k) for k in keys])
    if key not in cache:
        try:
            changed = city_changed(run.config)
            if changed is not None:
                cache[key] = None
                notes.append(f"{run.path}: {consequence}: {changed}")
                return None
            model = run_map(run.config)
            cache[key] = (model, Renderer(model, engine="numba"))
        except SemCityLocError as exc:
            cache[key] = None
            notes.append(f"{run.path}: {consequence}, its map cannot be loaded ({exc})")
        except KeyError as exc:  # a run.json written by hand or by other code: the key it lacks
            cache[key] = None
            notes.append(f"{run.path}: {consequence}, its run.json does not say where its map is (no {exc})")
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

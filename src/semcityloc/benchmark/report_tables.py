"""The report's tables as Markdown and CSV text: run summaries, comparisons, acceptance, misses.

Why its own module: a table is text made from runs (``report_runs.RunData``), with nothing drawn and no
file written here; ``benchmark.report`` writes the tables to ``tables/`` and into ``report.md``, and the
CLI prints ``summary_markdown`` after a run. One row per run: the factor compared first, then the
settings that differ between the table's runs (rows ordered by those, ``_order_value``), then the
metrics. Recall cells show both conventions, ``<=`` / ``<`` (see ``evaluation.metrics``).
"""

from __future__ import annotations

import csv
import io
import math
from typing import Any

import numpy as np

from semcityloc.benchmark.miss_kinds import MISS_KINDS, summarize_misses
from semcityloc.benchmark.report_runs import (
    RunData,
    acceptance_data,
    differing_keys,
    finite_max,
    has_truth,
    self_assessment,
    sweep_x,
)
from semcityloc.benchmark.results import SKIPPED
from semcityloc.evaluation.metrics import CAP_XYZ_M, THRESHOLDS, threshold_key
from semcityloc.localization.confidence import calibration_error
from semcityloc.localization.methods import ABLATIONS

SEG_ORDER = ("perfect", "trained", "medium", "zero-shot")
NO_TRUTH = "no truth"  # a truth-based cell of a run without ground truth (``report_runs.has_truth``)
# The metric columns readable without ground truth (``metric_headers``): counts and time.
UNTRUTHED_METRICS = ("queries", "localized", "not loc.", "skipped", "s/img")
ACCEPT_THRESHOLDS = (0.3, 0.5, 0.7, 0.9)
# The misses table's legend, written above the table in ``report.md``.
MISSES_NOTE = (
    "near: accepted within 5 m / 5° but beyond 2 m / 2°; refused-near: refused though the pose found "
    "was within 5 m / 5°; refused-wrong: refused, rightly; wrong: accepted beyond 5 m / 5°; "
    "unreadable-input: the query's mask or depth file could not be read, so nothing was searched or "
    "refused (a miss all the same, counted in the recall); skipped: a photo of the truth its run "
    "skipped (no usable prior or intrinsics, say), counted as a miss; failed: the query's worker died "
    "on every try (Ray). Map agreement: the query mask's building IoU against the map's labels at the "
    "true pose (simulated runs): low where the map differs from the world in view (`python "
    "benchmarks/miss_causes.py RUN` lists every miss). Outdated-map warning: results that said the "
    "image and the map disagree about buildings at the pose found (the evidence a run on real photos "
    "has)."
)


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


def _num(v: Any, digits: int = 1) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, float) and math.isinf(v):
        return "inf"
    return f"{v:.{digits}f}"


def markdown_table(headers: list[str], rows: list[list[str]]) -> str:
    """A Markdown table from headers and rows of cells (cells as given, turned into text)."""
    out = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(out) + "\n"


def metric_headers() -> list[str]:
    """The column headers of the metrics table (counts, recall at each threshold under both conventions,
    median errors, time), one list so that every table and its CSV name the columns alike.
    """
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


def metric_cells(s: dict, truth: bool = True) -> list[str]:
    """The ``metric_headers`` cells of a summary; those that need ground truth say ``no truth`` when the
    run has none (``truth`` False), not "-" (which would read as nothing found)."""
    cells = _metric_cells(s)
    if truth:
        return cells
    return [c if h in UNTRUTHED_METRICS else NO_TRUTH for h, c in zip(metric_headers(), cells, strict=True)]


def _metric_cells(s: dict) -> list[str]:
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
    md_headers = [*metric_headers(), "query mIoU % (vs reality)", "mIoU % vs map: pooled / per image"]
    md_rows, csv_rows = [], []
    for r in ordered:
        keys = [str(r.settings.get(k)) for k in headers]
        if not r.complete:
            keys[0] += f" (incomplete {len(r.rows)}/{r.config['queries']})"
        truth = has_truth(r)
        miou = f"{_num(r.summary.get('map_miou_pooled'))} / {_num(r.summary.get('map_miou_per_image'))}"
        miou_cells = [f"{_num(r.summary.get('mean_query_miou'))}", miou] if truth else [NO_TRUTH, NO_TRUTH]
        md_rows.append([*keys, *metric_cells(r.summary, truth), *miou_cells])
        csv_rows.append([*keys, *_csv_metrics(r.summary), str(r.path)])
    if not any(map(has_truth, runs)):  # no run has ground truth: only the columns that need none
        keep = [i for i, h in enumerate(md_headers) if h in UNTRUTHED_METRICS]
        md_headers = [md_headers[i] for i in keep]
        md_rows = [row[: len(headers)] + [row[len(headers) + i] for i in keep] for row in md_rows]
    md = markdown_table([*headers, *md_headers], md_rows)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow([*headers, *CSV_METRICS, "run_dir"])
    writer.writerows(csv_rows)
    return md, buf.getvalue()


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


# The self-assessment table's legend, written above it in ``report.md``.
SELF_NOTE = (
    "What a run without ground truth says of itself: the calibrated probability that the pose found is "
    "within 5 m / 5° (of the localized queries and of those refused), the 1-sigma each localized pose "
    "states (its covariance) and how far it moved from the prior (median, and the largest move). A large "
    "move with a small sigma is a correction of the prior; a move as large as the search volume is worth "
    "a look in the query browser of report.html."
)


SELF_HEADERS = (
    "run",
    "queries",
    "localized",
    "not localized: reasons",
    "skipped",
    "probability, median: localized / refused",
    "stated 1σ, median: xy m / z m / yaw °",
    "shift from the prior, median / max: xy m",
    "z m",
    "yaw °",
)
SELF_CSV = (
    "run",
    "queries",
    "localized",
    "not_localized",
    "reasons",
    "skipped",
    "probability_median_localized",
    "probability_median_refused",
    "sigma_xy_m_median",
    "sigma_z_m_median",
    "sigma_yaw_deg_median",
    *(f"shift_{k}_{stat}" for k in ("xy_m", "z_m", "yaw_deg") for stat in ("median", "max")),
    "run_dir",
)


def _median(values: np.ndarray) -> float:
    """The median of the finite ``values``; NaN when there are none."""
    finite = values[np.isfinite(values)]
    return float(np.median(finite)) if finite.size else float("nan")


def _reasons(summary: dict) -> str:
    """The reasons queries were not localized, counted, most frequent first (``reason n; ...``); a reason
    naming a file is counted by its kind (the text before the first ``: ``)."""
    counts: dict[str, int] = {}
    for reason, n in summary.get("not_localized_reasons", {}).items():
        kind = (reason or "no reason given").split(": ")[0]
        counts[kind] = counts.get(kind, 0) + n
    return "; ".join(f"{k} {n}" for k, n in sorted(counts.items(), key=lambda kv: -kv[1])) or "-"


def self_assessment_table(runs: list[RunData]) -> tuple[str, str]:
    """Per run without ground truth (``report_runs.self_assessment``): how many queries were localized
    and why the others were not, the calibrated probability (median of the localized, of the refused),
    the stated 1-sigma (median) and the shift from the prior (median / max)."""
    rows, csv_rows = [], [list(SELF_CSV)]
    for run in runs:
        s, a = run.summary, self_assessment(run)
        p, accepted = a["probability"], a["accepted"]
        probs = [_median(p[accepted]), _median(p[~accepted])]
        sigmas = [_median(a[k]) for k in ("sigma_xy_m", "sigma_z_m", "sigma_yaw_deg")]
        shifts = [(_median(a[k]), finite_max(a[k])) for k in ("shift_xy_m", "shift_z_m", "shift_yaw_deg")]
        missed = s.get("not_localized", 0)
        rows.append(
            [
                run.label,
                str(s.get("queries", 0)),
                str(s.get("localized", 0)),
                f"{missed}: {_reasons(s)}" if missed else "0",
                str(s.get("skipped", 0)),
                " / ".join(_num(v, 2) for v in probs),
                " / ".join(_num(v, 2) for v in sigmas),
                *(f"{_num(med)} / {_num(top)}" for med, top in shifts),
            ]
        )
        counts = [s.get("queries", 0), s.get("localized", 0), missed, _reasons(s), s.get("skipped", 0)]
        csv_rows.append(
            [run.label, *counts, *probs, *sigmas, *(v for pair in shifts for v in pair), run.path]
        )
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(csv_rows)
    return markdown_table(list(SELF_HEADERS), rows), buf.getvalue()

"""What kind of miss each query of a run is, and how far the map agreed with the world where it looked.

Why: a recall figure says how many queries were missed, not why. A miss at 2 m / 2 deg is one of

- ``near``: accepted within 5 m / 5 deg but beyond the threshold (nadir views: the tilt-versus-shift ridge);
- ``refused-near``: refused, though the pose found was within 5 m / 5 deg (the evidence judged too weak);
- ``refused-wrong``: refused, and rightly (the pose found was farther);
- ``wrong``: accepted and more than 5 m / 5 deg off (a confident wrong pose);
- ``unreadable-input``: the query's own input (a data set's mask or depth file) could not be read, so
  nothing was searched and nothing refused (``results.unreadable_result``); a miss all the same, in the
  recall's denominator, but the data's, not the localizer's, and kept apart from ``refused-wrong``;
- ``skipped``: a photo of a run against ground truth that the run skipped before anything ran (no usable
  prior or intrinsics, a prior off the map: ``results.skipped_miss_result``); a miss in the recall since
  stop 53, nothing searched either;
- ``failed``: the query's worker process died on every try (Ray, ``results.failed_row``): nothing was
  searched either; a miss where the query has a true pose.

The simulated scenarios record the query mask's confusion against the MAP's own labels at the true pose
(``meta["map_confusion"]``). Its building-vs-rest IoU (``map_building_iou``) holds the segmentation's errors
and the map's differences from the world; with a fair mask mIoU against the world (``query_miou``), a low
value says the map is wrong where the camera looked: buildings missing, new, re-roofed or heightened since
it was made. Misses gathered there are the map's, not the localizer's (``docs/benchmark.md``). Runs on
real photos have no such record; there the results' outdated-map warnings (``localization.agreement``,
the ``warnings`` column) are the evidence, counted for the hits and the misses alike.
Used by ``semcityloc report`` (the misses table) and ``benchmarks/miss_causes.py`` (one line per miss).
"""

from __future__ import annotations

import json
import math

import numpy as np

from semcityloc.benchmark.results import FAILED, cell_float, skipped_miss_row, unreadable_row
from semcityloc.classes import BUILDING_CLASSES, NUM_CLASSES
from semcityloc.evaluation.metrics import is_right
from semcityloc.localization.agreement import UNMAPPED_WARNING, UNSEEN_WARNING
from semcityloc.localization.result import LOCALIZED

UNREADABLE_KIND = "unreadable-input"
SKIPPED_KIND = "skipped"
MISS_KINDS = ("near", "refused-near", "refused-wrong", "wrong", UNREADABLE_KIND, SKIPPED_KIND, FAILED)
# Bins of the map's building IoU at the truth for the hits-per-bin figure; from MAP_AGREES up the map
# agrees with the world in view.
MAP_AGREES = 0.6
MAP_AGREEMENT_BINS = ((0.0, MAP_AGREES), (MAP_AGREES, 0.8), (0.8, 1.01))


def map_building_iou(meta: dict) -> float:
    """Building-vs-rest IoU of the query mask against the map's labels at the true pose (NaN without
    ``map_confusion``). Symmetric, so the confusion's axis order does not matter."""
    counts = meta.get("map_confusion")
    if counts is None:
        return math.nan
    c = np.asarray(counts, dtype=np.int64).reshape(NUM_CLASSES, NUM_CLASSES)
    b = list(BUILDING_CLASSES)
    inter = c[np.ix_(b, b)].sum()
    union = c[b, :].sum() + c[:, b].sum() - inter
    return float(inter / union) if union else math.nan


def row_agreement(row: dict[str, str]) -> float:
    """``map_building_iou`` of a ``results.csv`` row (NaN when its meta has no confusion)."""
    return map_building_iou(json.loads(row.get("meta_json") or "{}"))


def map_warnings(row: dict[str, str]) -> list[str]:
    """The outdated-map warnings a ``results.csv`` row carried, short: "map lacks" (buildings the image
    shows), "image lacks" (buildings the map has); empty when none."""
    text = row.get("warnings") or ""
    return [
        name for name, w in (("map lacks", UNMAPPED_WARNING), ("image lacks", UNSEEN_WARNING)) if w in text
    ]


def kind_of(row: dict[str, str], max_m: float = 2.0, max_deg: float = 2.0) -> str | None:
    """A ``results.csv`` row's kind of miss at ``max_m`` / ``max_deg`` (module docstring); None: a hit."""
    if unreadable_row(row):
        return UNREADABLE_KIND
    if skipped_miss_row(row):
        return SKIPPED_KIND
    if row["status"] == FAILED:
        return FAILED
    localized = row["status"] == LOCALIZED
    if localized and cell_float(row["err_xyz_m"]) <= max_m and cell_float(row["err_rot_deg"]) <= max_deg:
        return None
    found_m, found_deg = cell_float(row.get("found_err_xyz_m")), cell_float(row.get("found_err_rot_deg"))
    if localized and math.isnan(found_m):  # a results file without the found-pose columns
        found_m, found_deg = cell_float(row["err_xyz_m"]), cell_float(row["err_rot_deg"])
    near = is_right(found_m, found_deg)  # "near": the calibrated probability's own event
    if not localized:
        return "refused-near" if near else "refused-wrong"
    return "near" if near else "wrong"


def summarize_misses(rows: list[dict[str, str]], max_m: float = 2.0, max_deg: float = 2.0) -> dict:
    """Over the rows with a true pose: the count of hits and of each kind of miss, the median map
    agreement at the truth of the hits, of each kind and of all misses (None where no row has it),
    [hits, queries] per bin of that agreement (``MAP_AGREEMENT_BINS``) and where it is at least
    ``MAP_AGREES`` (empty / None when no row has it), and the hits and misses that carried an
    outdated-map warning (``map_warnings``)."""
    rows = [r for r in rows if r.get("err_xyz_m", "") != ""]
    kinds = [kind_of(r, max_m, max_deg) or "hit" for r in rows]
    agree = np.array([row_agreement(r) for r in rows], dtype=np.float64)
    count, median = {}, {}
    for k in ("hit", *MISS_KINDS):
        sel = np.array([x == k for x in kinds], dtype=bool)
        count[k] = int(sel.sum())
        known = agree[sel][np.isfinite(agree[sel])]
        median[k] = float(np.median(known)) if known.size else None
    hit = np.array([k == "hit" for k in kinds], dtype=bool)
    missed = agree[~hit][np.isfinite(agree[~hit])]
    median["misses"] = float(np.median(missed)) if missed.size else None
    bins = {}
    for lo, hi in MAP_AGREEMENT_BINS:
        sel = (agree >= lo) & (agree < hi)
        bins[f"{lo:g}-{hi:g}"] = [int(hit[sel].sum()), int(sel.sum())]
    agrees = agree >= MAP_AGREES
    warned = np.array([bool(map_warnings(r)) for r in rows], dtype=bool)
    known_any = bool(np.isfinite(agree).any())
    return {
        "queries": len(rows),
        "threshold": [max_m, max_deg],
        "count": count,
        "median_map_building_iou": median,
        "hits_by_map_building_iou": bins if known_any else {},
        "hits_where_map_agrees": [int(hit[agrees].sum()), int(agrees.sum())] if known_any else None,
        "map_warned": [int((warned & hit).sum()), int((warned & ~hit).sum())],
    }

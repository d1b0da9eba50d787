"""Why a benchmark run missed what it missed, read from its ``results.csv`` alone (nothing is localized).

Every query missed at ``--m`` metres / ``--deg`` degrees falls in one kind:

- ``refused-near``: refused, though the pose it found was within 5 m / 5 deg (the acceptance judged the
  evidence too weak);
- ``refused-wrong``: refused, and rightly (the pose found was farther);
- ``near``: accepted within 5 m / 5 deg but beyond the threshold (nadir views: the tilt-versus-shift ridge);
- ``wrong``: accepted and more than 5 m / 5 deg off (a confident wrong pose).

The evidence printed with each miss: the view, the query mask's mIoU against the simulated world
(``query_miou``: the segmentation's errors), the mask's **building IoU against the map at the true pose**
(from ``meta.map_confusion``, written by the simulated scenarios: it holds the segmentation's errors AND
the map's differences from the world, so a low value with a fair ``query_miou`` says the map is wrong
there: buildings missing, new, re-roofed or heightened since it was made), the prior's roll and pitch
errors, and the acceptance's probability. The same building IoU over the hits is printed for scale.

    python benchmarks/miss_causes.py RUN_DIR [--m 2 --deg 2]

Prints a markdown table of the misses, then one JSON line: counts per kind and the median map building
IoU at the truth of the hits and of each kind, and the hits per bin of it (``hits_by_map_building_iou``).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path

import numpy as np

from semcityloc.classes import BUILDING_CLASSES, NUM_CLASSES

NEAR_M, NEAR_DEG = 5.0, 5.0
MAP_AGREEMENT_BINS = ((0.0, 0.6), (0.6, 0.8), (0.8, 1.01))


def _num(text: str | None) -> float:
    return float(text) if text not in (None, "") else math.nan


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


def kind_of(row: dict[str, str], max_m: float, max_deg: float) -> str | None:
    """The row's kind of miss (module docstring), None for a hit."""
    localized = row["status"] == "localized"
    if localized and _num(row["err_xyz_m"]) <= max_m and _num(row["err_rot_deg"]) <= max_deg:
        return None
    found_m, found_deg = _num(row["found_err_xyz_m"]), _num(row["found_err_rot_deg"])
    near = found_m <= NEAR_M and found_deg <= NEAR_DEG
    if not localized:
        return "refused-near" if near else "refused-wrong"
    return "near" if near else "wrong"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", type=Path, help="a benchmark output folder (holds results.csv)")
    ap.add_argument("--m", type=float, default=2.0)
    ap.add_argument("--deg", type=float, default=2.0)
    args = ap.parse_args()
    path = args.run / "results.csv"
    if not path.is_file():
        print(f"{path}: no results.csv (pass a folder written by 'semcityloc benchmark')", file=sys.stderr)
        return 2
    with path.open(newline="", encoding="utf-8") as fh:
        rows = [r for r in csv.DictReader(fh) if r["status"] != "skipped" and r["err_xyz_m"] != ""]
    by_kind: dict[str, list[float]] = {"hit": []}
    print(
        "| query | view | kind | found error | query mIoU | map building IoU at truth "
        "| prior roll / pitch error | p |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        meta = json.loads(r["meta_json"] or "{}")
        agree = map_building_iou(meta)
        kind = kind_of(r, args.m, args.deg)
        by_kind.setdefault(kind or "hit", []).append(agree)
        if kind is None:
            continue
        rp = (abs(meta.get("prior_roll_err_deg", math.nan)), abs(meta.get("prior_pitch_err_deg", math.nan)))
        print(
            f"| {r['query_id']} | {r['view']} | {kind} | {_num(r['found_err_xyz_m']):.2f} m / "
            f"{_num(r['found_err_rot_deg']):.2f}° | {_num(r['query_miou']):.0f} | {agree:.2f} | "
            f"{rp[0]:.1f}° / {rp[1]:.1f}° | {_num(r['probability']):.2f} |"
        )
    summary = {
        "run": str(args.run),
        "queries": len(rows),
        "threshold": [args.m, args.deg],
        "count": {k: len(v) for k, v in by_kind.items()},
        "median_map_building_iou": {
            k: float(np.nanmedian(v)) if np.isfinite(v).any() else None for k, v in by_kind.items()
        },
    }
    agree = np.array([map_building_iou(json.loads(r["meta_json"] or "{}")) for r in rows])
    hit = np.array([kind_of(r, args.m, args.deg) is None for r in rows])
    summary["hits_by_map_building_iou"] = {
        f"{lo:g}-{hi:g}": f"{int(hit[sel].sum())}/{int(sel.sum())}"
        for lo, hi in MAP_AGREEMENT_BINS
        for sel in [(agree >= lo) & (agree < hi)]
    }
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())

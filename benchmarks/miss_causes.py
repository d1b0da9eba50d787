"""Why a benchmark run missed what it missed, read from its ``results.csv`` alone (nothing is localized).

Every query missed at ``--m`` metres / ``--deg`` degrees is one kind (``benchmark.miss_kinds``: near,
refused-near, refused-wrong, wrong, unreadable-input, failed). Printed with each miss: the view, the query
mask's mIoU against the simulated world (``query_miou``: the segmentation's errors), the mask's **building IoU
against the map at the true pose** (``miss_kinds.map_building_iou``: low with a fair ``query_miou`` = the
map is wrong where the camera looked), the prior's roll and pitch errors, the acceptance's probability,
how far apart the class boundaries of the mask and of the map lie at the found pose
(``boundary_distance_px``, in the refinement's pixels: under 1 at a right pose on a map that agrees; "-"
in runs before stop 42), and the outdated-map warnings the result carried (``miss_kinds.map_warnings``:
"map lacks" buildings the image shows, "image lacks" buildings the map has; what a run on real photos has
instead of the map's agreement).

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

from semcityloc.benchmark.miss_kinds import kind_of, map_building_iou, map_warnings, summarize_misses
from semcityloc.benchmark.results import cell_float


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
    print(
        "| query | view | kind | found error | query mIoU | map building IoU at truth "
        "| prior roll / pitch error | p | boundaries px | map warning |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        kind = kind_of(r, args.m, args.deg)
        if kind is None:
            continue
        meta = json.loads(r["meta_json"] or "{}")
        rp = (abs(meta.get("prior_roll_err_deg", math.nan)), abs(meta.get("prior_pitch_err_deg", math.nan)))
        warned = ", ".join(map_warnings(r)) or "-"
        apart = r.get("boundary_distance_px") or ""
        boundaries = f"{cell_float(apart):.1f}" if apart else "-"
        print(
            f"| {r['query_id']} | {r['view']} | {kind} | {cell_float(r['found_err_xyz_m']):.2f} m / "
            f"{cell_float(r['found_err_rot_deg']):.2f}° | {cell_float(r['query_miou']):.0f} | "
            f"{map_building_iou(meta):.2f} | "
            f"{rp[0]:.1f}° / {rp[1]:.1f}° | {cell_float(r['probability']):.2f} | {boundaries} | {warned} |"
        )
    print(json.dumps({"run": str(args.run), **summarize_misses(rows, args.m, args.deg)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())

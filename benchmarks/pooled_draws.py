"""Several benchmark draws read as one: per-draw recall of each method, the pooled figures, and the queries
one method gets right that another misses (paired, the same queries).

Why: one seed's reality decides a lot (Berlin seed 0 draws nine views where the map lost or changed a
building in sight, seed 1 one), so a difference of a few points between two methods on one draw is
within what the draw itself moves. Pooling draws that nothing was tuned on says which differences hold.

    python benchmarks/pooled_draws.py RUN_DIR... [--against semcityloc] [--m 2 --deg 2]

Each RUN_DIR is a ``semcityloc benchmark`` output folder (``results.csv`` + ``summary.json``); a draw is
the (city, seed) of its config, a method its config's ``method``. Prints a markdown table (one row per
draw: recall at 2 m / 3 m / 5 m, localized, accepted within 5 m / 5 deg) and, per method, the pooled
summary over every draw it ran (``benchmark.results.summarize_rows``) and the queries it has right at
``--m`` / ``--deg`` that ``--against`` misses and the other way round. Nothing is localized.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from semcityloc.benchmark.results import cell_float, parse_results, summarize_rows
from semcityloc.evaluation.metrics import RIGHT_DEG, RIGHT_M

THRESHOLDS = ((2.0, 2.0), (3.0, 3.0), (5.0, 5.0))


def load_run(folder: Path) -> tuple[tuple[str, int], str, list[dict[str, str]]]:
    """((city name, seed), method, rows with a true pose) of one benchmark output folder."""
    summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    config = summary["config"]
    path = folder / "results.csv"
    # Read-only: an analysis never repairs or rewrites a run's file; an earlier layout is read by its header.
    rows = [r for r in parse_results(path.read_bytes(), path, strict=False) if r["status"] != "skipped"]
    rows = [r for r in rows if r["err_xyz_m"]]  # a true pose is needed (a user's photos have none)
    return (Path(config["city"]).stem, int(config["seed"])), config["method"], rows


def right(row: dict[str, str], max_m: float, max_deg: float) -> bool:
    """The row's pose was accepted and lies within ``max_m`` and ``max_deg`` of the truth (``<=``)."""
    return (
        row["status"] == "localized"
        and cell_float(row["err_xyz_m"]) <= max_m
        and cell_float(row["err_rot_deg"]) <= max_deg
    )


def draw_cell(rows: list[dict[str, str]]) -> str:
    """``R@2 / R@3 / R@5 (localized, accepted right %)`` of one run."""
    n = len(rows)
    hits = [100.0 * sum(right(r, m, d) for r in rows) / n for m, d in THRESHOLDS]
    accepted = [r for r in rows if r["status"] == "localized"]
    precision = 100.0 * sum(right(r, RIGHT_M, RIGHT_DEG) for r in accepted) / max(len(accepted), 1)
    return f"{hits[0]:.0f} / {hits[1]:.0f} / {hits[2]:.0f} ({len(accepted)}, {precision:.1f} %)"


def paired(a: list[dict[str, str]], b: list[dict[str, str]], max_m: float, max_deg: float) -> tuple[int, int]:
    """(right in ``a`` only, right in ``b`` only) over the queries both runs hold."""
    by_id = {r["query_id"]: r for r in b}
    only_a = only_b = 0
    for r in a:
        other = by_id.get(r["query_id"])
        if other is None:
            continue
        ra, rb = right(r, max_m, max_deg), right(other, max_m, max_deg)
        only_a += ra and not rb
        only_b += rb and not ra
    return only_a, only_b


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", type=Path, nargs="+", help="benchmark output folders")
    ap.add_argument("--against", default="semcityloc", help="the method the others are paired with")
    ap.add_argument("--m", type=float, default=2.0)
    ap.add_argument("--deg", type=float, default=2.0)
    args = ap.parse_args()
    runs: dict[tuple[str, int], dict[str, list[dict[str, str]]]] = {}
    for folder in args.runs:
        if not (folder / "summary.json").is_file():
            print(f"{folder}: not a finished benchmark run (no summary.json)", file=sys.stderr)
            return 2
        draw, method, rows = load_run(folder)
        if method in runs.setdefault(draw, {}):
            print(f"{folder}: a second {method} run of {draw[0]} seed {draw[1]}", file=sys.stderr)
            return 2
        runs[draw][method] = rows
    methods = sorted({m for by in runs.values() for m in by}, key=lambda m: (m != args.against, m))
    print("| draw | queries | " + " | ".join(methods) + " |")
    print("|---|---|" + "---|" * len(methods))
    for (city, seed), by in sorted(runs.items()):
        n = len(next(iter(by.values())))
        cells = [draw_cell(by[m]) if m in by else "-" for m in methods]
        print(f"| {city} seed {seed} | {n} | " + " | ".join(cells) + " |")
    print("\ncells: R@2m,2° / 3m,3° / 5m,5° % of all queries (localized, accepted within 5 m / 5°)\n")
    for m in methods:
        pooled: list[dict[str, str]] = []
        gained = lost = 0
        for (city, seed), by in sorted(runs.items()):
            if m not in by:
                continue
            # Query ids repeat from draw to draw: the pooled rows are told apart by their draw.
            pooled += [
                {**r, "query_id": f"{city}-{seed}-{r['query_id']}", "index": str(len(pooled) + i)}
                for i, r in enumerate(by[m])
            ]
            if m != args.against and args.against in by:
                g, l_ = paired(by[m], by[args.against], args.m, args.deg)
                gained, lost = gained + g, lost + l_
        s = summarize_rows(pooled, {"method": m})
        line = {
            "method": m,
            "queries": s["with_ground_truth"],
            "draws": sum(m in by for by in runs.values()),
            **{k: round(s[k], 1) for k in ("recall_2m2deg", "recall_3m3deg", "recall_5m5deg")},
            "localized": s["localized"],
            "acceptance_precision": round(s["acceptance_precision"], 1),
            "mean_xyz_m": round(s["mean_xyz_m"], 2),
        }
        if m != args.against:
            line[f"right_at_{args.m:g}m{args.deg:g}deg_only_here"] = gained
            line[f"right_at_{args.m:g}m{args.deg:g}deg_only_{args.against}"] = lost
        print(json.dumps(line))
    return 0


if __name__ == "__main__":
    sys.exit(main())

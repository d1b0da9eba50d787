"""The per-image focal-length check (``localization.focal_check``) measured on the benchmark's queries.

    python benchmarks/focal_check.py --city generated --seed 0 --focal-error 0.05 --queries 40 --out F.jsonl

The queries are rendered with the true camera and the localizer is told one whose focal length is
``1 + focal_error`` times it (the ``focal_error`` knob). One JSON line per query: status, errors, right
(5 m / 5 deg), oblique (the check's own test, on the pose found), the localize and check times, the
check's record (``result.search["focal_check"]``) and whether it warned; a last line sums up: the warned
share of the accepted poses, of the accepted wrong ones, and the precision with and without them.
Reporting cities are refused unless ``--check-only`` (docs/localization.md, "A focal length the image
contradicts").
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from semcityloc.benchmark.calibration import calibration_cities_or_exit
from semcityloc.benchmark.scenario import query_config
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.evaluation.metrics import is_right, pose_errors
from semcityloc.localization.focal_check import FOCAL_WARNING, is_oblique
from semcityloc.localization.localize import Localizer
from semcityloc.localization.result import LOCALIZED

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--city", default="generated")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--queries", type=int, default=40)
    ap.add_argument("--focal-error", type=float, default=0.0)
    ap.add_argument("--out", required=True, help="the JSON lines file to write")
    ap.add_argument("--check-only", action="store_true", help="allow a reporting city: a check only")
    args = ap.parse_args(argv)
    if not args.check_only:
        calibration_cities_or_exit([args.city], SHARED, "measure the focal-length check")
    cfg = query_config("realistic", {"focal_error": args.focal_error}, queries=args.queries, seed=args.seed)
    spec = BenchmarkSpec(city=args.city, query=cfg)
    source = spec.open_source(spec.run_config())
    localizer = Localizer(source.map_model)
    rows = []
    with open(args.out, "w", encoding="utf-8") as fh:
        for i in range(args.queries):
            q = source.query(i)
            if not q.meta.get("accepted", True):
                continue
            r = localizer.localize(q.camera, q.prior_pose_local, q.labels, q.depth)
            localized = r.status == LOCALIZED
            m, d, _ = pose_errors(r.pose_local if localized else None, q.true_pose_local)
            row = {
                "i": i,
                "status": r.status,
                "err_m": m,
                "err_deg": d,
                "right": bool(is_right(m, d)),
                "oblique": bool(localized and is_oblique(r.pose_local)),
                "localize_s": r.timings.get("total_s"),
                "check_s": r.timings.get("focal_check_s", 0.0),
                "focal_check": r.search.get("focal_check"),
                "warned": any(w.startswith(FOCAL_WARNING) for w in r.warnings),
            }
            rows.append(row)
            fh.write(json.dumps(row) + "\n")
        fh.write(json.dumps(summary(rows, args)) + "\n")
    print(json.dumps(summary(rows, args)))
    return 0


def summary(rows: list[dict], args) -> dict:
    """The run's figures: accepted, wrong among them, warned, and precision with and without the warned."""
    accepted = [r for r in rows if r["status"] == LOCALIZED]
    wrong = [r for r in accepted if not r["right"]]
    kept = [r for r in accepted if not r["warned"]]
    total = sum(r["localize_s"] or 0.0 for r in rows)
    return {
        "city": Path(args.city).stem,
        "seed": args.seed,
        "focal_error": args.focal_error,
        "queries": len(rows),
        "accepted": len(accepted),
        "wrong": len(wrong),
        "warned": sum(r["warned"] for r in accepted),
        "wrong_warned": sum(r["warned"] for r in wrong),
        "precision_pct": round(100.0 * (len(accepted) - len(wrong)) / max(len(accepted), 1), 1),
        "precision_unwarned_pct": round(100.0 * sum(r["right"] for r in kept) / max(len(kept), 1), 1),
        "check_time_share_pct": round(100.0 * sum(r["check_s"] for r in rows) / max(total, 1e-9), 1),
    }


if __name__ == "__main__":
    sys.exit(main())

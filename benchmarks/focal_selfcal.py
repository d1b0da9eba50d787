"""A flight's focal length estimated from its own oblique images (``localization.focal``), measured.

The benchmark's realistic queries of one city and seed play the flight: every query is rendered with the
true camera and the localizer is told one whose focal length is ``1 + focal_error`` times it (the
``focal_error`` knob). The focal scale is estimated from the flight's oblique queries, then every query is
localized with the stated camera and with the corrected one. Prints one JSON line: the estimate, the scale
that is right (``1 / (1 + focal_error)``), and recall at 2 m / 2 deg, 3 m / 3 deg, 5 m / 5 deg of the
accepted poses, stated and corrected, with the share of accepted poses within 5 m / 5 deg.

    python benchmarks/focal_selfcal.py --city generated --focal-error -0.024 [--seed 0] [--queries 100]

``--views nadir`` estimates from the flight's nadir queries alone (every view counted): tried for
nadir-only mapping flights and not shipped, the summed scores prefer a longer focal length there
(``docs/benchmark.md``, "Other cameras and cities").

Reporting cities (Berlin, Den Haag) are refused unless ``--check-only``: nothing of the estimator is
chosen on them.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from semcityloc.benchmark.calibration import calibration_cities_or_exit
from semcityloc.benchmark.results import recall_summary
from semcityloc.benchmark.scenario import query_config
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.localization.focal import FocalView, estimate_focal_scale
from semcityloc.localization.focal_check import is_oblique, with_focal_scale
from semcityloc.localization.localize import Localizer

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--city", default="generated")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--queries", type=int, default=100)
    ap.add_argument("--focal-error", type=float, default=-0.024)
    ap.add_argument(
        "--views",
        choices=("oblique", "nadir"),
        default="oblique",
        help="estimate from the oblique views (the shipped estimator) or from the nadir ones only",
    )
    ap.add_argument("--check-only", action="store_true", help="allow a reporting city: a check only")
    args = ap.parse_args(argv)
    if not args.check_only:
        calibration_cities_or_exit([args.city], SHARED, "measure the focal estimator")
    cfg = query_config("realistic", {"focal_error": args.focal_error}, queries=args.queries, seed=args.seed)
    spec = BenchmarkSpec(city=args.city, query=cfg)
    source = spec.open_source(spec.run_config())
    queries = [q for q in (source.query(i) for i in range(args.queries)) if q.meta.get("accepted", True)]
    localizer = Localizer(source.map_model)
    t0 = time.perf_counter()
    views = [FocalView(q.camera, q.prior_pose_local, q.labels, q.depth) for q in queries]
    if args.views == "nadir":
        views = [v for v in views if not is_oblique(v.prior_local)]
        estimate = estimate_focal_scale(localizer, views, min_oblique_deg=0.0)
    else:
        estimate = estimate_focal_scale(localizer, views)
    seconds = time.perf_counter() - t0
    stated = [localizer.localize(q.camera, q.prior_pose_local, q.labels, q.depth) for q in queries]
    out = {
        "city": Path(args.city).stem,
        "seed": args.seed,
        "queries": len(queries),
        "focal_error": args.focal_error,
        "views": args.views,
        "right_scale": round(1.0 / (1.0 + args.focal_error), 4),
        "estimate": estimate.as_dict(),
        "estimate_s": round(seconds, 1),
        "stated": recall_summary(stated, queries),
    }
    if estimate.scale is not None:
        corrected = [
            localizer.localize(
                with_focal_scale(q.camera, estimate.scale), q.prior_pose_local, q.labels, q.depth
            )
            for q in queries
        ]
        out["corrected"] = recall_summary(corrected, queries)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())

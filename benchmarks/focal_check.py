"""The per-image focal-length check (``localization.focal_check``) measured on the benchmark's queries.

    python benchmarks/focal_check.py --city generated --seed 0 --focal-error 0.05 --queries 40 --out F.jsonl

The queries are rendered with the true camera and the localizer is told one whose focal length is
``1 + focal_error`` times it (the ``focal_error`` knob). One JSON line per query: status, errors, right
(5 m / 5 deg), oblique (the check's own test, on the pose found), the localize and check times, the
check's record (``result.search["focal_check"]``) and whether it warned; a last line sums up: the warned
share of the accepted poses, of the accepted wrong ones, and the precision with and without them.

The correction (``FocalCheckConfig.correct``, stop 54): each row also has the error of the pose found at the
stated focal length (``first``: what the localizer returned before the correction) and of the one returned
(``err_m``); with ``--stretches 1,2`` the queries it ran on are localized again with each further stretch
(``err_by_stretch``). The last line sums up R@2/3/5 m and precision before and after, per stretch.
Reporting cities are refused unless ``--check-only`` (docs/localization.md, "A focal length the image
contradicts").
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from semcityloc.benchmark.calibration import calibration_cities_or_exit
from semcityloc.benchmark.scenario import query_config
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.evaluation.metrics import is_right, pose_errors
from semcityloc.geometry.pose import Pose
from semcityloc.localization.config import LocalizerConfig
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
    ap.add_argument("--stretches", default="1", help="FocalCheckConfig.stretch values, the first for all")
    ap.add_argument("--no-correct", action="store_true", help="FocalCheckConfig.correct=False")
    args = ap.parse_args(argv)
    if not args.check_only:
        calibration_cities_or_exit([args.city], SHARED, "measure the focal-length check")
    cfg = query_config("realistic", {"focal_error": args.focal_error}, queries=args.queries, seed=args.seed)
    spec = BenchmarkSpec(city=args.city, query=cfg)
    source = spec.open_source(spec.run_config())
    stretches = [float(x) for x in args.stretches.split(",")]
    base = LocalizerConfig()
    configs = [
        replace(base, focal_check=replace(base.focal_check, stretch=k, correct=not args.no_correct))
        for k in stretches
    ]
    localizer = Localizer(source.map_model, configs[0])
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
            corr = (r.search.get("focal_check") or {}).get("correction")
            row["first_err"] = [m, d]
            if corr is not None:
                row["first_err"] = list(
                    pose_errors(Pose.from_state(np.array(corr["first_state"])), q.true_pose_local)[:2]
                )
                row["err_by_stretch"] = {args.stretches.split(",")[0]: [m, d, corr["taken"], corr["scale"]]}
                for name, cfg_k in zip(args.stretches.split(",")[1:], configs[1:], strict=True):
                    rk = localizer.localize(q.camera, q.prior_pose_local, q.labels, q.depth, config=cfg_k)
                    ck = rk.search["focal_check"]["correction"]
                    mk, dk, _ = pose_errors(
                        rk.pose_local if rk.status == LOCALIZED else None, q.true_pose_local
                    )
                    row["err_by_stretch"][name] = [mk, dk, ck["taken"], ck["scale"]]
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
        "corrections_run": sum("err_by_stretch" in r for r in rows),
        "before": recall_figures([r["first_err"] for r in accepted], len(rows)),
        "after": {
            k: recall_figures([by_stretch(r, k) for r in accepted], len(rows))
            for k in args.stretches.split(",")
        },
        "taken": {
            k: sum(r.get("err_by_stretch", {}).get(k, [0, 0, False])[2] for r in rows)
            for k in args.stretches.split(",")
        },
        "right_made_wrong": {
            k: sum(is_right(*r["first_err"]) and not is_right(*by_stretch(r, k)) for r in accepted)
            for k in args.stretches.split(",")
        },
        "wrong_made_right": {
            k: sum(not is_right(*r["first_err"]) and is_right(*by_stretch(r, k)) for r in accepted)
            for k in args.stretches.split(",")
        },
    }


def by_stretch(row: dict, k: str) -> list[float]:
    """The (m, deg) errors of ``row``'s returned pose with stretch ``k`` (the first pose's where no correction
    ran)."""
    return row["err_by_stretch"][k][:2] if "err_by_stretch" in row else row["first_err"]


def recall_figures(errs: list, queries: int) -> dict:
    """R@2/3/5 (m and deg, per query) and the precision (within 5 m / 5 deg) of the accepted ``errs``."""
    out = {
        f"R@{t}": round(100.0 * sum(m <= t and d <= t for m, d in errs) / max(queries, 1), 1)
        for t in (2, 3, 5)
    }
    out["precision"] = round(100.0 * sum(bool(is_right(m, d)) for m, d in errs) / max(len(errs), 1), 1)
    return out


if __name__ == "__main__":
    sys.exit(main())

"""A flight's shared prior offset, estimated from its own photos and removed: measured, not shipped.

Why: GNSS heights without RTK are off by a height reference (geoid, take-off altitude) that a whole
flight shares. This script asks whether removing that offset, and shrinking the stated uncertainty to the
photos' scatter about it, makes the poses better. The benchmark's realistic queries of one city and seed
play the flight, with new priors: truth + one shared offset (x, y ~ N(0, 3 m), height uniform +-30 m, yaw
uniform +-6 deg; ``--flight-seed``) + each photo's own scatter (``--jitter-xy``, ``--jitter-z``, yaw 1 deg),
roll and pitch as the benchmark draws them. Every query is localized from its prior with the default
uncertainty; then ``--subset`` of them (evenly spread) estimate the offset (median of the accepted poses'
moves) and the scatter (1.4826 x MAD, times 1.5, floored at 1.5 m / 1.5 m / 1 deg), and every query is
localized again from its corrected prior with that uncertainty. Prints one JSON line: the offset and its
estimate, and recall at 2 m / 2 deg, 3 m / 3 deg, 5 m / 5 deg with the share of accepted poses within
5 m / 5 deg, stated and corrected.

    python benchmarks/flight_prior.py --city generated [--seed 0] [--flight-seed 0] [--queries 100]

The result (``docs/your-data.md``, section 8): no better within the stated uncertainty, so a photo run
only says when its photos share an offset (``photo_exports.prior_offset_notes``). Reporting cities are
refused unless ``--check-only``.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from semcityloc.benchmark.calibration import calibration_cities_or_exit
from semcityloc.benchmark.results import recall_summary
from semcityloc.benchmark.scenario import query_config
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.geometry.conventions import state_difference
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.localization.localize import Localizer
from semcityloc.localization.result import LOCALIZED

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def flight_priors(queries, flight_seed: int, jitter_xy: float, jitter_z: float):
    """(priors, offset xyz, yaw offset): each query's truth moved by the flight's offset and its own
    scatter (module docstring)."""
    rng = np.random.default_rng([flight_seed, 99])
    offset = np.array([rng.normal(0, 3), rng.normal(0, 3), rng.uniform(-30, 30)])
    yaw_offset = float(rng.uniform(-6, 6))
    priors = []
    for q in queries:
        truth, prior = q.true_pose_local.to_xyz_rpy(), q.prior_pose_local.to_xyz_rpy()
        scatter = np.array([rng.normal(0, jitter_xy), rng.normal(0, jitter_xy), rng.normal(0, jitter_z)])
        yaw = truth[5] + yaw_offset + rng.normal(0, 1.0)
        priors.append(Pose.from_xyz_rpy(truth[:3] + offset + scatter, prior[3], prior[4], yaw))
    return priors, offset, yaw_offset


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--city", default="generated")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--flight-seed", type=int, default=0)
    ap.add_argument("--queries", type=int, default=100)
    ap.add_argument("--jitter-xy", type=float, default=1.5)
    ap.add_argument("--jitter-z", type=float, default=1.0)
    ap.add_argument("--subset", type=int, default=20)
    ap.add_argument("--check-only", action="store_true", help="allow a reporting city: a check only")
    args = ap.parse_args(argv)
    if not args.check_only:
        calibration_cities_or_exit([args.city], SHARED, "measure the flight prior")
    cfg = query_config("realistic", {}, queries=args.queries, seed=args.seed)
    spec = BenchmarkSpec(city=args.city, query=cfg)
    source = spec.open_source(spec.run_config())
    queries = [q for q in (source.query(i) for i in range(args.queries)) if q.meta.get("accepted", True)]
    priors, offset, yaw_offset = flight_priors(queries, args.flight_seed, args.jitter_xy, args.jitter_z)
    localizer = Localizer(source.map_model)
    default = PriorUncertainty()

    def localize(i, prior, uncertainty):
        q = queries[i]
        return localizer.localize(q.camera, prior, q.labels, q.depth, prior_uncertainty=uncertainty)

    stated = [localize(i, p, default) for i, p in enumerate(priors)]
    subset = sorted(set(np.linspace(0, len(queries) - 1, args.subset).round().astype(int).tolist()))
    moves = []
    for i in subset:
        if stated[i].status == LOCALIZED:
            found, prior = stated[i].pose_local.to_xyz_rpy(), priors[i].to_xyz_rpy()
            moves.append(state_difference(found, prior)[[0, 1, 2, 5]].tolist())
    out = {
        "city": Path(args.city).stem,
        "seed": args.seed,
        "flight_seed": args.flight_seed,
        "queries": len(queries),
        "offset": [*offset.round(2).tolist(), round(yaw_offset, 2)],
        "subset_localized": len(moves),
        "stated": recall_summary(stated, queries),
    }
    if moves:
        moves = np.array(moves)
        median = np.median(moves, axis=0)
        scatter = 1.4826 * np.median(np.abs(moves - median), axis=0)
        unc = replace(
            default,
            xy_m=min(default.xy_m, max(1.5, 1.5 * max(scatter[0], scatter[1]))),
            z_m=min(default.z_m, max(1.5, 1.5 * scatter[2])),
            yaw_deg=min(default.yaw_deg, max(1.0, 1.5 * scatter[3])),
        )
        corrected = []
        for i, p in enumerate(priors):
            x = p.to_xyz_rpy()
            corrected.append(
                localize(i, Pose.from_xyz_rpy(x[:3] + median[:3], x[3], x[4], x[5] + median[3]), unc)
            )
        out["estimated_correction"] = median.round(2).tolist()
        out["corrected_uncertainty"] = [round(unc.xy_m, 2), round(unc.z_m, 2), round(unc.yaw_deg, 2)]
        out["corrected"] = recall_summary(corrected, queries)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())

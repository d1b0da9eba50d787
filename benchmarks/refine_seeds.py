"""How much of a real image's error is the refinement's random draw? One query, several refinement seeds.

Localizes one query of the real-data benchmark (``semcityloc benchmark --dataset``: LoD-Loc layout, the
GPS prior, default settings) with ``LocalizerConfig.seed`` = 0 .. N-1 and prints, per seed, the error
vector of the camera centre (estimate minus truth, local frame), its length, the rotation error, and the
refinement's own score (``Localizer.score_poses``) of the estimate and of the true pose. A spread of
errors across seeds is the draw's; a mean error vector far from zero is a bias; a truth scoring below the
estimates means the score, not the search, decides where the estimate lands.

    python benchmarks/refine_seeds.py [--dataset ../shared/data] [--perception oracle]
        [--label-seed 0] [--query 0] [--seeds 8]

A diagnosis, not a tuning tool: ``docs/benchmark.md`` ("the two real UAV images") has its figures.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from semcityloc.benchmark.dataset_source import DatasetSpec
from semcityloc.geometry.errors import rotation_error_deg
from semcityloc.localization.localize import Localizer

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", type=Path, default=SHARED)
    ap.add_argument("--perception", default="oracle", help="oracle or oracle-degraded")
    ap.add_argument("--label-seed", type=int, default=0, help="noise seed of the degraded labels")
    ap.add_argument("--query", type=int, default=0, help="query index (0: the thermal image)")
    ap.add_argument("--seeds", type=int, default=8, help="refinement seeds 0 .. N-1")
    args = ap.parse_args()
    if not args.dataset.is_dir():
        print(f"{args.dataset}: no such data set folder", file=sys.stderr)
        return 2

    spec = DatasetSpec(dataset=str(args.dataset), perception=args.perception, seed=args.label_seed)
    source = spec.open_source(spec.run_config())
    loc = Localizer(source.map_model)
    q = source.query(args.query)
    truth = q.true_pose_local
    vectors, errors = [], []
    for seed in range(args.seeds):
        cfg = replace(loc.config, seed=seed)
        r = loc.localize(q.camera, q.prior_pose_local, q.labels, q.depth, config=cfg)
        found = r.found_pose_local
        vectors.append(found.center - truth.center)
        errors.append(float(np.linalg.norm(vectors[-1])))
        s = loc.score_poses(
            q.camera, q.labels, q.depth, [found, truth], prior_local=q.prior_pose_local, config=cfg
        )
        row = {
            "seed": seed,
            "status": r.status,
            "error_vector_m": np.round(vectors[-1], 3).tolist(),
            "error_m": round(errors[-1], 3),
            "error_deg": round(float(rotation_error_deg(found, truth)), 3),
            "score_found": round(float(s["score"][0]), 4),
            "score_truth": round(float(s["score"][1]), 4),
        }
        print(json.dumps(row), flush=True)
    summary = {
        "query": q.query_id,
        "perception": args.perception,
        "seeds": args.seeds,
        "mean_error_m": round(float(np.mean(errors)), 3),
        "within_1m": int(sum(e <= 1.0 for e in errors)),
        "mean_error_vector_m": np.round(np.mean(vectors, axis=0), 3).tolist(),
    }
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())

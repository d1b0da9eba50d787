"""The pose covariance on the real UAV images: how far each found pose is from the truth in its own sigmas.

Usage::

    python benchmarks/covariance_real.py [--dataset ../shared/data] [--label-seeds 6]

Each image of the data set is localized with the default settings, once with the oracle labels and once
per degraded-label seed (``--perception oracle-degraded --seed S`` of the benchmark); printed per run:
the status, the 6D state error (x, y, z m; roll, pitch, yaw deg), the covariance's 1-sigma, and the
squared Mahalanobis distance ``d2`` of the error with its chi-square (6 dof) probability: below 0.95 the
truth is inside the 95 % ellipsoid (``docs/localization.md``, "Pose covariance").
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from semcityloc.benchmark.dataset_source import DatasetSpec
from semcityloc.localization.covariance import mahalanobis_sq, state_error
from semcityloc.localization.localize import Localizer

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def runs(label_seeds: int) -> list[tuple[str, int]]:
    return [("oracle", 0)] + [("oracle-degraded", s) for s in range(label_seeds)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", type=Path, default=SHARED)
    ap.add_argument("--label-seeds", type=int, default=6, help="degraded-label seeds 0 .. N-1")
    args = ap.parse_args(argv)
    if not args.dataset.is_dir():
        print(f"{args.dataset}: no such data set folder", file=sys.stderr)
        return 2
    for perception, seed in runs(args.label_seeds):
        spec = DatasetSpec(dataset=str(args.dataset), perception=perception, seed=seed)
        source = spec.open_source(spec.run_config())
        localizer = Localizer(source.map_model)
        for index in range(len(source)):
            q = source.query(index)
            r = localizer.localize(q.camera, q.prior_pose_local, q.labels, q.depth)
            found = r.found_pose_local
            label = f"{q.query_id} {perception} seed {seed}: {r.status}"
            if found is None or r.covariance is None:
                print(f"{label}, no pose or no covariance ({r.reason})")
                continue
            error = state_error(found, q.true_pose_local)
            d2 = mahalanobis_sq(error, r.covariance)
            sigma = np.sqrt(np.diag(r.covariance))
            print(
                f"{label}, error {np.round(error, 2).tolist()}, sigma {np.round(sigma, 2).tolist()}, "
                f"d2 {d2:.1f} (chi2 probability {chi2.cdf(d2, 6):.3f})"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""How right the localizer's outdated-map warnings are (``localization/agreement.py``), against what really
changed in view.

Usage::

    python benchmarks/map_change_warnings.py [--city C ...] [--seed 0] [--queries 60] [--workers 2]

For each city (default: the calibration cities, seed 0) the realistic scenario and the same with a fifth of
the map's buildings gone and as many new (``reality.missing_fraction`` = ``reality.new_fraction`` = 0.2).
Each query is localized with the default settings; at the poses found within 5 m / 5 deg (accepted or
not) the two warnings (buildings the map lacks; buildings the image does not show) are compared with the
truth: the same rule (``building_agreement``) applied to the simulated reality's clean labels in place of
the query's, at the true pose and the same resolution, a real change counted from ``REAL_SHARE`` of the
labelled pixels. Prints one markdown row per city and reality: warned / of them a real change / real
changes not warned, per warning, and how many wrong poses got the first warning.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from semcityloc.benchmark.calibration import calibration_cities
from semcityloc.benchmark.scenario import query_config
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.evaluation.metrics import is_right
from semcityloc.geometry.errors import center_error_m, rotation_error_deg
from semcityloc.localization.agreement import WARN_SHARE, building_agreement
from semcityloc.localization.localize import Localizer

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
REAL_SHARE = 0.01
CHANGED = {"reality.missing_fraction": 0.2, "reality.new_fraction": 0.2}
_WORKER: dict = {}


def _init(city: str, seed: int, queries: int, changed: bool) -> None:
    spec = BenchmarkSpec(
        city=city, query=query_config("realistic", CHANGED if changed else None, queries=queries, seed=seed)
    )
    source = spec.open_source(spec.run_config())
    _WORKER.update(source=source, localizer=Localizer(source.map_model))


def _one(index: int) -> dict | None:
    """The warnings at the found pose and the truth's shares at the true pose of one query."""
    source, loc = _WORKER["source"], _WORKER["localizer"]
    q = source.query(index)
    if not q.meta.get("accepted", True):
        return None
    result = loc.localize(q.camera, q.prior_pose_local, q.labels, q.depth)
    pose = result.found_pose_local
    if pose is None or "unmapped_building_share" not in result.confidence:
        return None
    fine = loc.fine_camera(q.camera)
    map_labels = loc.render_labels(fine, q.true_pose_local)
    reality = source.simulator.reality.renderer.render(fine, q.true_pose_local).labels[0]
    truth = building_agreement(reality, map_labels)
    return {
        "right": is_right(
            center_error_m(pose, q.true_pose_local), rotation_error_deg(pose, q.true_pose_local)
        ),
        "warned": [
            result.confidence["unmapped_building_share"] >= WARN_SHARE,
            result.confidence["unseen_building_share"] >= WARN_SHARE,
        ],
        "real": [truth.unmapped_share >= REAL_SHARE, truth.unseen_share >= REAL_SHARE],
    }


def row(label: str, rows: list[dict]) -> str:
    right = [r for r in rows if r["right"]]
    cells = []
    for k in (0, 1):
        warned = sum(r["warned"][k] for r in right)
        real = sum(r["warned"][k] and r["real"][k] for r in right)
        missed = sum(r["real"][k] and not r["warned"][k] for r in right)
        cells.append(f"{warned} / {real} / {missed}")
    wrong = [r for r in rows if not r["right"]]
    first = sum(r["warned"][0] for r in wrong)
    return f"| {label} | {len(right)} | {cells[0]} | {cells[1]} | {first} of {len(wrong)} |"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--city", action="append", default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--queries", type=int, default=60)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    cities = args.city or calibration_cities(SHARED)
    print(
        "| city, reality | right poses | map lacks: warned / real / real not warned "
        "| image does not show: warned / real / real not warned | wrong poses with the first |"
    )
    print("|---|---|---|---|---|")
    for city in cities:
        for changed in (False, True):
            with ProcessPoolExecutor(
                args.workers, initializer=_init, initargs=(city, args.seed, args.queries, changed)
            ) as pool:
                rows = [r for r in pool.map(_one, range(args.queries)) if r is not None]
            reality = "a fifth changed" if changed else "realistic"
            print(row(f"{Path(city).stem} seed {args.seed}, {reality}", rows), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

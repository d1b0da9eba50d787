"""How a view beyond the search volume scores against the best inside it, query by query.

The look beyond (``cascade.look_beyond``, ``docs/localization.md`` "A look beyond the volume") runs on
refused results only and warns when a ring of views just beyond the volume's largest extent holds one,
distinct from the refused pose, that scores higher than the sweep's best. This script measures that
signal on every query, accepted or not: the default localizer localizes each query, then the ring is
scored around its pose, so that both uses can be judged on the same rows: as the shipped hint (on the
refused results) and as a refusal of any result (``--margin``: the pose refused when the ring's best is at
least the sweep's best + margin; a ring on a coarser lattice than the sweep's rarely reaches its peak).

Conditions: ``trained``, ``medium``, ``zero-shot`` masks with the realistic priors; ``prior20-30`` and
``prior40-50``: trained masks and the paper's extra prior error per axis against the default stated
uncertainty (the truth beyond what the volume reaches).

    python benchmarks/look_beyond.py [--city generated] [--seed 0] [--queries 50]
        [--condition prior40-50] [--margin 0] [--exclude 12] [--rows FILE.jsonl] [--workers 2]
        [--check-only]  (a reporting city, Berlin or Den Haag, only with --check-only)

Prints one summary JSON line: right and wrong poses (within 5 m / 5 deg), how many were refused by the
acceptance, on how many refused ones the hint fires (right / wrong), and how many accepted ones a refusal
at ``--margin`` would take away (right / wrong). Calibration cities only for decisions.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from semcityloc.benchmark.calibration import ACCEPTANCE_CONDITIONS, require_calibration_cities
from semcityloc.benchmark.scenario import query_config
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.errors import ParameterError
from semcityloc.evaluation.metrics import is_right
from semcityloc.geometry.errors import center_error_m, rotation_error_deg
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.localize import Localizer
from semcityloc.localization.query import Query
from semcityloc.localization.result import LOCALIZED

CONDITIONS = ACCEPTANCE_CONDITIONS
SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"

_WORKER: dict = {}


def _init(city: str, seed: int, queries: int, condition: str, margin: float, exclude: float) -> None:
    seg, extra = CONDITIONS[condition]
    query = query_config("realistic", queries=queries, seed=seed, seg_quality=seg, prior_extra_m=extra)
    spec = BenchmarkSpec(city=city, query=query)
    source = spec.open_source(spec.run_config())
    base = LocalizerConfig.preset("default")
    beyond = dataclasses.replace(base.cascade.beyond, enabled=False, margin=margin, exclude_m=exclude)
    cfg = dataclasses.replace(base, cascade=dataclasses.replace(base.cascade, beyond=beyond))
    _WORKER.update(source=source, localizer=Localizer(source.map_model, cfg), cfg=cfg)


def _one(index: int) -> dict | None:
    source, loc, cfg = _WORKER["source"], _WORKER["localizer"], _WORKER["cfg"]
    q = source.query(index)
    if not q.meta.get("accepted", True):
        return None
    r = loc.localize(q.camera, q.prior_pose_local, q.labels, q.depth)
    pose = r.found_pose_local
    row = {"query": q.query_id, "status": r.status, "reason": r.reason}
    if pose is None or "sweep_best" not in r.search:
        return row
    e_m, e_deg = (
        float(center_error_m(pose, q.true_pose_local)),
        float(rotation_error_deg(pose, q.true_pose_local)),
    )
    query = Query.from_arrays(q.labels, None, loc.has_openings)
    prior = q.prior_pose_local.to_xyz_rpy()
    ring, _ = loc.ring_beyond(q.camera, query, prior, pose.to_xyz_rpy()[:2], cfg, cfg.prior_uncertainty)
    row.update(
        error_m=e_m,
        error_deg=e_deg,
        right=is_right(e_m, e_deg),
        sweep_best=r.search["sweep_best"],
        ring_best=None if ring is None else ring.score,
        ring_offset_m=None if ring is None else ring.offset_xy_m,
    )
    return row


def summarize(rows: list[dict], margin: float) -> dict:
    """The summary line of the module docstring; ``hint``: the ring's best scores higher than the sweep's
    (the shipped rule, margin 0), ``refuse``: the ring's best >= the sweep's + ``margin``."""
    scored = [r for r in rows if r.get("ring_best") is not None]

    def gap(r: dict) -> float:
        return r["ring_best"] - r["sweep_best"]

    out: dict = {"queries": len(rows), "scored": len(scored)}
    for side, right in (("right", True), ("wrong", False)):
        mine = [r for r in scored if r["right"] == right]
        refused = [r for r in mine if r["status"] != LOCALIZED]
        accepted = [r for r in mine if r["status"] == LOCALIZED]
        out[side] = len(mine)
        out[f"{side}_refused"] = len(refused)
        out[f"{side}_refused_hinted"] = sum(gap(r) >= 0.0 for r in refused)
        out[f"{side}_accepted_taken_at_margin"] = sum(gap(r) >= margin for r in accepted)
        out[f"{side}_all_taken_at_margin"] = sum(gap(r) >= margin for r in mine)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--city", default="generated")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--queries", type=int, default=50)
    ap.add_argument("--condition", default="trained", choices=tuple(CONDITIONS))
    ap.add_argument("--margin", type=float, default=LocalizerConfig().cascade.beyond.margin)
    ap.add_argument("--exclude", type=float, default=LocalizerConfig().cascade.beyond.exclude_m)
    ap.add_argument("--rows", type=Path, help="write every query's row here as JSON lines")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--check-only", action="store_true", help="allow a reporting city: a check, not a choice")
    args = ap.parse_args()
    if not args.check_only:
        try:
            require_calibration_cities([args.city], SHARED_DATA, "choose the look beyond's margin")
        except ParameterError as exc:
            raise SystemExit(f"{exc} (pass --check-only for a check)") from None
    init = (args.city, args.seed, args.queries, args.condition, args.margin, args.exclude)
    with ProcessPoolExecutor(args.workers, initializer=_init, initargs=init) as pool:
        rows = [r for r in pool.map(_one, range(args.queries)) if r is not None]
    if args.rows:
        args.rows.write_text("".join(json.dumps(r) + "\n" for r in rows), encoding="utf-8")
    summary = {"city": Path(args.city).stem, "seed": args.seed, "condition": args.condition}
    print(json.dumps({**summary, "margin": args.margin, **summarize(rows, args.margin)}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

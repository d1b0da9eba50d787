"""Is a miss the search's fault or the score's? The true pose's score against the estimate's.

For every query of the benchmark's realistic scenario (``semcityloc benchmark`` default) that the default
localizer misses at 2 m / 2 deg, the refinement's own score (``Localizer.score_poses``: C_s - C_d minus the
prior's roll/pitch term, at the refinement's final resolution) of the true pose and of the found pose:

- the true pose scores HIGHER: the search did not find the best pose (more search would help);
- the true pose scores LOWER: the score prefers the wrong pose (the map differs from the world, the masks
  and depth err): no search can help, only a better score or better input.

Prints one JSON line per missed query (``id``, ``view``, errors, ``score_truth``, ``score_found``) and, last,
a summary line: queries, misses, and how many of them are the score's (``truth_lower``).

``--scales 2,4,8`` also scores both poses at other refinement resolutions (``refine.scale`` times the
search's width: 128, 256, 512 pixels across by default): ``score_truth_x4`` etc. per miss and
``truth_lower_x4`` in the summary. Does a finer score tell the truth from the found pose where the
refinement's cannot (a resolution limit), or does it prefer the found pose too (the input's bias)?

    python benchmarks/score_at_truth.py [--city generated] [--seed 0] [--queries 100] [--workers 2]
        [--scales 4,8] [--set focal_mm=28 ...]

Calibration cities only for decisions (the generated city, Fürth); ``docs/localization.md`` has the figures.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from concurrent.futures import ProcessPoolExecutor

from semcityloc.benchmark.scenario import query_config
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.cli.benchmark import parse_settings  # the command line's --set knob=value
from semcityloc.errors import BenchmarkConfigError
from semcityloc.geometry.errors import center_error_m, rotation_error_deg
from semcityloc.localization.localize import Localizer

_WORKER: dict = {}


def _init(city: str, seed: int, queries: int, scales: tuple[int, ...], settings: dict) -> None:
    spec = BenchmarkSpec(city=city, query=query_config("realistic", settings, queries=queries, seed=seed))
    source = spec.open_source(spec.run_config())
    _WORKER.update(source=source, localizer=Localizer(source.map_model), scales=scales)


def _one(index: int) -> dict | None:
    source, loc = _WORKER["source"], _WORKER["localizer"]
    q = source.query(index)
    if not q.meta.get("accepted", True):
        return None
    r = loc.localize(q.camera, q.prior_pose_local, q.labels, q.depth)
    found = r.found_pose_local
    row = {"id": q.query_id, "view": q.meta.get("view"), "status": r.status}
    if "probability" in r.confidence:
        row["probability"] = round(float(r.confidence["probability"]), 3)
    if found is None:
        return {**row, "miss": True}
    e_m, e_deg = (
        float(center_error_m(found, q.true_pose_local)),
        float(rotation_error_deg(found, q.true_pose_local)),
    )
    row.update(err_m=round(e_m, 3), err_deg=round(e_deg, 3), miss=not (e_m <= 2.0 and e_deg <= 2.0))
    if row["miss"]:
        s = loc.score_poses(
            q.camera, q.labels, q.depth, [q.true_pose_local, found], prior_local=q.prior_pose_local
        )["score"]
        row.update(score_truth=round(float(s[0]), 4), score_found=round(float(s[1]), 4))
        for scale in _WORKER["scales"]:
            cfg = dataclasses.replace(loc.config, refine=dataclasses.replace(loc.config.refine, scale=scale))
            s = loc.score_poses(
                q.camera, q.labels, q.depth, [q.true_pose_local, found], q.prior_pose_local, config=cfg
            )["score"]
            row[f"score_truth_x{scale}"] = round(float(s[0]), 4)
            row[f"score_found_x{scale}"] = round(float(s[1]), 4)
    return row


def _scales(text: str) -> tuple[int, ...]:
    try:
        scales = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"--scales: comma-separated integers, got {text!r}") from None
    if any(v < 1 for v in scales):
        raise argparse.ArgumentTypeError(f"--scales: each scale must be >= 1, got {text!r}")
    return scales


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", default="generated")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--queries", type=int, default=100)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--scales", type=_scales, default=(), help="also score at these refine.scale values")
    ap.add_argument("--set", action="append", default=[], metavar="KNOB=VALUE", help="a scenario knob")
    args = ap.parse_args()
    try:
        settings = parse_settings(args.set)
        query_config("realistic", settings, queries=args.queries, seed=args.seed)
    except BenchmarkConfigError as exc:
        raise SystemExit(f"score_at_truth: {exc}") from None
    init_args = (args.city, args.seed, args.queries, args.scales, settings)
    with ProcessPoolExecutor(args.workers, initializer=_init, initargs=init_args) as pool:
        rows = [r for r in pool.map(_one, range(args.queries)) if r is not None]
    misses = [r for r in rows if r["miss"]]
    for r in misses:
        print(json.dumps(r))
    scored = [r for r in misses if "score_truth" in r]
    lower = sum(r["score_truth"] < r["score_found"] for r in scored)
    summary = {"city": args.city, "seed": args.seed, "settings": settings, "queries": len(rows)}
    summary["misses"] = len(misses)
    summary.update(scored_misses=len(scored), truth_lower=lower, truth_higher=len(scored) - lower)
    for scale in args.scales:
        summary[f"truth_lower_x{scale}"] = sum(
            r[f"score_truth_x{scale}"] < r[f"score_found_x{scale}"] for r in scored
        )
    print(json.dumps(summary))


if __name__ == "__main__":
    main()

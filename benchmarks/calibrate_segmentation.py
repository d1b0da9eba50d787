"""Calibrate the realistic segmentation presets: their mIoU measured the paper's way.

Usage::

    python benchmarks/calibrate_segmentation.py [--city generated --city FILE ...] [--views 60] [--direct]
        [--seed 0] [--reality realistic|default] [--presets trained,medium,zero-shot] [--cache DIR]

For each city (default: the generated city and Fuerth, ``../shared/data/fuerth_lod2_citygml1/
LOD2_4424_5482_solid.gml``; never Berlin, whose numbers are reported, not tuned on), the script simulates
``--views`` benchmark views (``benchmark.seg_calibration.calibration_views``: the benchmark's poses,
reality render, ``ViewTruth`` with the query's sun and the map's labels; views the simulator does not
accept are skipped, as the benchmark skips them) and scores every realistic preset on them
(``score_preset``: the queries' own segmentation streams).

Measured the paper's way: against the MAP's own labels projected at the true pose by the automatic
labelling rules (``perception.autolabel.auto_label``; IGNORE pixels left out), confusion matrices summed
over the views (pooled) and mean IoU over ``MIOU_CLASSES`` present; also the mean of the per-image mIoU.
Classes the map does not have (windows and doors on an LoD2 map) are folded into wall before scoring
(``seg_errors.fold_to_map_classes``: a network trained on the map's labels never outputs them).

``--reality realistic`` (default) builds the reality with ``reality.REALISTIC_REALITY``; ``default``
with ``RealityParams()`` (the clean scenario's). The line ``ceiling`` is a perfect segmentation of the
reality with trees and cars labelled as what is behind them: what the reality's differences from the map
alone cost. ``--cache DIR`` keeps the simulated views (truth + map labels) in ``DIR`` for re-runs.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import sys
import time
from pathlib import Path

import numpy as np

from semcityloc.benchmark.calibration import calibration_cities_or_exit
from semcityloc.benchmark.perception_sim import MIN_PRESENT_PIXELS, MIOU_CLASSES
from semcityloc.benchmark.queries import QueryConfig, QuerySimulator
from semcityloc.benchmark.reality import REALISTIC_REALITY, RealityParams
from semcityloc.benchmark.scenario import query_config
from semcityloc.benchmark.seg_calibration import CalibrationView, calibration_views, score_preset
from semcityloc.benchmark.seg_errors import REALISTIC_SEG_PRESETS, SEG_TARGETS, ViewTruth
from semcityloc.benchmark.spec import BenchmarkSpec, load_models
from semcityloc.classes import NUM_CLASSES
from semcityloc.perception.metrics import iou_per_class, mean_iou

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
TRUTH_FIELDS = [f.name for f in dataclasses.fields(ViewTruth)]


def prepare_views(city: str, views: int, seed: int, reality: str, cache: Path | None = None) -> dict:
    """{"views": [CalibrationView], "map_classes": array, "s_per_view": float} (``--cache``: kept in npz)."""
    params = REALISTIC_REALITY if reality == "realistic" else RealityParams()
    key = hashlib.sha1(f"{city}|{views}|{seed}|{params!r}".encode()).hexdigest()[:12]
    path = None if cache is None else Path(cache) / f"views_{Path(city).stem}_{key}.npz"
    if path is not None and path.exists():
        z = np.load(path, allow_pickle=False)
        out = [
            CalibrationView(
                int(z[f"index_{i}"]),
                str(z[f"view_{i}"]),
                ViewTruth(**{k: z[f"{k}_{i}"] for k in TRUTH_FIELDS}),
                z[f"ref_{i}"],
            )
            for i in range(int(z["n"]))
        ]
        return {"views": out, "map_classes": z["map_classes"], "s_per_view": float(z["s_per_view"])}
    cfg = QueryConfig(queries=views, seed=seed, reality=params)
    map_model, reality_model = load_models(BenchmarkSpec(city=city, query=cfg).run_config())
    t0 = time.perf_counter()
    out, map_classes = calibration_views(map_model, cfg, reality_model)
    spent = (time.perf_counter() - t0) / max(views, 1)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {"n": len(out), "map_classes": map_classes, "s_per_view": spent}
        for i, v in enumerate(out):
            arrays[f"index_{i}"], arrays[f"view_{i}"], arrays[f"ref_{i}"] = v.index, v.view, v.map_labels
            for k in TRUTH_FIELDS:
                arrays[f"{k}_{i}"] = getattr(v.truth, k)
        np.savez_compressed(path, **arrays)
    return {"views": out, "map_classes": map_classes, "s_per_view": spent}


def score(data: dict, preset, seed: int = 0, perfect: bool = False) -> dict:
    """Pooled and per-image mIoU (%) of ``preset`` on prepared views (module docstring)."""
    t0 = time.perf_counter()
    res = score_preset(data["views"], data["map_classes"], None if perfect else preset, seed)
    return {
        "pooled": res.pooled,
        "per_image": res.per_image,
        "iou": res.iou,
        "confusion": res.confusion,
        "seg_s": (time.perf_counter() - t0) / max(len(data["views"]), 1),
    }


def direct(city: str, views: int, seed: int, quality: str, reality: str) -> dict:
    """The benchmark's own path (``--direct``): ``QuerySimulator(map, query_config("realistic", ...),
    reality)``, ``query_with_truth(i)`` (runs ``view_truth`` + ``simulate_segmentation``) and
    ``sim.map_confusion`` pooled over the accepted views; no class folding (what the benchmark reports)."""

    extra = {} if reality == "realistic" else {"reality": RealityParams()}
    cfg = query_config("realistic", queries=views, seed=seed, seg_quality=quality, **extra)
    map_model, reality_model = load_models(BenchmarkSpec(city=city, query=cfg).run_config())
    sim = QuerySimulator(map_model, cfg, reality_model)
    pooled = np.zeros((NUM_CLASSES, NUM_CLASSES), dtype=np.int64)
    per_image, t0, n = [], time.perf_counter(), 0
    for i in range(views):
        view = sim.query_with_truth(i)
        if not view.query.meta.get("accepted", True):
            continue
        n += 1
        conf = sim.map_confusion(view.query.true_pose_local, view.query.labels)
        pooled += conf
        per_image.append(
            mean_iou(conf, classes=MIOU_CLASSES, min_pixels=MIN_PRESENT_PIXELS, percent_of_mean=True)
        )
    return {
        "pooled": mean_iou(pooled, classes=MIOU_CLASSES, min_pixels=1, percent_of_mean=True),
        "per_image": float(np.nanmean(per_image)),
        "iou": iou_per_class(pooled),
        "confusion": pooled,
        "views": n,
        "s_per_view": (time.perf_counter() - t0) / max(views, 1),
    }


def _row_shares(conf: np.ndarray) -> str:
    names = ("bg", "ground", "wall", "roof")
    rows = []
    for g in (1, 2, 3):
        total = max(int(conf[g].sum()), 1)
        shares = " ".join(f"{names[p]} {100 * conf[g, p] / total:4.1f}" for p in range(4))
        rows.append(f"    map {names[g]:>6} -> {shares}")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--city", action="append", help="generated or a CityGML/CityJSON file (repeatable)")
    ap.add_argument("--views", type=int, default=60)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--reality", choices=("realistic", "default"), default="realistic")
    ap.add_argument("--presets", default="trained,medium,zero-shot")
    ap.add_argument("--cache", type=Path, default=None)
    ap.add_argument("--direct", action="store_true", help="the benchmark's own path (no cache, slower)")
    args = ap.parse_args(argv)

    cities = calibration_cities_or_exit(args.city, SHARED_DATA, "calibrate the segmentation presets")
    if args.direct:
        for city in cities:
            print(f"== {Path(city).name}: direct, {args.views} views ({args.reality} reality)", flush=True)
            for name in ["perfect", *args.presets.split(",")]:
                res = direct(city, args.views, args.seed, name, args.reality)
                lo, hi = SEG_TARGETS.get(name, (100.0, 100.0))
                ok = "ok" if lo - 2 <= res["pooled"] <= hi + 2 else "OUT"
                print(
                    f"  {name:>9}: pooled {res['pooled']:5.1f}  per-image {res['per_image']:5.1f}  "
                    f"(target {lo:g}-{hi:g}: {ok})  IoU g/w/r {np.round(res['iou'][1:4], 1)}  "
                    f"{res['views']} views, {res['s_per_view']:.2f} s/view",
                    flush=True,
                )
                print(_row_shares(res["confusion"]), flush=True)
        return 0
    for city in cities:
        t0 = time.perf_counter()
        data = prepare_views(city, args.views, args.seed, args.reality, args.cache)
        n = len(data["views"])
        print(
            f"== {Path(city).name}: {n} views ({args.reality} reality), prepared in "
            f"{time.perf_counter() - t0:.1f} s ({data['s_per_view']:.3f} s/view)"
        )
        ceiling = score(data, None, args.seed, perfect=True)
        print(
            f"  ceiling (perfect, occluders as behind): pooled {ceiling['pooled']:.1f}  "
            f"per-image {ceiling['per_image']:.1f}  IoU g/w/r {np.round(ceiling['iou'][1:4], 1)}"
        )
        for name in args.presets.split(","):
            res = score(data, REALISTIC_SEG_PRESETS[name], args.seed)
            lo, hi = SEG_TARGETS[name]
            ok = "ok" if lo - 2 <= res["pooled"] <= hi + 2 else "OUT"
            print(
                f"  {name:>9}: pooled {res['pooled']:5.1f}  per-image {res['per_image']:5.1f}  "
                f"(target {lo:g}-{hi:g}: {ok})  IoU g/w/r {np.round(res['iou'][1:4], 1)}  "
                f"seg {res['seg_s']:.3f} s/view"
            )
            print(_row_shares(res["confusion"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())

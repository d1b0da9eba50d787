"""Fit the localizer's calibrated acceptance (``localization/confidence.py``) and check it on held-out data.

Usage::

    python benchmarks/calibrate_confidence.py [--queries 60] [--workers 2] [--cache DIR]
        [--write [--write-only V]] [--fit-city generated --fit-city FUERTH ...] [--check-city BERLIN ...]
        [--seed 0] [--without FEATURE] [--cross-city [--reached]]

Fit data (never a reporting city): the realistic scenario on the generated city and Fürth, with every
segmentation quality (trained, medium, zero-shot) and with the paper's extra prior errors (20-30 and
40-50 m per axis, so that look-alikes and edge cases are seen), ``--queries`` per condition. Every query
is localized by SemCityLoc with depth, without depth (``no-depth``) and by the silhouette baseline, with
acceptance switched off, and the features of each result (``confidence.FEATURES_*``) are kept with the
answer (within 5 m and 5 deg of the truth or not). One sign-constrained logistic model is fitted per
(kind, with depth) and, with ``--write``, saved to ``src/semcityloc/localization/confidence_models.json``
(``--write-only semcityloc`` replaces that localizer's model alone and keeps the others as shipped).

Check (``--check-city``, default Berlin, seed 1 so that no benchmark query is reused): the same
conditions; prints the expected calibration error (10 bins), the Brier score, and the risk-coverage
curve (coverage and precision at the acceptance probabilities 0.3 ... 0.9) of each model.

``--cross-city`` (judging a feature on the calibration cities alone): each model is fitted on one
calibration city and checked on the other, both ways; with ``--without NAME`` the same is done without
that feature too, side by side (ECE, log-loss, right and wrong poses accepted at p >= 0.5), and the
difference of the two in log-loss and Brier with a 95 % interval from a paired bootstrap over queries
(a query's results under the five conditions resampled together; ``evaluation/scoring_rules.py``). Without
``--cross-city``, ``--without NAME`` also fits each model without that feature and reports its fit and
check beside the full model's and the paired difference on the check city (never written). With
``--reached`` the check counts only the results that reached the acceptance (the population the model
is applied to), and each model is fitted both on every row and on those.

``--check-shipped`` fits nothing: it checks the models the package ships (``confidence_models.json``)
on the check city's conditions with today's localizer, one line per condition and one over all of them
(the table of ``docs/benchmark.md``, "Acceptance and risk-coverage").

``--cache DIR`` keeps every condition's features (``DIR/<city>_<condition>_<seed>_<queries>_<code>.json``,
``<code>`` the package's ``code_fingerprint``), so a refit does not localize again, and features made by
other code (another localizer or simulation) are never reused.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from semcityloc.baselines.silhouette import SilhouetteLocalizer
from semcityloc.benchmark.calibration import ACCEPTANCE_CONDITIONS, calibration_cities_or_exit
from semcityloc.benchmark.calibration import condition_rows as calibration_rows
from semcityloc.benchmark.scenario import query_config
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.evaluation.metrics import is_right
from semcityloc.evaluation.scoring_rules import paired_difference
from semcityloc.geometry.errors import center_error_m, rotation_error_deg
from semcityloc.localization.confidence import (
    FEATURES_DEPTH,
    FEATURES_NO_DEPTH,
    calibration_error,
    confidence_model,
    features_of,
    fit_logistic,
    load_models,
    risk_coverage,
    save_models,
)
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.localize import Localizer

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data"
BERLIN = SHARED / "berlin_lod2_citygml2" / "3910_5817.gml"
CONDITIONS = ACCEPTANCE_CONDITIONS
# (kind, with depth) -> the localizer variant whose results fit it
VARIANTS = {
    ("semantic", True): "semcityloc",
    ("semantic", False): "no-depth",
    ("silhouette", False): "silhouette",
}

_WORKER: dict = {}


def _open_config() -> LocalizerConfig:
    """The default localizer with acceptance switched off (every result keeps its pose)."""
    base = LocalizerConfig.preset("default")
    return replace(
        base,
        acceptance="thresholds",
        min_building_iou=0.0,
        min_score=-1e9,
        min_semantic_with_depth=-1e9,
        max_depth_cost=1e9,
    )


def _init(city: str, seed: int, queries: int, condition: str) -> None:
    seg, extra = CONDITIONS[condition]
    spec = BenchmarkSpec(
        city=city,
        query=query_config("realistic", queries=queries, seed=seed, seg_quality=seg, prior_extra_m=extra),
    )
    source = spec.open_source(spec.run_config())
    cfg = _open_config()
    _WORKER.update(
        source=source,
        semcityloc=Localizer(source.map_model, cfg),
        silhouette=SilhouetteLocalizer(source.map_model, cfg),
        cfg=cfg,
    )


def _one(index: int) -> list[dict]:
    source, cfg = _WORKER["source"], _WORKER["cfg"]
    q = source.query(index)
    if not q.meta.get("accepted", True):
        return []
    out = []
    for variant in ("semcityloc", "no-depth", "silhouette"):
        if variant == "silhouette":
            r = _WORKER["silhouette"].localize(q.camera, q.prior_pose_local, q.labels, None)
        else:
            c = replace(cfg, no_depth=variant == "no-depth")
            r = _WORKER["semcityloc"].localize(q.camera, q.prior_pose_local, q.labels, q.depth, config=c)
        pose = r.found_pose_local
        row = {"query": q.query_id, "variant": variant, "status": r.status, "reason": r.reason}
        if pose is not None:
            e_m = float(center_error_m(pose, q.true_pose_local))
            e_deg = float(rotation_error_deg(pose, q.true_pose_local))
            row.update(error_m=e_m, error_deg=e_deg, right=is_right(e_m, e_deg))
            names = FEATURES_DEPTH if variant == "semcityloc" else FEATURES_NO_DEPTH
            row["features"] = dict(zip(names, features_of(r, names).tolist(), strict=True))
        out.append(row)
    return out


def condition_rows(city: str, seed: int, queries: int, condition: str, workers: int, cache: Path | None):
    """One condition's rows, each tagged with its query's ``group`` (city and query id): the unit the
    paired bootstrap resamples, since a query is seen under every condition."""
    rows = calibration_rows("", city, seed, queries, condition, workers, cache, _init, _one)
    return [dict(row, group=f"{Path(city).stem}/{row['query']}") for row in rows]


def _selected(rows: list[dict], variant: str) -> list[dict]:
    return [r for r in rows if r["variant"] == variant and "features" in r]


def groups_of(rows: list[dict], variant: str) -> np.ndarray:
    """The ``group`` of each row ``matrix`` keeps, in its order (a row without one is a group of its own)."""
    return np.array([r.get("group") or f"row {i}" for i, r in enumerate(_selected(rows, variant))])


def matrix(rows: list[dict], variant: str, names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    sel = _selected(rows, variant)
    X = np.array([[r["features"][n] if r["features"][n] is not None else np.nan for n in names] for r in sel])
    y = np.array([r["right"] for r in sel], dtype=float)
    return X.reshape(len(sel), len(names)), y


def report(model, X: np.ndarray, y: np.ndarray, label: str) -> dict:
    p = model.probability_of(X)
    curve = risk_coverage(p, y)
    at = {}
    for t in (0.3, 0.5, 0.7, 0.9):
        acc = p >= t
        at[t] = (float(acc.mean()), float(y[acc].mean()) if acc.any() else float("nan"))
    ece = calibration_error(p, y)
    brier = float(np.mean((p - y) ** 2))
    print(
        f"{label}: n={len(y)} right={y.mean():.3f} ECE={ece:.3f} Brier={brier:.3f} "
        + " ".join(f"p>={t}: cover {c:.2f} prec {pr:.3f}" for t, (c, pr) in at.items())
    )
    return {"n": len(y), "ece": ece, "brier": brier, "at": at, "curve": curve}


def compare(model_a, model_b, rows: list[dict], variant: str) -> str:
    """Paired bootstrap over the rows' groups of (A - B) in log-loss and Brier: negative = A better."""
    Xa, y = matrix(rows, variant, model_a.features)
    Xb, _ = matrix(rows, variant, model_b.features)
    pa, pb, groups = model_a.probability_of(Xa), model_b.probability_of(Xb), groups_of(rows, variant)
    return "; ".join(str(paired_difference(pa, pb, y, groups, rule=r)) for r in ("log-loss", "brier"))


def _decisions(model, X: np.ndarray, y: np.ndarray) -> str:
    p = np.clip(model.probability_of(X), 1e-9, 1 - 1e-9)
    log_loss = float(-np.mean(y * np.log(p) + (1 - y) * np.log(1 - p)))
    acc = p >= 0.5
    return (
        f"ECE {calibration_error(p, y):.3f} log-loss {log_loss:.3f} "
        f"right accepted {int((acc & (y == 1)).sum())}/{int(y.sum())} "
        f"wrong accepted {int((acc & (y == 0)).sum())}/{int((y == 0).sum())}"
    )


def reached_acceptance(rows: list[dict]) -> list[dict]:
    """The rows whose localization reached the acceptance (not stopped on the volume's edge or earlier:
    those keep a pose but no scores, and are refused whatever the probability)."""
    return [row for row in rows if row.get("reason") is None and "features" in row]


def cross_city(rows_by_city: dict[str, list[dict]], without: str | None, reached: bool = False) -> None:
    """Fit on each calibration city, check on the other; with ``without`` also without that feature; with
    ``reached`` checked on the rows that reached the acceptance only, fitted on every row and on those."""
    for (kind, with_depth), variant in VARIANTS.items():
        names = FEATURES_DEPTH if with_depth else FEATURES_NO_DEPTH
        sets = {"all": names}
        if without is not None:
            sets[f"without {without}"] = tuple(n for n in names if n != without)
        for fit_city, fit_rows in rows_by_city.items():
            fits = {"": fit_rows}
            if reached:
                fits = {", fit on every row": fit_rows, ", fit on the reached": reached_acceptance(fit_rows)}
            for check_city, check_rows in rows_by_city.items():
                if check_city == fit_city:
                    continue
                checked = reached_acceptance(check_rows) if reached else check_rows
                for fit_label, rows in fits.items():
                    models = {}
                    for label, feats in sets.items():
                        model = fit_logistic(*matrix(rows, variant, feats), feats, kind, with_depth)
                        models[label] = model
                        print(
                            f"{variant} {fit_city} -> {check_city}, {label}{fit_label}: "
                            + _decisions(model, *matrix(checked, variant, feats))
                        )
                    if without is not None:
                        print(
                            f"    all - without {without} (paired bootstrap over queries): "
                            + compare(models["all"], models[f"without {without}"], checked, variant)
                        )


def check_shipped(check_cities: list[str], args) -> int:
    """``--check-shipped``: the shipped models on each check city's conditions, one line per condition and
    one over all of them (coverage and precision at 0.3 ... 0.9, ECE, Brier)."""
    if not check_cities:
        print(
            "--check-shipped: no check city (Berlin is not in ../shared/data; pass --check-city)",
            file=sys.stderr,
        )
        return 2
    for city in check_cities:
        rows = {
            cond: condition_rows(city, args.check_seed, args.queries, cond, args.workers, args.cache)
            for cond in CONDITIONS
        }
        for (kind, with_depth), variant in VARIANTS.items():
            model = confidence_model(kind, with_depth)
            names = model.features
            depth = "with" if with_depth else "without"
            print(f"## {Path(city).stem} seed {args.check_seed}, shipped {kind} {depth} depth ({variant})")
            for cond, cond_rows in rows.items():
                report(model, *matrix(cond_rows, variant, names), f"  {cond}")
            report(model, *matrix([r for rr in rows.values() for r in rr], variant, names), "  all")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fit-city", action="append", default=None)
    ap.add_argument("--check-city", action="append", default=None)
    ap.add_argument("--queries", type=int, default=60)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--check-seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=None)
    ap.add_argument("--write", action="store_true", help="save the fitted models into the package")
    ap.add_argument(
        "--write-only",
        action="append",
        choices=sorted(VARIANTS.values()),
        default=None,
        help="with --write: save only this localizer's model (repeatable); the others stay as shipped",
    )
    ap.add_argument("--cross-city", action="store_true", help="fit on one calibration city, check on another")
    ap.add_argument("--without", default=None, help="also fit and check without this feature (not written)")
    ap.add_argument(
        "--reached",
        action="store_true",
        help="with --cross-city: check on the results that reached the acceptance",
    )
    ap.add_argument(
        "--check-shipped",
        action="store_true",
        help="fit nothing: check the shipped models on the check city, per condition",
    )
    args = ap.parse_args()
    if args.without is not None and args.without not in FEATURES_DEPTH:
        print(
            f"--without: unknown feature {args.without!r}; one of {', '.join(FEATURES_DEPTH)}",
            file=sys.stderr,
        )
        return 2

    check_cities = (
        args.check_city if args.check_city is not None else ([str(BERLIN)] if BERLIN.exists() else [])
    )
    if args.check_shipped:
        return check_shipped(check_cities, args)
    fit_cities = calibration_cities_or_exit(args.fit_city, SHARED, "fit the confidence model")
    by_city = {
        Path(city).stem: [
            row
            for cond in CONDITIONS
            for row in condition_rows(city, args.seed, args.queries, cond, args.workers, args.cache)
        ]
        for city in fit_cities
    }
    if args.cross_city:
        cross_city(by_city, args.without, args.reached)
        return 0
    fit_rows = [row for rows in by_city.values() for row in rows]
    check_rows = []
    for city in check_cities:
        for cond in CONDITIONS:
            check_rows += condition_rows(city, args.check_seed, args.queries, cond, args.workers, args.cache)

    described = ", ".join(Path(c).stem for c in fit_cities)
    models = []
    for (kind, with_depth), variant in VARIANTS.items():
        names = FEATURES_DEPTH if with_depth else FEATURES_NO_DEPTH
        X, y = matrix(fit_rows, variant, names)
        model = fit_logistic(
            X,
            y,
            names,
            kind,
            with_depth,
            fitted_on=f"realistic, {described}, seed {args.seed}, conditions {', '.join(CONDITIONS)}",
        )
        models.append(model)
        print(
            f"## {kind} {'with' if with_depth else 'without'} depth ({variant}): "
            + ", ".join(f"{n} {w:+.3f}" for n, w in zip(names, model.weights, strict=True))
            + f", bias {model.bias:+.3f}"
        )
        report(model, X, y, "  fit")
        if check_rows:
            Xc, yc = matrix(check_rows, variant, names)
            report(model, Xc, yc, "  check")
            print("    check: " + _decisions(model, Xc, yc))
        if args.without is not None and args.without in names:
            fewer = tuple(n for n in names if n != args.without)
            X, y = matrix(fit_rows, variant, fewer)
            other = fit_logistic(X, y, fewer, kind, with_depth, fitted_on="comparison only")
            report(other, X, y, f"  fit without {args.without}")
            if check_rows:
                Xc, yc = matrix(check_rows, variant, fewer)
                report(other, Xc, yc, f"  check without {args.without}")
                print(f"    check without {args.without}: " + _decisions(other, Xc, yc))
                print(
                    f"    all - without {args.without} (paired bootstrap over queries): "
                    + compare(model, other, check_rows, variant)
                )
    if args.write:
        if args.write_only is not None:
            shipped = {(m.kind, m.with_depth): m for m in load_models()}
            fitted = {(m.kind, m.with_depth): m for m in models}
            models = [
                fitted[k] if v in args.write_only else shipped.get(k, fitted[k]) for k, v in VARIANTS.items()
            ]
        save_models(models)
        print("# written", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())

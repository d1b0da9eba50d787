"""Fit the pose covariance (``localization/covariance.py``: temperature, floor); check it on held-out data.

Usage::

    python benchmarks/calibrate_covariance.py [--queries 100] [--workers 2] [--cache DIR] [--write]
        [--fit-city generated --fit-city FUERTH ...] [--check-city BERLIN ...] [--seed 0] [--check-seed 1]

Fit data (never a reporting city): the realistic scenario on the calibration cities, trained and medium
segmentation, ``--queries`` each; for the narrow-camera models (``<key>/narrow``, used below
``covariance.NARROW_BELOW_DEG`` across), trained masks seen by a 34 deg camera (``focal_mm`` 28).
Every query is localized by SemCityLoc with depth and without
(``no-depth``, the default acceptance); each found pose within 5 m / 5 deg of the truth gives its state
error ``e`` (x, y, z in m; roll, pitch, yaw in deg) and the score's curvature ``A`` at the pose. The
model ``T * A^-1 + diag(floor^2)`` (a temperature and six floor sigmas) is fitted by maximum likelihood
over the accepted right poses of both conditions, then widened as a whole until its 95 % ellipsoid holds
95 % of them (``fit_model``: the errors are heavier-tailed than a Gaussian). With ``--write`` it is saved to
``src/semcityloc/localization/covariance_model.json``.

Printed for the fit and the check (``--check-city``, default Berlin, seed 1 so that no benchmark query is
reused), over the accepted right poses: the share inside the ellipsoids of 50 / 68 / 90 / 95 / 99 %, the
share of each component within 1 and 2 sigma (68 / 95 % if calibrated), and the mean Gaussian negative
log-likelihood of the errors under the fitted covariance next to two simpler ones: the curvature alone
(``T * A^-1``, ``T`` putting the median Mahalanobis distance at chi2_6's median) and one constant
covariance (the fit data's error covariance). Lower means the covariance knows more.

``--cache DIR`` keeps each condition's rows (``DIR/cov_<city>_<condition>_<seed>_<queries>_<code>.json``,
``<code>`` the package's ``code_fingerprint``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import minimize
from scipy.stats import chi2

from semcityloc.benchmark.calibration import calibration_cities_or_exit
from semcityloc.benchmark.calibration import condition_rows as calibration_rows
from semcityloc.benchmark.scenario import query_config
from semcityloc.benchmark.spec import BenchmarkSpec
from semcityloc.evaluation.metrics import is_right
from semcityloc.geometry.errors import center_error_m, rotation_error_deg
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.covariance import STATE_NAMES, CovarianceModel, save_models, state_error
from semcityloc.localization.localize import Localizer

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data"
BERLIN = SHARED / "berlin_lod2_citygml2" / "3910_5817.gml"
# condition -> (segmentation quality, scenario knobs); the wide models are fitted on CONDITIONS, the
# narrow-camera ones (``covariance.NARROW_BELOW_DEG``) on NARROW_CONDITIONS: a 34 deg camera (a thermal one)
CONDITIONS = {"trained": ("trained", {}), "medium": ("medium", {})}
NARROW_CONDITIONS = {"narrow": ("trained", {"focal_mm": 28.0})}
VARIANTS = {"semantic/depth": False, "semantic/no-depth": True}  # model key -> the config's no_depth
LEVELS = (0.5, 0.68, 0.9, 0.95, 0.99)
TAIL = 0.95  # the ellipsoid probability the fitted covariance is widened to hold (``fit_model``)

_WORKER: dict = {}


def _init(city: str, seed: int, queries: int, condition: str) -> None:
    quality, knobs = {**CONDITIONS, **NARROW_CONDITIONS}[condition]
    spec = BenchmarkSpec(
        city=city,
        query=query_config("realistic", knobs, queries=queries, seed=seed, seg_quality=quality),
    )
    source = spec.open_source(spec.run_config())
    _WORKER.update(source=source, localizer=Localizer(source.map_model, LocalizerConfig.preset("default")))


def _one(index: int) -> list[dict]:
    source, localizer = _WORKER["source"], _WORKER["localizer"]
    q = source.query(index)
    if not q.meta.get("accepted", True):
        return []
    out = []
    for key, no_depth in VARIANTS.items():
        cfg = localizer.config.with_ablation("no-depth") if no_depth else localizer.config
        r = localizer.localize(q.camera, q.prior_pose_local, q.labels, q.depth, config=cfg)
        pose = r.found_pose_local
        if pose is None or r.score_curvature is None:
            continue
        e = state_error(pose, q.true_pose_local)
        e_m, e_deg = (
            float(center_error_m(pose, q.true_pose_local)),
            float(rotation_error_deg(pose, q.true_pose_local)),
        )
        out.append(
            {
                "query": q.query_id,
                "model": key,
                "accepted": r.localized,
                "right": is_right(e_m, e_deg),
                "error": e.tolist(),
                "curvature": r.score_curvature.tolist(),
            }
        )
    return out


def condition_rows(city: str, seed: int, queries: int, condition: str, workers: int, cache: Path | None):
    return calibration_rows("cov_", city, seed, queries, condition, workers, cache, _init, _one)


def arrays(rows: list[dict], key: str) -> tuple[np.ndarray, np.ndarray]:
    """(errors (n, 6), curvatures (n, 6, 6)) of the accepted right poses of one model."""
    sel = [r for r in rows if r["model"] == key and r["accepted"] and r["right"]]
    err = np.array([r["error"] for r in sel], dtype=np.float64).reshape(len(sel), 6)
    curv = np.array([r["curvature"] for r in sel], dtype=np.float64).reshape(len(sel), 6, 6)
    return err, curv


def covariances(model: CovarianceModel, curv: np.ndarray) -> np.ndarray:
    """(n, 6, 6) covariances of a model at curvatures (n, 6, 6)."""
    return np.array([model.covariance(a) for a in curv]).reshape(len(curv), 6, 6)


def median_temperature(err: np.ndarray, curv: np.ndarray) -> float:
    """The temperature of the curvature alone that puts the median Mahalanobis distance at chi2_6's."""
    m = np.einsum("ni,nij,nj->n", err, curv, err)
    return float(np.median(m) / chi2.ppf(0.5, 6))


def fit_model(err: np.ndarray, curv: np.ndarray, tail: float | None = TAIL) -> CovarianceModel:
    """Temperature and floor sigmas of ``T * A^-1 + diag(floor^2)``: the maximum-likelihood shape, then,
    with ``tail``, the whole covariance widened (never narrowed) until that share of the errors lies
    inside the ellipsoid of the same chi-square probability (the errors are heavier-tailed than a
    Gaussian: a navigation filter gating on the covariance must not reject right poses)."""
    model = _max_likelihood(err, curv)
    if tail is None:
        return model
    m = np.einsum("ni,nij,nj->n", err, np.linalg.inv(covariances(model, curv)), err)
    k = max(1.0, float(np.quantile(m, tail) / chi2.ppf(tail, 6)))
    return CovarianceModel(model.temperature * k, tuple(float(v) * np.sqrt(k) for v in model.floor_sigma))


def _max_likelihood(err: np.ndarray, curv: np.ndarray) -> CovarianceModel:
    """Maximum-likelihood temperature and floor sigmas of ``T * A^-1 + diag(floor^2)``."""
    inv = np.linalg.inv(curv)

    def covs(theta: np.ndarray) -> np.ndarray:
        return np.exp(theta[0]) * inv + np.diag(np.exp(2 * theta[1:]))

    start = np.concatenate([[np.log(median_temperature(err, curv))], np.log(err.std(axis=0) / 2 + 1e-3)])
    best = minimize(
        lambda th: gaussian_nll(err, covs(th)),
        start,
        method="Nelder-Mead",
        options={"maxiter": 4000, "xatol": 1e-4, "fatol": 1e-6},
    )
    return CovarianceModel(float(np.exp(best.x[0])), tuple(float(v) for v in np.exp(best.x[1:])))


def gaussian_nll(err: np.ndarray, covs: np.ndarray) -> float:
    """Mean negative log-likelihood of the errors (n, 6) under covariances (n, 6, 6)."""
    _, logdet = np.linalg.slogdet(covs)
    m = np.einsum("ni,nij,nj->n", err, np.linalg.inv(covs), err)
    return float(np.mean(0.5 * (m + logdet + 6 * np.log(2 * np.pi))))


def describe(
    err: np.ndarray,
    curv: np.ndarray,
    model: CovarianceModel,
    ml: CovarianceModel,
    alone: float,
    constant: np.ndarray,
    label: str,
) -> dict:
    covs = covariances(model, curv)
    m = np.einsum("ni,nij,nj->n", err, np.linalg.inv(covs), err)
    inside = {q: float(np.mean(m <= chi2.ppf(q, 6))) for q in LEVELS}
    sig = np.sqrt(np.einsum("nii->ni", covs))
    z = np.abs(err) / sig
    per = " ".join(
        f"{n} {np.mean(z[:, i] <= 1):.2f}/{np.mean(z[:, i] <= 2):.2f}" for i, n in enumerate(STATE_NAMES)
    )
    med_sig = " ".join(f"{n} {np.median(sig[:, i]):.2f}" for i, n in enumerate(STATE_NAMES))
    nll = gaussian_nll(err, covs)
    nll_ml = gaussian_nll(err, covariances(ml, curv))
    nll_a = gaussian_nll(err, alone * np.linalg.inv(curv))
    nll_c = gaussian_nll(err, np.broadcast_to(constant, covs.shape))
    shares = " ".join(f"{int(100 * q)}%:{share:.2f}" for q, share in inside.items())
    print(f"  {label}: n={len(err)} inside ellipsoid {shares}")
    print(f"    within 1/2 sigma: {per}")
    print(f"    median sigma: {med_sig}")
    print(
        f"    NLL per pose: fitted {nll:.2f}, before widening {nll_ml:.2f}, curvature alone {nll_a:.2f}, "
        f"one constant {nll_c:.2f}"
    )
    return {
        "n": len(err),
        "inside": {str(q): share for q, share in inside.items()},
        "nll": {"fitted": nll, "before_widening": nll_ml, "curvature_alone": nll_a, "constant": nll_c},
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fit-city", action="append", default=None)
    ap.add_argument("--check-city", action="append", default=None)
    ap.add_argument("--queries", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--check-seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=None)
    ap.add_argument("--write", action="store_true", help="save the fitted model into the package")
    args = ap.parse_args()
    fit_cities = calibration_cities_or_exit(args.fit_city, SHARED, "fit the covariance's temperature")
    check_cities = (
        args.check_city if args.check_city is not None else ([str(BERLIN)] if BERLIN.exists() else [])
    )

    def rows_of(cities: list[str], seed: int, conditions) -> dict[str, list[dict]]:
        return {
            cond: [
                r
                for c in cities
                for r in condition_rows(c, seed, args.queries, cond, args.workers, args.cache)
            ]
            for cond in conditions
        }

    models, checks = {}, {}
    for suffix, conditions in (("", CONDITIONS), ("/narrow", NARROW_CONDITIONS)):
        fit = rows_of(fit_cities, args.seed, conditions)
        check = rows_of(check_cities, args.check_seed, conditions) if check_cities else {}
        for variant in VARIANTS:
            key = variant + suffix
            err, curv = arrays([r for rows in fit.values() for r in rows], variant)
            if len(err) < 10:
                print(f"{key}: {len(err)} right poses, too few to fit", file=sys.stderr)
                return 1
            model, ml = fit_model(err, curv), fit_model(err, curv, tail=None)
            alone = median_temperature(err, curv)
            constant = np.cov(err.T)
            models[key] = model
            floor = " ".join(f"{n} {v:.3g}" for n, v in zip(STATE_NAMES, model.floor_sigma, strict=True))
            print(
                f"## {key}: temperature {model.temperature:.4g} (score units), floor sigma {floor}; "
                f"{len(err)} right poses (curvature alone: temperature {alone:.4g})"
            )
            fitted = (model, ml, alone, constant)
            for cond, rows in fit.items():
                describe(*arrays(rows, variant), *fitted, f"fit {cond}")
            for cond, rows in check.items():
                checks[f"{key} {cond}"] = describe(*arrays(rows, variant), *fitted, f"check {cond}")
                if suffix:  # what the wide model, which narrow views got before, says on the same poses
                    wide = models[variant]
                    describe(*arrays(rows, variant), wide, wide, alone, constant, f"check {cond}, wide model")
    if args.write:
        described = ", ".join(Path(c).stem for c in fit_cities)
        checked = ", ".join(Path(c).stem for c in check_cities)
        save_models(
            models,
            f"realistic, {described}, seed {args.seed}, {', '.join(CONDITIONS)} masks; "
            f"'/narrow': trained masks, focal_mm 28 (34 deg across)",
            {"on": f"realistic, {checked}, seed {args.check_seed}", **checks} if checks else None,
        )
        print("# written", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())

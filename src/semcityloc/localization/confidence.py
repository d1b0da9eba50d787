"""Calibrated acceptance: the probability that a localization is within 5 m and 5 deg of the truth.

Why: hand-set gates on single scores (``C_d <= 0.06``, building IoU >= 0.7) were calibrated on clean
inputs; with realistic depth and model errors they refuse correct poses and pass look-alikes. A
confidence that means something is a probability, estimated from all the evidence at once and fitted on
data with known answers, then checked on data it was not fitted on.

Model: logistic regression on standardised features of a ``LocalizationResult`` (``FEATURES``; a
feature that is missing, e.g. the hypothesis margin when only one hypothesis was refined, sits at its
mean), each weight constrained to the sign the evidence must have (more overlap, larger margins: more
confident; larger depth cost, wider particle spread, class boundaries farther from the map's
(``agreement.boundary_distance_px``): less), so the probability is monotone in every piece of evidence by
construction. Standardised values are clipped to +-``CLIP`` so that an input far
outside the fitted range cannot produce a confident extrapolation.

Fitting (``fit_logistic``, L-BFGS-B with those sign bounds and a small L2 penalty) is done by
``benchmarks/calibrate_confidence.py`` on the calibration cities only (Fürth and the generated city, the
realistic scenario with every segmentation quality and wider priors so that failures are seen); the
fitted models live in ``confidence_models.json`` beside this module, one per (kind, with depth): kind
``semantic`` is SemCityLoc's multi-class score, ``silhouette`` the one-class baseline's. The script
reports the expected calibration error and the risk-coverage curve on held-out data (Berlin).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from semcityloc.errors import ParameterError

MODELS_PATH = Path(__file__).with_name("confidence_models.json")
CLIP = 4.0
# Feature name -> the sign its weight must have (+1: more of it, more confident).
FEATURE_SIGNS: dict[str, int] = {
    "semantic": +1,
    "building_iou": +1,
    "hypothesis_margin": +1,
    "score_margin": +1,
    "depth_cost": -1,
    "depth_cost_agreed": -1,
    "spread_m": -1,
    "building_fraction": +1,
    "prior_distance": -1,
    "boundary_distance_px": -1,
}
DEPTH_FEATURES = ("depth_cost", "depth_cost_agreed")  # what only a query with depth has
FEATURES_DEPTH = tuple(FEATURE_SIGNS)
FEATURES_NO_DEPTH = tuple(f for f in FEATURE_SIGNS if f not in DEPTH_FEATURES)
# The fitted models saw one camera, 70 deg across (``benchmark.queries.zenmuse_l2_camera``). Narrower,
# a view holds fewer buildings and the probability overstates its confidence: accepted poses within
# 5 m / 5 deg on the calibration cities (generated / Fürth, 100 queries each) 98.0 / 100 % at 50 deg
# across, 96.9 / 100 % at 40, 92.8 / 98.0 % at 34 (``docs/benchmark.md``, "Other cameras and cities").
# A camera narrower than this gets a warning.
CALIBRATED_MIN_HFOV_DEG = 50.0
NARROW_VIEW_WARNING = "narrow field of view"
# The fitted models saw views 40-150 m above ground (``benchmark.queries``, realistic scenario): their
# span across at the mean depth of the map seen from the found pose (``view_span_m``; the mean, not the
# median, which jumps between roofs and ground where they share a view) was at least 55 m in 99 % of them
# (generated and Fürth, seed 0, 100 queries each: 1st percentiles 52 / 59 m). Closer (a flight 15-30 m
# above ground) or narrower, a view holds a few roofs and the probability overstates its confidence: of
# the accepted wrong poses on the calibration cities at 15-30 m above ground, 5 of 7 (generated) and 1
# of 2 (Fürth) spanned less than this; with a 34 deg camera 6 of 7 and 2 of 2 (``docs/benchmark.md``,
# "Other cameras and cities"). A view spanning less gets a warning.
CALIBRATED_MIN_SPAN_M = 55.0
CLOSE_VIEW_WARNING = "close view"


def features_of(result, names: tuple[str, ...]) -> np.ndarray:
    """(len(names),) float64 feature vector of a ``LocalizationResult`` (NaN where missing)."""
    conf = result.confidence
    values = []
    for name in names:
        if name == "semantic":
            v = result.semantic
        elif name == "depth_cost":
            v = result.depth_cost
        else:
            v = conf.get(name, float("nan"))
        v = float(v) if v is not None else float("nan")
        values.append(v if math.isfinite(v) else float("nan"))
    return np.array(values, dtype=np.float64)


@dataclass(frozen=True)
class ConfidenceModel:
    """A fitted logistic model (module docstring)."""

    kind: str
    with_depth: bool
    features: tuple[str, ...]
    mean: tuple[float, ...]
    scale: tuple[float, ...]
    weights: tuple[float, ...]
    bias: float
    fitted_on: str = ""
    samples: int = 0

    def standardise(self, X: np.ndarray) -> np.ndarray:
        """Features scaled as at fitting, NaN and inf as the mean, clipped at ±CLIP."""
        Z = (np.asarray(X, dtype=np.float64) - np.array(self.mean)) / np.array(self.scale)
        return np.clip(np.where(np.isfinite(Z), Z, 0.0), -CLIP, CLIP)

    def probability_of(self, X: np.ndarray) -> np.ndarray:
        """Probabilities of feature rows X (N, F) in ``features`` order."""
        z = self.standardise(np.atleast_2d(X)) @ np.array(self.weights) + self.bias
        return 1.0 / (1.0 + np.exp(-z))

    def probability(self, result) -> float:
        """The probability that ``result`` is right, from its features."""
        return float(self.probability_of(features_of(result, self.features)[None])[0])

    def as_dict(self) -> dict:
        """The fitted model as plain values, for the confidence-models JSON file."""
        return asdict(self)


def fit_logistic(
    X: np.ndarray,
    y: np.ndarray,
    features: tuple[str, ...],
    kind: str,
    with_depth: bool,
    l2: float = 1e-2,
    fitted_on: str = "",
) -> ConfidenceModel:
    """Sign-constrained, L2-penalised logistic regression of ``y`` (1 = within 5 m / 5 deg) on ``X``."""
    X = np.asarray(X, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != len(features) or len(X) != len(y):
        raise ParameterError(
            f"fit_logistic: X {X.shape} does not match {len(features)} features / {len(y)} labels"
        )
    if len(np.unique(y)) < 2:
        raise ParameterError("fit_logistic needs both correct and wrong examples")
    mean = np.nanmean(X, axis=0)
    scale = np.nanstd(X, axis=0)
    mean = np.where(np.isfinite(mean), mean, 0.0)
    scale = np.where(np.isfinite(scale) & (scale > 1e-12), scale, 1.0)
    Z = np.clip(np.where(np.isfinite((X - mean) / scale), (X - mean) / scale, 0.0), -CLIP, CLIP)
    n = len(y)

    def loss(theta):
        w, b = theta[:-1], theta[-1]
        z = Z @ w + b
        # log(1 + exp(z)) - y z, stably
        nll = np.sum(np.logaddexp(0.0, z) - y * z) / n
        p = 1.0 / (1.0 + np.exp(-z))
        grad_w = Z.T @ (p - y) / n + l2 * w
        grad_b = np.sum(p - y) / n
        return nll + 0.5 * l2 * float(w @ w), np.append(grad_w, grad_b)

    bounds = [(0.0, None) if FEATURE_SIGNS[f] > 0 else (None, 0.0) for f in features] + [(None, None)]
    res = minimize(loss, np.zeros(len(features) + 1), jac=True, method="L-BFGS-B", bounds=bounds)
    w, b = res.x[:-1], float(res.x[-1])
    return ConfidenceModel(
        kind=kind,
        with_depth=bool(with_depth),
        features=tuple(features),
        mean=tuple(float(v) for v in mean),
        scale=tuple(float(v) for v in scale),
        weights=tuple(float(v) for v in w),
        bias=b,
        fitted_on=fitted_on,
        samples=int(n),
    )


def calibration_error(p: np.ndarray, y: np.ndarray, bins: int = 10) -> float:
    """Expected calibration error: the mean |observed - predicted| share over equal-width probability
    bins, weighted by the bin's size."""
    p, y = np.asarray(p, dtype=np.float64), np.asarray(y, dtype=np.float64)
    if not len(p):
        return float("nan")
    idx = np.minimum((p * bins).astype(int), bins - 1)
    total = 0.0
    for b in range(bins):
        sel = idx == b
        if sel.any():
            total += sel.sum() * abs(y[sel].mean() - p[sel].mean())
    return float(total / len(p))


def risk_coverage(p: np.ndarray, y: np.ndarray) -> list[tuple[float, float, float]]:
    """(threshold, coverage, precision) for every distinct probability, most confident first: accepting
    the queries with probability >= threshold covers that share and is right that often."""
    p, y = np.asarray(p, dtype=np.float64), np.asarray(y, dtype=np.float64)
    order = np.argsort(-p, kind="stable")
    ps, ys = p[order], y[order]
    out = []
    right = 0.0
    for i in range(len(ps)):
        right += ys[i]
        if i == len(ps) - 1 or ps[i + 1] != ps[i]:
            out.append((float(ps[i]), (i + 1) / len(ps), right / (i + 1)))
    return out


def save_models(models: list[ConfidenceModel], path: Path = MODELS_PATH) -> None:
    """Write the fitted acceptance models to ``path`` (the package's ``confidence_models.json`` by default;
    ``calibrate_confidence.py --write``) and drop the loaded copy, so the next localization uses them.
    """
    data = {"models": [m.as_dict() for m in models]}
    path.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    _load.cache_clear()


@lru_cache(maxsize=4)
def _load(path: str) -> dict[tuple[str, bool], ConfidenceModel]:
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise ParameterError(
            f"{path}: no fitted confidence models (run benchmarks/calibrate_confidence.py)"
        ) from exc
    out = {}
    for m in data["models"]:
        m = {**m, "features": tuple(m["features"]), "mean": tuple(m["mean"]), "scale": tuple(m["scale"])}
        m["weights"] = tuple(m["weights"])
        model = ConfidenceModel(**m)
        out[(model.kind, model.with_depth)] = model
    return out


def load_models(path: Path = MODELS_PATH) -> list[ConfidenceModel]:
    """Every fitted model in ``path`` (the shipped ones by default)."""
    return list(_load(str(path)).values())


def confidence_model(kind: str, with_depth: bool, path: Path = MODELS_PATH) -> ConfidenceModel:
    """The fitted model for a localizer kind (``Localizer.confidence_kind``) with or without depth."""
    models = _load(str(path))
    key = (kind, bool(with_depth))
    if key not in models:
        raise ParameterError(
            f"no fitted confidence model for {kind!r} {'with' if with_depth else 'without'} depth in {path}"
        )
    return models[key]


def view_span_m(hfov_deg: float, mean_depth_m: float) -> float:
    """How much of the scene a view spans across (m): the width of its field of view at the mean depth
    of what it sees; 0 when it sees nothing."""
    if not mean_depth_m > 0.0:
        return 0.0
    return 2.0 * mean_depth_m * math.tan(math.radians(hfov_deg) / 2.0)


def is_close_view(span_m: float) -> bool:
    """The view spans less of the scene than the views the models were fitted on
    (``CALIBRATED_MIN_SPAN_M``); 0 (nothing seen) is not a span."""
    return 0.0 < span_m < CALIBRATED_MIN_SPAN_M


def close_view_warning(span_m: float, min_probability: float) -> str | None:
    """What a user should hear when a view spans less of the scene than the views the models were fitted
    on (``CALIBRATED_MIN_SPAN_M``): flown low, or through a narrow lens. ``min_probability``: what such a
    view is accepted at (``LocalizerConfig.min_confidence_close_view``)."""
    if not is_close_view(span_m):
        return None
    return (
        f"{CLOSE_VIEW_WARNING} (it spans {span_m:.0f} m across at the mean depth of the map it sees): the "
        f"acceptance probability was fitted on views spanning {CALIBRATED_MIN_SPAN_M:.0f}+ m (40-150 m above "
        f"ground) and overstates confidence here, so it is accepted only at {min_probability:g} or more; a "
        "look-alike can still pass (check the overlay)"
    )


def field_of_view_warning(hfov_deg: float) -> str | None:
    """What a user should hear when the camera is narrower than the views the models were fitted on."""
    if hfov_deg >= CALIBRATED_MIN_HFOV_DEG:
        return None
    return (
        f"{NARROW_VIEW_WARNING} ({hfov_deg:.0f} deg across): the acceptance probability was fitted on views "
        f"{CALIBRATED_MIN_HFOV_DEG:.0f}+ deg across and overstates confidence here; a look-alike can be "
        "accepted (state a tighter height prior if the drone has one, or accept at 0.9)"
    )

"""Benchmark metrics: recall at (metres, degrees) thresholds and mean / median pose errors.

Why one module: every table of the paper (and every run's ``summary.json``) must use the same
definitions, and the two threshold conventions in the literature must never be mixed up silently.

Definitions (errors from ``semcityloc.geometry.errors``):

- position error = distance between the estimated and true camera centres (metres);
- rotation error = full geodesic angle between the two orientations (degrees), not only yaw;
- a query counts as recalled at (m, deg) when BOTH errors are within the thresholds;
- recall is a percentage of ALL queries: a ``not_localized`` query has infinite error (a failure);
- ``recall_*`` uses ``<=`` (LoD-Loc v1's convention); ``recall_strict`` uses ``<``. They differ only for
  errors exactly at a threshold;
- mean / median yaw and position errors are over the localized queries; ``median_*_all`` counts
  ``not_localized`` queries as infinite error (so it is ``inf`` once half the queries failed).

NaN errors are treated like ``not_localized`` (infinite) so that a broken estimate never counts as a hit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from semcityloc.errors import ShapeError
from semcityloc.geometry.errors import center_error_m, rotation_error_deg, yaw_error_deg
from semcityloc.geometry.pose import Pose

THRESHOLDS: tuple[tuple[float, float], ...] = ((2.0, 2.0), (3.0, 3.0), (5.0, 5.0))

CONVENTION = (
    "recall_XmYdeg: percent of ALL queries (not_localized = failure, infinite error) whose camera-centre "
    "distance <= X m AND full rotation angle <= Y deg (LoD-Loc v1 convention, '<='); recall_strict: the "
    "same with '<' for both. mean/median yaw and xyz errors: over localized queries; median_*_all: "
    "not_localized counted as infinite error."
)


def threshold_key(max_m: float, max_deg: float) -> str:
    """``recall_2m2deg`` for (2, 2); non-integers keep their decimals (``recall_2.5m1deg``)."""

    def fmt(v: float) -> str:
        return str(int(v)) if float(v).is_integer() else repr(float(v))

    return f"recall_{fmt(max_m)}m{fmt(max_deg)}deg"


def _errors(values, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64).reshape(-1) if np.ndim(values) else None
    if arr is None:
        raise ShapeError(f"{name} must be a 1-D sequence of errors, got a scalar")
    if np.any(arr < 0):
        raise ShapeError(f"{name} holds negative errors")
    return np.where(np.isnan(arr), np.inf, arr)


def _pair(xyz_err, rot_err) -> tuple[np.ndarray, np.ndarray]:
    xyz, rot = _errors(xyz_err, "xyz_err"), _errors(rot_err, "rot_err")
    if xyz.shape != rot.shape:
        raise ShapeError(f"xyz_err and rot_err differ in length: {xyz.size} vs {rot.size}")
    return xyz, rot


def recall(xyz_err, rot_err, max_m: float, max_deg: float, strict: bool = False) -> float:
    """Percent of queries with position error <= ``max_m`` and rotation error <= ``max_deg``
    (``<`` for both when ``strict``). Infinite / NaN errors (not localized) are failures; 0 queries -> NaN.
    """
    xyz, rot = _pair(xyz_err, rot_err)
    if not xyz.size:
        return float("nan")
    hit = (xyz < max_m) & (rot < max_deg) if strict else (xyz <= max_m) & (rot <= max_deg)
    return float(100.0 * np.count_nonzero(hit) / xyz.size)


def recalls(
    xyz_err, rot_err, thresholds: Sequence[tuple[float, float]] = THRESHOLDS, strict: bool = False
) -> dict[str, float]:
    """``{threshold_key(m, deg): recall percent}`` for every threshold pair."""
    return {threshold_key(m, d): recall(xyz_err, rot_err, m, d, strict) for m, d in thresholds}


def _mean(a: np.ndarray) -> float:
    return float(np.mean(a)) if a.size else float("nan")


def _median(a: np.ndarray) -> float:
    return float(np.median(a)) if a.size else float("nan")


# Errors over ALL queries: a not-localized query (and any error beyond the cap) counts at the cap, so the
# mean says what a user gets whatever the localizer decided (the prior's own error is usually below it).
CAP_XYZ_M, CAP_ROT_DEG = 50.0, 45.0
# "Right": within 5 m AND 5 deg of the truth (<=). The event the calibrated acceptance probability is
# fitted to (``benchmarks/calibrate_confidence.py``), the acceptance precision (the share of accepted poses
# that are right), the report's reliability table and the kinds of miss all count it; one definition, so
# that the model and the report never disagree about what "right" means.
RIGHT_M, RIGHT_DEG = 5.0, 5.0


def is_right(err_m, err_deg):
    """Whether a pose with these errors (metres, degrees; scalars or arrays) is right: within ``RIGHT_M``
    AND ``RIGHT_DEG`` (``<=``). NaN errors are never right. A bool for scalars, a bool array otherwise."""
    out = np.less_equal(err_m, RIGHT_M) & np.less_equal(err_deg, RIGHT_DEG)
    return bool(out) if np.ndim(out) == 0 else out


def summarize_errors(
    xyz_err,
    rot_err,
    yaw_err,
    localized=None,
    thresholds: Sequence[tuple[float, float]] = THRESHOLDS,
) -> dict:
    """The error part of a benchmark summary (see the module docstring for every definition).

    Args:
        xyz_err, rot_err, yaw_err: per-query errors (metres, degrees, degrees); inf / NaN where the query
            was not localized.
        localized: per-query bool; default: the queries whose three errors are finite.
    Returns keys ``queries``, ``localized``, ``not_localized``, ``recall_*`` (``<=``), ``recall_strict``
    (dict, ``<``), ``mean_/median_`` ``xyz_m``, ``rot_deg``, ``yaw_deg`` (localized only),
    ``median_xyz_m_all`` / ``median_rot_deg_all`` / ``median_yaw_deg_all`` (not_localized = inf),
    ``mean_/median_`` ``xyz_m_capped`` / ``rot_deg_capped`` (every query, errors capped at ``CAP_XYZ_M`` /
    ``CAP_ROT_DEG``, not_localized at the cap), ``coverage`` (% of queries localized),
    ``acceptance_precision`` (% of localized queries within 5 m and 5 deg) and ``convention``.
    """
    xyz, rot = _pair(xyz_err, rot_err)
    yaw = _errors(yaw_err, "yaw_err")
    if yaw.shape != xyz.shape:
        raise ShapeError(f"yaw_err has {yaw.size} entries for {xyz.size} queries")
    finite = np.isfinite(xyz) & np.isfinite(rot) & np.isfinite(yaw)
    if localized is None:
        loc = finite
    else:
        loc = np.asarray(localized, dtype=bool).reshape(-1)
        if loc.shape != xyz.shape:
            raise ShapeError(f"localized has {loc.size} entries for {xyz.size} queries")
        loc = loc & finite
    # A query that is not localized has no estimate: infinite error whatever was passed for it.
    xyz_all, rot_all, yaw_all = (np.where(loc, a, np.inf) for a in (xyz, rot, yaw))
    out: dict = {
        "queries": int(xyz.size),
        "localized": int(np.count_nonzero(loc)),
        "not_localized": int(xyz.size - np.count_nonzero(loc)),
    }
    out.update(recalls(xyz_all, rot_all, thresholds, strict=False))
    out["recall_strict"] = recalls(xyz_all, rot_all, thresholds, strict=True)
    for name, a, a_all in (("xyz_m", xyz, xyz_all), ("rot_deg", rot, rot_all), ("yaw_deg", yaw, yaw_all)):
        out[f"mean_{name}"] = _mean(a[loc])
        out[f"median_{name}"] = _median(a[loc])
        out[f"median_{name}_all"] = _median(a_all)
    for name, a_all, cap in (("xyz_m", xyz_all, CAP_XYZ_M), ("rot_deg", rot_all, CAP_ROT_DEG)):
        capped = np.minimum(a_all, cap)
        out[f"mean_{name}_capped"] = _mean(capped)
        out[f"median_{name}_capped"] = _median(capped)
    good = loc & is_right(xyz_all, rot_all)
    n_loc = int(np.count_nonzero(loc))
    out["coverage"] = 100.0 * n_loc / xyz.size if xyz.size else float("nan")
    out["acceptance_precision"] = 100.0 * int(np.count_nonzero(good)) / n_loc if n_loc else float("nan")
    out["convention"] = CONVENTION
    return out


def pose_errors(est: Pose | None, gt: Pose) -> tuple[float, float, float]:
    """(position m, rotation deg, yaw deg) of one estimate; all ``inf`` when ``est`` is None."""
    if est is None:
        return math.inf, math.inf, math.inf
    for name, pose in (("est", est), ("gt", gt)):
        if isinstance(pose, Pose) and pose.batch_shape:
            raise ShapeError(f"pose_errors takes one pose each, got {name} of batch shape {pose.batch_shape}")
    return (
        float(center_error_m(est, gt)),
        float(rotation_error_deg(est, gt)),
        float(yaw_error_deg(est, gt)),
    )


def cumulative_curve(errors, grid) -> np.ndarray:
    """Percent of queries with error <= each value of ``grid`` (inf / NaN never count): the y values of a
    cumulative error plot."""
    e = _errors(errors, "errors")
    g = np.asarray(grid, dtype=np.float64).reshape(-1)
    if not e.size:
        return np.full(g.shape, np.nan)
    e = np.sort(e)
    return 100.0 * np.searchsorted(e, g, side="right") / e.size

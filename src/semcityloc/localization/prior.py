"""What the prior counts for besides the volume it spans (``cascade.search_volume``): a penalty on the
refinement's roll and pitch, and how far a found pose lies from it.

Why: the image alone barely tells a nadir camera's tilt from a sideways shift, the gimbal's IMU does, so
the cascade's refinement pays for leaving the prior's roll and pitch (``prior_term``, a ``refine.PriorTerm``
weighted by ``RefineConfig.prior_roll_pitch_weight``). And a pose found far out in the search volume is a
priori less likely to be right: its distance in sigmas (``prior_distance``) is an acceptance feature
(``confidence.FEATURE_SIGNS``). An accepted pose that contradicts a confident prior is told
(``prior_conflict_warning``): one of the two is wrong, and an RTK fix is rarely the one. A found roll/pitch
far outside the IMU's stated sigma (``roll_pitch_conflict``) says the IMU is worse than stated: the localizer
refines again with the sigma widened (``roll_pitch_wide_sigma``) and warns (``roll_pitch_conflict_warning``).
"""

from __future__ import annotations

import math

import numpy as np

from semcityloc.errors import parameter
from semcityloc.geometry.conventions import state_difference
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.uncertainty import PriorUncertainty
from semcityloc.localization.config import LocalizerConfig
from semcityloc.localization.refine import PriorTerm


def prior_term(prior_state: np.ndarray, cfg: LocalizerConfig, unc: PriorUncertainty) -> PriorTerm | None:
    """The prior's roll/pitch penalty of the cascade's refinement (None when switched off)."""
    if cfg.refine.prior_roll_pitch_weight <= 0 or unc.roll_pitch_deg <= 0:
        return None
    rp = unc.roll_pitch_deg
    sigma = np.array([np.inf, np.inf, np.inf, rp, rp, np.inf])
    return PriorTerm(prior_state, sigma, cfg.refine.prior_roll_pitch_weight)


def prior_distance(pose_local: Pose, prior_state: np.ndarray, unc: PriorUncertainty) -> float:
    """How many sigmas of the prior's uncertainty the pose is from the prior (Mahalanobis distance over
    x, y, z and yaw): a pose found far out in the search volume is a priori less likely to be right."""
    d = state_difference(pose_local.to_xyz_rpy(), prior_state)
    sig = np.array([unc.xy_m, unc.xy_m, unc.z_m, unc.yaw_deg])
    v = d[[0, 1, 2, 5]] / np.maximum(sig, 1e-6)
    return float(np.sqrt(np.sum(v * v)))


# An accepted pose this many sigmas of the stated position uncertainty, and this many metres, from the prior
# contradicts it (``prior_conflict_warning``). On Berlin seed 0 (default sigmas) no accepted pose does.
PRIOR_CONFLICT_SIGMA = 5.0
PRIOR_CONFLICT_M = 2.0


def prior_conflict_warning(pose_local: Pose, prior_state: np.ndarray, unc: PriorUncertainty) -> str | None:
    """A warning when an accepted pose lies farther from the prior's position than its stated uncertainty
    allows (``PRIOR_CONFLICT_SIGMA`` sigmas and ``PRIOR_CONFLICT_M`` m), else None. Why: the acceptance reads
    the distance as one feature among nine, so an image whose geometry is off (a focal length a few percent
    short: a 35 mm-equivalent EXIF value; a lens left out; the map) can move a camera metres from an RTK
    fix and still be accepted; the user should know the two disagree."""
    d = pose_local.center - np.asarray(prior_state[:3], dtype=np.float64)
    sig = np.maximum(np.array([unc.xy_m, unc.xy_m, unc.z_m]), 1e-6)
    sigmas, metres = float(np.linalg.norm(d / sig)), float(np.linalg.norm(d))
    if sigmas < PRIOR_CONFLICT_SIGMA or metres < PRIOR_CONFLICT_M:
        return None
    return (
        f"the pose lies {metres:.1f} m from the prior, {sigmas:.1f} sigma of its stated uncertainty (xy "
        f"{unc.xy_m:g} m, z {unc.z_m:g} m; {unc.source}): if the prior is right, the image's geometry "
        "is off (a focal length a few percent off, e.g. a 35 mm-equivalent EXIF value: calibrate it; a lens "
        f"left out; the map), else state the prior's real uncertainty ({parameter('prior_sigma')})"
    )


# The found roll/pitch departs from the IMU's by more than ``LocalizerConfig.roll_pitch_conflict_sigma``
# sigmas of its stated uncertainty and by at least this many degrees (``roll_pitch_conflict``): the IMU is
# worse than stated. The floor, set before measuring, is what the image alone fixes of a nadir view's tilt
# (stop 48: nadir views end 0.5-0.9 deg RMS off), so that a tightly stated IMU (an RTK gimbal, 0.1 deg)
# does not call the image's own noise a conflict.
ROLL_PITCH_CONFLICT_MIN_DEG = 1.0
# The second refinement's roll/pitch sigma is this many times the first pose's departure (the prior's
# pull shrinks a departure, so the truth lies farther out), capped at ``ROLL_PITCH_WIDE_MAX_DEG``.
ROLL_PITCH_WIDEN = 2.0
ROLL_PITCH_WIDE_MAX_DEG = 20.0
# The two refinements disagree by more than the acceptance tolerates (its probability is that of lying
# within 5 m / 5 deg of the truth): ``LocalizerConfig.roll_pitch_conflict_refuse`` refuses then
# (``result.REASON_ROLL_PITCH_CONFLICT``).
ROLL_PITCH_APART_M = 5.0
ROLL_PITCH_APART_DEG = 5.0
ROLL_PITCH_CONFLICT_WARNING = "roll/pitch prior conflict"


def roll_pitch_departure(state: np.ndarray, prior_state: np.ndarray) -> float:
    """How far (deg) a state's roll and pitch lie from the prior's: the norm of the two wrapped offsets."""
    d = state_difference(np.asarray(state, dtype=np.float64), prior_state)
    return float(np.hypot(d[3], d[4]))


def roll_pitch_conflict(
    state: np.ndarray, prior_state: np.ndarray, unc: PriorUncertainty, k_sigma: float
) -> bool:
    """Does a found state's roll/pitch depart from the prior's by more than ``k_sigma`` sigmas of its stated
    uncertainty (and ``ROLL_PITCH_CONFLICT_MIN_DEG``)? False when ``k_sigma`` is 0 (off) or no roll/pitch
    uncertainty is stated. Why: the refinement's roll/pitch penalty trusts the stated sigma; an IMU worse
    than stated pulls the pose onto a tilt-for-shift compromise metres off, which the acceptance, reading
    only the image, passes."""
    if not k_sigma > 0.0 or not unc.roll_pitch_deg > 0.0:
        return False
    departure = roll_pitch_departure(state, prior_state)
    return departure >= ROLL_PITCH_CONFLICT_MIN_DEG and departure > k_sigma * unc.roll_pitch_deg


def roll_pitch_wide_sigma(departure_deg: float, unc: PriorUncertainty) -> float:
    """The second refinement's roll/pitch sigma (deg) after a departure of ``departure_deg``."""
    return float(min(max(ROLL_PITCH_WIDEN * departure_deg, unc.roll_pitch_deg), ROLL_PITCH_WIDE_MAX_DEG))


def roll_pitch_take_gain(
    departure_deg: float, unc: PriorUncertainty, sure_sigma: float, unsure_gain: float
) -> float:
    """The image-score gain the second refinement's pose must exceed to be kept after a departure of
    ``departure_deg``: 0 beyond ``sure_sigma`` sigmas of the stated roll/pitch uncertainty, ``unsure_gain``
    within. Why: a departure the stated IMU itself gives now and then (a 2-3 sigma one, 12 % of views) is
    as often the map's fault (terrain, shifted or missing buildings) pulling the tilt as an IMU worse than
    stated; a widened sigma then trades tilt for shift on a gain of a few thousandths (stop 54)."""
    sigmas = departure_deg / max(unc.roll_pitch_deg, 1e-6)
    return 0.0 if sigmas > sure_sigma else float(unsure_gain)


def roll_pitch_conflict_warning(departure_deg: float, unc: PriorUncertainty, outcome: str) -> str:
    """What the user hears after a roll/pitch conflict: the departure in degrees and sigmas of the stated
    uncertainty, what the localizer did (``outcome``) and the uncertainty to state."""
    sigmas = departure_deg / max(unc.roll_pitch_deg, 1e-6)
    return (
        f"{ROLL_PITCH_CONFLICT_WARNING}: the image's roll/pitch departs {departure_deg:.1f} deg from the "
        f"prior's, {sigmas:.1f} sigma of its stated {unc.roll_pitch_deg:g} deg ({unc.source}): {outcome}. "
        "If the IMU is that far off, state its real uncertainty "
        f"({parameter('prior_sigma', f'rp={max(1, math.ceil(departure_deg))}')})"
    )

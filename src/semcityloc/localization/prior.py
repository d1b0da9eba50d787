"""What the prior counts for besides the volume it spans (``cascade.search_volume``): a penalty on the
refinement's roll and pitch, and how far a found pose lies from it.

Why: the image alone barely tells a nadir camera's tilt from a sideways shift, the gimbal's IMU does, so
the cascade's refinement pays for leaving the prior's roll and pitch (``prior_term``, a ``refine.PriorTerm``
weighted by ``RefineConfig.prior_roll_pitch_weight``). And a pose found far out in the search volume is a
priori less likely to be right: its distance in sigmas (``prior_distance``) is an acceptance feature
(``confidence.FEATURE_SIGNS``). An accepted pose that contradicts a confident prior is told
(``prior_conflict_warning``): one of the two is wrong, and an RTK fix is rarely the one.
"""

from __future__ import annotations

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

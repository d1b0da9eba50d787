"""What a localization returns: a pose and a status, never a silently wrong pose on empty evidence."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from semcityloc.errors import parameter
from semcityloc.geometry.pose import Pose
from semcityloc.geometry.pose_json import pose_to_dict
from semcityloc.localization.coarse import CostVolume
from semcityloc.localization.covariance import covariance_dict

LOCALIZED = "localized"
NOT_LOCALIZED = "not_localized"

# Reasons for NOT_LOCALIZED (stable strings: benchmark CSVs and scripts match on them).
REASON_NO_BUILDINGS_IN_QUERY = "query mask has no building pixels"
REASON_NO_GEOMETRY = "no model geometry within the search volume around the prior"
REASON_LOW_SCORE = "best score below threshold"
REASON_LOW_CONFIDENCE = "confidence below the acceptance probability"
# A prior no camera of the search can see the model from (``search_reach.MapLayout.prior_problem``).
REASON_PRIOR_UNDERGROUND = (
    "the prior is below the model's ground, farther than the search reaches up: is its height in the "
    "model's height system (geoid, take-off altitude)?"
)
REASON_PRIOR_TOO_HIGH = (
    "the prior is so far above the model's highest roof that no building would be seen: is its height in "
    "the model's height system (geoid, take-off altitude)?"
)
# The hint names each source's convention: the same pitch reads "down" in one and "level" in the other.
REASON_PRIOR_LOOKS_UP = (
    "the prior looks above the horizon from above every roof, so nothing of the model is in view: is its "
    "pitch in its source's convention? (a DJI photo's or a geotag CSV's gimbal pitch: -90 = straight down, "
    "0 = level; semcityloc's x,y,z,roll,pitch,yaw and ODM's geo.txt: 0 = straight down)"
)
# The refinement with the IMU's roll/pitch as stated and one with it widened found poses farther apart than
# the acceptance tolerates (``prior.roll_pitch_conflict``; ``LocalizerConfig.roll_pitch_conflict_refuse``).
REASON_ROLL_PITCH_CONFLICT = (
    "the IMU's roll/pitch conflicts with the image: state its uncertainty, "
    + parameter("prior_sigma", "rp=...")
)
# A pose as likely as another more than 5 m / 5 deg away (``lookalike.py``); the reason goes on to say where.
REASON_AMBIGUOUS = "ambiguous"
REASON_AT_EDGE = "best hypothesis on the edge of the search volume (state a larger prior uncertainty)"


@dataclass
class LocalizationResult:
    """Outcome of one query.

    ``pose_local`` and ``coarse_pose_local`` are in the model's local frame (world = ``model.origin`` +
    local; ``model.pose_to_world`` converts). Scores: ``semantic`` = mean per-class IoU (0..1, higher better),
    ``depth_cost`` = affine-invariant relative depth error (lower better), ``score`` = the combined
    ``lambda_1 * semantic - lambda_2 * depth_cost``. ``confidence``: ``score_margin`` (best coarse cell
    minus the best cell more than 2 grid steps away), ``spread_m`` / ``spread_deg`` (weighted spread of
    the final particles), ``building_iou`` (building-vs-rest overlap at the final pose),
    ``hypothesis_margin`` (final score of the winner minus the best other refined hypothesis),
    ``building_fraction`` (share of building pixels in the query), ``prior_distance`` (sigmas of the
    prior's uncertainty between the pose and the prior, x/y/z/yaw), ``boundary_distance_px`` (how far
    apart the class boundaries of query and map lie at the pose, ``agreement.py``), ``lookalike_margin``
    (the pose's final score minus that of the best pose more than 5 m / 5 deg away, refined as well,
    ``lookalike.py``; NaN when none; its pose in ``search["lookalike"]``), ``probability``
    (the calibrated probability of being within 5 m / 5 deg, ``confidence.py``). ``search``: the volume
    searched, its extensions and edges; ``hypotheses``: the refined hypotheses' final states and scores,
    best first. ``rejected_pose_local``: the pose that was found but not accepted (for diagnostics; never
    a result). ``covariance``: (6, 6) covariance of the found pose's (x, y, z, roll, pitch, yaw) in m and deg
    (``covariance.py``: the score's curvature at the pose, probed after the refinement, with a fitted
    temperature and floor; None without refinement, without a model fitted for the localizer's kind, or
    with ``refine.covariance_probe_px = 0``); ``score_curvature`` the curvature it came from.
    ``warnings``: what the localizer ignored and why (a depth map dropped as unusable), and what it
    noticed about the map at the found pose (buildings on one side only: ``agreement.py``; the shares are
    ``confidence["unmapped_building_share"]`` and ``confidence["unseen_building_share"]``), and where the
    acceptance probability reaches beyond the views it was fitted on (a narrow camera; a close view:
    ``confidence["view_span_m"]``, ``confidence.close_view_warning``).
    """

    status: str
    reason: str | None = None
    pose_local: Pose | None = None
    score: float = float("nan")
    semantic: float = float("nan")
    depth_cost: float = float("nan")
    confidence: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    counts: dict = field(default_factory=dict)
    cost_volume: CostVolume | None = None
    coarse_pose_local: Pose | None = None
    search: dict = field(default_factory=dict)
    hypotheses: list = field(default_factory=list)
    rejected_pose_local: Pose | None = None
    warnings: list[str] = field(default_factory=list)
    covariance: np.ndarray | None = None
    score_curvature: np.ndarray | None = None

    @property
    def found_pose_local(self) -> Pose | None:
        """The pose the search found, accepted or refused (diagnostics and risk-coverage; never a result)."""
        return self.pose_local if self.pose_local is not None else self.rejected_pose_local

    @property
    def localized(self) -> bool:
        """Whether a pose was accepted (``status == LOCALIZED``); otherwise ``pose_local`` is None and the
        found pose, if any, is ``rejected_pose_local``.
        """
        return self.status == LOCALIZED

    def finish(self, reason: str | None, t0: float) -> LocalizationResult:
        """This result closed with ``reason`` (not None: ``NOT_LOCALIZED`` for that reason) and its
        ``timings["total_s"]`` since ``t0`` (``time.perf_counter()``); returned, so a localizer ends with
        ``return result.finish(...)``."""
        self.reason = reason
        if reason is not None:
            self.status = NOT_LOCALIZED
        self.timings["total_s"] = time.perf_counter() - t0
        return self

    def to_dict(
        self, origin_world: np.ndarray, crs: str | None = None, crs_offset: np.ndarray | None = None
    ) -> dict:
        """JSON-ready record: status, reason, scores, confidence, timings, counts and, when localized,
        the pose in world (CRS) coordinates, ``world = origin + local`` in float64, written in the one
        layout of ``geometry.io.pose_to_dict`` (``frame``, ``origin``, ``position_local``, ``crs``,
        ``position``, ``roll`` / ``pitch`` / ``yaw``, ``world_from_cam``, ``cam_from_world``,
        ``qvec_wxyz`` / ``tvec``, ``convention``).

        Args:
            origin_world: float64 (3,) origin of the model the result's local poses are in
                (``model.origin``).
            crs: the name of the model's CRS, or None.
            crs_offset: the model's world frame is ``crs`` minus this (``run --offset``), or None.
        """
        out = {
            "status": self.status,
            "reason": self.reason,
            "score": self.score,
            "semantic_score": self.semantic,
            "depth_cost": self.depth_cost,
            "confidence": self.confidence,
            "timings_s": self.timings,
            "counts": self.counts,
            "search": self.search,
            "warnings": self.warnings,
        }
        if self.pose_local is not None:
            out.update(
                pose_to_dict(
                    pose_local=self.pose_local, origin_world=origin_world, crs=crs, crs_offset=crs_offset
                )
            )
            out.setdefault("crs", None)  # always present for a pose, as in earlier versions
            if self.covariance is not None:
                out["covariance"] = covariance_dict(self.covariance)
        return out

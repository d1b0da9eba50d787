"""What a localization returns: a pose and a status, never a silently wrong pose on empty evidence."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from semcityloc.geometry.pose import Pose
from semcityloc.localization.coarse import CostVolume

LOCALIZED = "localized"
NOT_LOCALIZED = "not_localized"

# Reasons for NOT_LOCALIZED (stable strings: benchmark CSVs and scripts match on them).
REASON_NO_BUILDINGS_IN_QUERY = "query mask has no building pixels"
REASON_NO_GEOMETRY = "no model geometry within the search volume around the prior"
REASON_LOW_SCORE = "best score below threshold"


@dataclass
class LocalizationResult:
    """Outcome of one query.

    ``pose`` is in the frame the prior was given in (world CRS coordinates by default); ``pose_local``
    in the model's local frame. Scores: ``semantic`` = mean per-class IoU (0..1, higher better),
    ``depth_cost`` = affine-invariant relative depth error (lower better), ``score`` = the combined
    ``lambda_1 * semantic - lambda_2 * depth_cost``. ``confidence``: ``score_margin`` (best coarse cell
    minus the best cell more than 2 grid steps away), ``spread_m`` / ``spread_deg`` (weighted spread of
    the final particles), ``building_iou`` (building-vs-rest overlap at the final pose).
    """

    status: str
    reason: str | None = None
    pose: Pose | None = None
    pose_local: Pose | None = None
    score: float = float("nan")
    semantic: float = float("nan")
    depth_cost: float = float("nan")
    confidence: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    counts: dict = field(default_factory=dict)
    cost_volume: CostVolume | None = None
    coarse_pose_local: Pose | None = None

    @property
    def localized(self) -> bool:
        return self.status == LOCALIZED

    def to_dict(self, origin: np.ndarray | None = None, crs: str | None = None) -> dict:
        out = {
            "status": self.status,
            "reason": self.reason,
            "score": self.score,
            "semantic_score": self.semantic,
            "depth_cost": self.depth_cost,
            "confidence": self.confidence,
            "timings_s": self.timings,
            "counts": self.counts,
        }
        if self.pose is not None:
            x, y, z, roll, pitch, yaw = self.pose.to_xyz_rpy()
            out.update(
                world_from_cam=self.pose.world_from_cam.tolist(),
                position=[x, y, z],
                roll=roll,
                pitch=pitch,
                yaw=yaw,
                crs=crs,
            )
        return out

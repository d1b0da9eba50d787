"""Where the map and the query disagree about whole buildings: a hint that the map is outdated.

At a pose, a connected building region of the query that the rendered map barely touches is a building the
map lacks (built after the survey), and a rendered building region that the query barely touches is one the
image does not show (torn down since, or hidden under trees). A wrong pose leaves such regions too, so the
hint names both causes. Regions are counted when less than ``MATCH_MIN_OVERLAP`` of them overlaps the
other side's buildings and they cover at least ``MIN_REGION_SHARE`` of the query's labelled pixels (smaller
ones are segmentation noise); the localizer warns from ``WARN_SHARE`` on.

Measured on the calibration cities (``docs/localization.md``, "Map changes in view"): at right poses the
warning for buildings the map lacks fired only where the simulated reality had such a building in view.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from semcityloc.classes import BUILDING_CLASSES, IGNORE

MATCH_MIN_OVERLAP = 0.2
MIN_REGION_SHARE = 0.005
WARN_SHARE = 0.02
# How the two warnings begin (``LocalizationResult.warnings``; scripts reading a results.csv match on them).
UNMAPPED_WARNING = "the image shows buildings the map lacks"
UNSEEN_WARNING = "the map has buildings the image does not show"
_EIGHT_CONNECTED = np.ones((3, 3), dtype=bool)


@dataclass(frozen=True)
class BuildingAgreement:
    """How the buildings of a render agree with the query's, as shares of the query's labelled pixels
    (neither background nor ``IGNORE``)."""

    building_iou: float  # building vs rest IoU (0 when neither side has a building)
    unmapped_share: float  # in query building regions the map lacks
    unseen_share: float  # in map building regions the query does not show

    def warnings(self) -> list[str]:
        """What a user should hear about the map at this pose (empty when the shares are small)."""
        out = []
        if self.unmapped_share >= WARN_SHARE:
            out.append(
                f"{UNMAPPED_WARNING} ({100 * self.unmapped_share:.0f} % of the labelled pixels at the found "
                "pose): the map may be outdated there, or the pose wrong"
            )
        if self.unseen_share >= WARN_SHARE:
            out.append(
                f"{UNSEEN_WARNING} ({100 * self.unseen_share:.0f} % of the labelled pixels at the found "
                "pose): demolished or hidden, or the pose wrong"
            )
        return out


def _lonely_share(regions: np.ndarray, other: np.ndarray, labelled: int) -> float:
    """Pixels of the connected regions of ``regions`` (bool 2D) that ``other`` barely covers and that are
    large enough to count, as a share of ``labelled``."""
    labels, n = ndimage.label(regions, _EIGHT_CONNECTED)
    if n == 0:
        return 0.0
    index = np.arange(1, n + 1)
    size = ndimage.sum_labels(regions, labels, index)
    covered = ndimage.sum_labels(other, labels, index)
    lonely = (covered < MATCH_MIN_OVERLAP * size) & (size >= MIN_REGION_SHARE * labelled)
    return float(size[lonely].sum() / labelled)


def building_agreement(query: np.ndarray, rendered: np.ndarray) -> BuildingAgreement:
    """Agreement of the query's labels (H, W) with a render's (H, W) at one pose; the query's background
    (0) and ``IGNORE`` pixels are left out of both."""
    query, rendered = np.asarray(query), np.asarray(rendered)
    if query.ndim != 2 or query.shape != rendered.shape:
        raise ValueError(f"query {query.shape} and render {rendered.shape} must be the same 2D shape")
    valid = (query != 0) & (query != IGNORE)
    labelled = int(np.count_nonzero(valid))
    if labelled == 0:
        return BuildingAgreement(0.0, 0.0, 0.0)
    q = np.isin(query, BUILDING_CLASSES) & valid
    r = np.isin(rendered, BUILDING_CLASSES) & valid
    union = np.count_nonzero(q | r)
    iou = float(np.count_nonzero(q & r) / union) if union else 0.0
    return BuildingAgreement(iou, _lonely_share(q, r, labelled), _lonely_share(r, q, labelled))

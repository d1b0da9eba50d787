"""Where the map and the query disagree about whole buildings or large parts of them: a hint that the map
is outdated.

At a pose, query building pixels that the rendered map does not cover are, in a blob, a building (or part
of a block) the map lacks: built after the survey, raised, extended. Rendered building pixels that the query
does not cover are, in a blob, one the image does not show: torn down, lowered, re-roofed, or hidden under
trees. A slightly wrong pose, a height error or eaves leave thin bands instead, which an opening that
removes bands up to ``BAND_PX`` pixels wide (at the refinement's resolution) takes away; blobs under
``MIN_REGION_SHARE`` of the query's labelled pixels are segmentation noise. The localizer warns from
``WARN_SHARE`` on. A wrong pose leaves blobs too, so the warning names both causes.

``agreed_depth_cost``: the depth cost on the pixels where query and render agree on building or not, an
acceptance feature (``confidence.FEATURE_SIGNS``) that a building changed since the survey does not inflate.

``boundary_distance_px``: how far apart the class boundaries of query and render lie, a median in pixels
(an acceptance feature too). The IoUs count areas, so a building the map lacks and a pose a few metres
off lower them alike; the boundaries that do exist on both sides lie on each other at a right pose
however many buildings changed (the median ignores the rest), and a few pixels apart at a wrong one.

Measured on the calibration cities and a held-out Berlin seed (``docs/localization.md``, "Map changes in
view", ``benchmarks/map_change_warnings.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from semcityloc.classes import BUILDING_CLASSES, IGNORE
from semcityloc.localization.scoring import robust_depth_cost

BAND_PX = 2
MIN_REGION_SHARE = 0.005
WARN_SHARE = 0.02
# How the two warnings begin (``LocalizationResult.warnings``; scripts reading a results.csv match on them).
UNMAPPED_WARNING = "the image shows buildings the map lacks"
UNSEEN_WARNING = "the map has buildings the image does not show"
_EIGHT_CONNECTED = np.ones((3, 3), dtype=bool)
_OPENING = np.ones((BAND_PX + 1, BAND_PX + 1), dtype=bool)


@dataclass(frozen=True)
class BuildingAgreement:
    """How the buildings of a render agree with the query's, as shares of the query's labelled pixels
    (neither background nor ``IGNORE``)."""

    building_iou: float  # building vs rest IoU (0 when neither side has a building)
    unmapped_share: float  # query building pixels in blobs the map does not cover
    unseen_share: float  # map building pixels in blobs the query does not cover

    def warnings(self) -> list[str]:
        """What a user should hear about the map at this pose (empty when the shares are small)."""
        out = []
        if self.unmapped_share >= WARN_SHARE:
            out.append(
                f"{UNMAPPED_WARNING} or parts of them ({100 * self.unmapped_share:.0f} % of the labelled "
                "pixels at the found pose): the map may be outdated there, or the pose wrong"
            )
        if self.unseen_share >= WARN_SHARE:
            out.append(
                f"{UNSEEN_WARNING} or parts of them ({100 * self.unseen_share:.0f} % of the labelled "
                "pixels at the found pose): demolished, changed or hidden, or the pose wrong"
            )
        return out


def _labelled(query: np.ndarray) -> np.ndarray:
    """bool, the query's shape: the pixels every measure here reads (neither background nor ``IGNORE``)."""
    return (query != 0) & (query != IGNORE)


def _same_2d(query: np.ndarray, rendered: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    query, rendered = np.asarray(query), np.asarray(rendered)
    if query.ndim != 2 or query.shape != rendered.shape:
        raise ValueError(f"query {query.shape} and render {rendered.shape} must be the same 2D shape")
    return query, rendered


def _uncovered_share(mine: np.ndarray, other: np.ndarray, labelled: int) -> float:
    """Pixels of ``mine`` (bool 2D) that ``other`` does not cover, in blobs wider than ``BAND_PX`` and of
    at least ``MIN_REGION_SHARE``, as a share of ``labelled``."""
    uncovered = ndimage.binary_opening(mine & ~other, _OPENING)
    labels, n = ndimage.label(uncovered, _EIGHT_CONNECTED)
    if n == 0:
        return 0.0
    size = ndimage.sum_labels(uncovered, labels, np.arange(1, n + 1))
    return float(size[size >= MIN_REGION_SHARE * labelled].sum() / labelled)


def building_agreement(query: np.ndarray, rendered: np.ndarray) -> BuildingAgreement:
    """Agreement of the query's labels (H, W) with a render's (H, W) at one pose; the query's background
    (0) and ``IGNORE`` pixels are left out of both."""
    query, rendered = _same_2d(query, rendered)
    valid = _labelled(query)
    labelled = int(np.count_nonzero(valid))
    if labelled == 0:
        return BuildingAgreement(0.0, 0.0, 0.0)
    q = np.isin(query, BUILDING_CLASSES) & valid
    r = np.isin(rendered, BUILDING_CLASSES) & valid
    union = np.count_nonzero(q | r)
    iou = float(np.count_nonzero(q & r) / union) if union else 0.0
    return BuildingAgreement(iou, _uncovered_share(q, r, labelled), _uncovered_share(r, q, labelled))


def _class_boundaries(labels: np.ndarray, labelled: np.ndarray) -> np.ndarray:
    """bool (H, W): the right / lower pixel of each horizontally / vertically adjacent labelled pair whose
    labels differ."""
    out = np.zeros(labels.shape, dtype=bool)
    out[:, 1:] |= (labels[:, 1:] != labels[:, :-1]) & labelled[:, 1:] & labelled[:, :-1]
    out[1:, :] |= (labels[1:, :] != labels[:-1, :]) & labelled[1:, :] & labelled[:-1, :]
    return out


def boundary_distance_px(query: np.ndarray, rendered: np.ndarray) -> float:
    """Symmetric median distance in pixels between the class boundaries of the query's labels and a
    render's (both (H, W), on the query's labelled pixels: neither background nor ``IGNORE``): the mean
    of the median distance from each query boundary pixel to the nearest render boundary pixel and the
    same the other way. NaN when either side has no boundary (no evidence, not a perfect fit)."""
    query, rendered = _same_2d(query, rendered)
    labelled = _labelled(query)
    in_query = _class_boundaries(query, labelled)
    in_render = _class_boundaries(rendered, labelled)
    if not in_query.any() or not in_render.any():
        return float("nan")
    to_render = ndimage.distance_transform_edt(~in_render)[in_query]
    to_query = ndimage.distance_transform_edt(~in_query)[in_render]
    return 0.5 * (float(np.median(to_render)) + float(np.median(to_query)))


def agreed_depth_cost(
    query: np.ndarray, query_depth: np.ndarray, rendered: np.ndarray, rendered_depth: np.ndarray, cap: float
) -> float:
    """The refinement's depth cost at one pose (``scoring.robust_depth_cost``) on the query's labelled
    pixels where query and render agree on building or not: a building gone or new since the survey then
    no longer reads as a depth error, while a wrong pose still does wherever its buildings line up by
    chance. All four arrays (H, W) or flat of one size; render depth +inf where nothing is hit."""
    query, rendered = np.asarray(query).reshape(-1), np.asarray(rendered).reshape(-1)
    query_depth, rendered_depth = np.asarray(query_depth).reshape(-1), np.asarray(rendered_depth).reshape(-1)
    if not query.shape == rendered.shape == query_depth.shape == rendered_depth.shape:
        raise ValueError(
            f"labels {query.shape} / {rendered.shape} and depths {query_depth.shape} / "
            f"{rendered_depth.shape} must be of one size"
        )
    agree = _labelled(query) & (np.isin(query, BUILDING_CLASSES) == np.isin(rendered, BUILDING_CLASSES))
    return robust_depth_cost(query_depth[agree], rendered_depth[agree], cap)

"""Score simulated segmentation presets the paper's way, on views shared by every preset.

Why: the realistic presets are calibrated to the paper's mIoU (trained 88 %, medium 78 %, zero-shot
32-37 %), and that mIoU is measured against the MAP's own labels projected at the true pose by the
automatic labelling rules (ignore pixels left out), pooled over the data set. Calibrating many preset
values needs the expensive part of a view (pose, reality render, ``ViewTruth``, map labels) computed
once and each preset scored on it in a fraction of the time (``benchmarks/calibrate_segmentation.py``,
``tests/test_seg_errors.py``).

``calibration_views`` draws the benchmark's own views (``QuerySimulator.query_with_truth``: pose and
camera distribution, rejected views skipped) and keeps, per view, the truth (``view_truth`` with the
query's own sun stream) and the map's labels; ``score_preset`` segments every view with the query's own
segmentation stream, folds windows / doors into wall on an LoD2 map (``fold_to_map_classes``) and returns
the pooled and per-image mIoU. With the same seed these are exactly the labels the benchmark's queries get.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from semcityloc.benchmark.perception_sim import (
    MIN_PRESENT_PIXELS,
    MIOU_CLASSES,
    SegPreset,
    simulate_segmentation,
)
from semcityloc.benchmark.queries import STREAM_SEG, STREAM_SUN, QueryConfig, QuerySimulator
from semcityloc.benchmark.seg_errors import ViewTruth, fold_to_map_classes, sun_direction, view_truth
from semcityloc.citymodel.model import CityModel
from semcityloc.classes import IGNORE, NUM_CLASSES
from semcityloc.perception.autolabel import auto_label
from semcityloc.perception.metrics import confusion, iou_per_class, mean_iou
from semcityloc.render import Renderer

__all__ = ["CalibrationView", "PresetScore", "calibration_views", "score_preset"]


@dataclass
class CalibrationView:
    """One accepted benchmark view: its query index, what it really contains and the map's labels."""

    index: int
    view: str  # "nadir" | "oblique"
    truth: ViewTruth
    map_labels: np.ndarray  # (H, W) uint8, IGNORE where the automatic labelling leaves a pixel out


@dataclass
class PresetScore:
    """The paper's mIoU of one preset over the views (percent)."""

    pooled: float  # mean IoU of the confusion summed over the views
    per_image: float  # mean over the views of each view's mIoU (classes with >= MIN_PRESENT_PIXELS)
    iou: np.ndarray  # (NUM_CLASSES,) pooled per-class IoU (percent, NaN = absent)
    confusion: np.ndarray  # (C, C) int64 [map label, predicted], pooled


def calibration_views(map_model: CityModel, config: QueryConfig, reality_model: CityModel | None = None):
    """The accepted views among ``config.queries`` benchmark queries (module docstring) and the map's
    classes: ``(views, map_classes)``."""
    # The pose, reality render and truth are all a view needs: no query segmentation, depth or scoring.
    cheap = dataclasses.replace(config, seg_model="blobs", depth=False, score_against_map=False)
    sim = QuerySimulator(map_model, cheap, reality_model)
    map_renderer = Renderer(map_model, engine="numba")
    views = []
    for i in range(config.queries):
        simulated = sim.query_with_truth(i)
        query = simulated.query
        if not query.meta.get("accepted", True):
            continue
        pose = query.true_pose_local
        sun = sun_direction(np.random.default_rng([config.seed, i, STREAM_SUN]))
        truth = view_truth(sim.reality, sim.camera, pose, sun)
        labels = auto_label(map_model, sim.camera, map_model.pose_to_world(pose), renderer=map_renderer)
        views.append(CalibrationView(i, str(query.meta["view"]), truth, labels))
    return views, np.unique(map_model.classes)


def score_preset(
    views: list[CalibrationView], map_classes: np.ndarray, preset: SegPreset | None, seed: int
) -> PresetScore:
    """Pooled and per-image mIoU of ``preset`` (``None``: a perfect segmentation of the reality with trees
    and cars labelled as what is behind them, the ceiling the reality's differences from the map leave)
    against the map's labels; ``seed`` is the run seed the views were drawn with."""
    pooled = np.zeros((NUM_CLASSES, NUM_CLASSES), dtype=np.int64)
    per_image = []
    for v in views:
        if preset is None:
            pred = np.where(v.truth.occluder, v.truth.behind, v.truth.labels).astype(np.uint8)
        else:
            rng = np.random.default_rng([seed, v.index, STREAM_SEG])
            pred = simulate_segmentation(v.truth.labels, preset, rng, truth=v.truth)
        pred = fold_to_map_classes(pred, map_classes)
        keep = v.map_labels != IGNORE
        conf = confusion(pred[keep], v.map_labels[keep], NUM_CLASSES)
        pooled += conf
        per_image.append(
            mean_iou(conf, classes=MIOU_CLASSES, min_pixels=MIN_PRESENT_PIXELS, percent_of_mean=True)
        )
    return PresetScore(
        pooled=float(mean_iou(pooled, classes=MIOU_CLASSES, min_pixels=1, percent_of_mean=True)),
        per_image=float(np.nanmean(per_image)) if per_image else float("nan"),
        iou=iou_per_class(pooled),
        confusion=pooled,
    )

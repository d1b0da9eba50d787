"""Segmentation scores: a confusion matrix and its mean IoU (training logs, the benchmark's query mIoU).

The mean runs over the classes that occur in the ground truth (a class never present has no defined
IoU), optionally only over some classes and only those with at least ``min_pixels`` ground-truth pixels;
pixels labelled IGNORE (255) do not count. Values are percentages.
"""

from __future__ import annotations

import numpy as np

from semcityloc.classes import IGNORE


def confusion(pred: np.ndarray, gt: np.ndarray, num_classes: int) -> np.ndarray:
    """(num_classes, num_classes) int64 counts, rows = ground truth, columns = prediction."""
    pred = np.asarray(pred).reshape(-1).astype(np.int64)
    gt = np.asarray(gt).reshape(-1).astype(np.int64)
    keep = (gt != IGNORE) & (gt >= 0) & (gt < num_classes) & (pred >= 0) & (pred < num_classes)
    idx = gt[keep] * num_classes + pred[keep]
    return np.bincount(idx, minlength=num_classes * num_classes).reshape(num_classes, num_classes)


def iou_per_class(conf: np.ndarray) -> np.ndarray:
    """IoU (%) per class; NaN for classes absent from the ground truth."""
    conf = np.asarray(conf, dtype=np.float64)
    tp = np.diag(conf)
    gt = conf.sum(1)
    union = gt + conf.sum(0) - tp
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = 100.0 * tp / union
    iou[gt == 0] = np.nan
    return iou


def mean_iou(
    conf: np.ndarray,
    classes: tuple[int, ...] | None = None,
    min_pixels: int = 1,
    percent_of_mean: bool = False,
) -> float:
    """Mean IoU (%) over the classes present in the ground truth (NaN when none is).

    ``classes``: the class ids that take part (default: every row of ``conf``); a class is present when
    it has at least ``min_pixels`` (at least 1) ground-truth pixels. The two callers round differently
    and both write their numbers to files, so the order is a parameter: the training log averages the
    per-class percentages (``iou_per_class``, default); the benchmark's query mIoU
    (``percent_of_mean=True``) is 100 x the mean of the per-class ratios.
    """
    conf = np.asarray(conf, dtype=np.float64)
    present = conf.sum(1) >= max(int(min_pixels), 1)
    if classes is not None:
        chosen = np.zeros(len(conf), dtype=bool)
        chosen[list(classes)] = True
        present &= chosen
    if not present.any():
        return float("nan")
    if percent_of_mean:
        tp = np.diag(conf)[present]
        union = conf.sum(1)[present] + conf.sum(0)[present] - tp
        return 100.0 * float(np.mean(tp / union))
    iou = iou_per_class(conf)
    iou[~present] = np.nan
    return float(np.nanmean(iou))


def pixel_accuracy(conf: np.ndarray) -> float:
    """The share of correctly labelled pixels in a confusion matrix, in percent (NaN for an empty one);
    reported beside mIoU in training logs.
    """
    conf = np.asarray(conf, dtype=np.float64)
    total = conf.sum()
    return float(100.0 * np.trace(conf) / total) if total else float("nan")

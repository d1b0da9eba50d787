"""Segmentation scores for training logs: a confusion matrix over a whole split and its mean IoU.

The mean runs over the classes that occur in the ground truth of the split (a class never present has no
defined IoU); pixels labelled IGNORE (255) do not count. Values are percentages.
"""

from __future__ import annotations

import numpy as np

from semcityloc.perception.base import IGNORE


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


def mean_iou(conf: np.ndarray) -> float:
    """Mean IoU (%) over the classes present in the ground truth (NaN when none is)."""
    iou = iou_per_class(conf)
    return float(np.nanmean(iou)) if np.any(np.isfinite(iou)) else float("nan")


def pixel_accuracy(conf: np.ndarray) -> float:
    conf = np.asarray(conf, dtype=np.float64)
    total = conf.sum()
    return float(100.0 * np.trace(conf) / total) if total else float("nan")

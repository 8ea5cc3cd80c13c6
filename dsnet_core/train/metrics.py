"""Validation metrics during training: a confusion-matrix mIoU (classes 1..C-1) and offset error."""

from __future__ import annotations

import numpy as np


class ConfusionMeter:
    """Accumulates a ``(C, C)`` confusion matrix (rows = ground truth) over points with gt ≠ 0."""

    def __init__(self, num_classes: int) -> None:
        self.num_classes = num_classes
        self.conf = np.zeros((num_classes, num_classes), np.int64)

    def add(self, pred: np.ndarray, gt: np.ndarray) -> None:
        keep = gt != 0
        idx = gt[keep].astype(np.int64) * self.num_classes + pred[keep].astype(np.int64)
        self.conf += np.bincount(idx, minlength=self.num_classes**2).reshape(self.conf.shape)

    def iou(self) -> np.ndarray:
        """``(C,)`` IoU per class; NaN for classes absent from both prediction and truth; [0] is NaN."""
        tp = np.diag(self.conf).astype(np.float64)
        union = self.conf.sum(0) + self.conf.sum(1) - tp
        with np.errstate(invalid="ignore", divide="ignore"):
            iou = np.where(union > 0, tp / union, np.nan)
        iou[0] = np.nan
        return iou

    def miou(self) -> float:
        """Mean IoU over classes present in ground truth or prediction (ignoring class 0)."""
        iou = self.iou()
        return float(np.nanmean(iou)) if np.isfinite(iou).any() else float("nan")

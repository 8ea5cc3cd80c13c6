"""Frame-level confidence of a labelled frame, with or without ground truth.

Four terms, each in [0, 1] (1 = nothing suspicious), and their product as the frame's score:

- ``semantic``: mean over the frame's points of the winning class's softmax probability;
- ``agreement``: over the frame's instances, the point-weighted mean fraction of an instance's points
  whose semantic prediction is the instance's fused class (DS-Net's fusion vote; 1 without instances);
- ``size``: one minus the fraction of instances smaller than ``min_points`` points (fragments and
  spurious clusters; 1 without instances);
- ``stitch``: mean over the frame's tracks of their weakest link IoU between overlapping volumes
  (1 for single-scan runs or frames without linked tracks).

The product ranks a frame low when any one of them is low; the review export takes the lowest.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

TERMS = ("semantic", "agreement", "size", "stitch")
MIN_INSTANCE_POINTS = 30
"""Instances smaller than this are fragments or spurious clusters: they lower a frame's ``size`` term
and are not listed one by one in a review queue."""


@dataclass(frozen=True)
class FrameConfidence:
    """One frame's confidence terms and score (all float in [0, 1]), and its instance count."""

    semantic: float
    agreement: float
    size: float
    stitch: float
    score: float
    n_instances: int

    def to_dict(self) -> dict:
        return asdict(self)


def frame_confidence(
    max_prob: np.ndarray,
    instance_points: np.ndarray,
    instance_agreement: np.ndarray,
    link_iou: np.ndarray | None = None,
    min_points: int = MIN_INSTANCE_POINTS,
) -> FrameConfidence:
    """Confidence of one frame.

    Args:
        max_prob: float ``(N,)`` winning-class probability of each point (NaN entries ignored).
        instance_points: int ``(K,)`` points of each instance in this frame.
        instance_agreement: float ``(K,)`` fraction of each instance's points predicted as its class.
        link_iou: float ``(T,)`` weakest stitching IoU of each track seen in this frame (NaN for a
            track that was never linked: ignored); None or empty for single-scan runs.
        min_points: instances smaller than this count as suspicious.

    Raises:
        ValueError: mismatched instance arrays.
    """
    pts = np.asarray(instance_points, dtype=np.float64)
    agree = np.asarray(instance_agreement, dtype=np.float64)
    if pts.shape != agree.shape:
        raise ValueError(f"instance_points {pts.shape} and instance_agreement {agree.shape} differ")
    probs = np.asarray(max_prob, dtype=np.float64)
    probs = probs[np.isfinite(probs)]
    semantic = float(np.clip(probs.mean(), 0.0, 1.0)) if probs.size else 1.0
    k = int(pts.size)
    agreement = float(np.clip((agree * pts).sum() / pts.sum(), 0.0, 1.0)) if k and pts.sum() > 0 else 1.0
    size = 1.0 - float((pts < min_points).mean()) if k else 1.0
    ious = np.asarray(link_iou if link_iou is not None else [], dtype=np.float64)
    ious = ious[np.isfinite(ious)]
    stitch = float(np.clip(ious.mean(), 0.0, 1.0)) if ious.size else 1.0
    return FrameConfidence(semantic, agreement, size, stitch, semantic * agreement * size * stitch, k)

"""Class-balanced pseudo-label selection.

A teacher's refined labels become training targets only where they are confident *for their
class*: each class's threshold is the confidence above which its ``keep`` most confident share of
(consistent) points lies (a per-class quantile, as in class-balanced self-training, CBST), clipped
to ``[min_confidence, max_confidence]``. A single global threshold keeps mostly road and
vegetation, the classes a model is surest of, and drowns the rare ones; per-class quantiles keep
the same share of every class.

Confidences are the teacher's probabilities of the refined class, quantised as the store keeps
them (``q / 255``, uint8), so the histograms and thresholds are integers: exact, independent of
the order frames are added in and of the CPU.

Instance targets (offsets to centres) come only from instances whose track is consistent
(:mod:`dsnet_core.adapt.consistency`) and of whose points in the frame at least
``instance_share`` pass their class's threshold; such an instance is kept whole. Every other
point is ignored (class 0, no instance).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dsnet_core.errors import ConfigError

LEVELS = 256
"""Confidence levels: probabilities quantised to ``q / 255``."""
NONE = LEVELS
"""The threshold of a class nothing is selected of (no candidate points, or the ignore class)."""


@dataclass(frozen=True)
class SelectionParams:
    """What makes a refined label a pseudo-label.

    Attributes:
        keep: each class's most confident share of its consistent points (the per-class quantile).
        min_confidence, max_confidence: bounds of every class's threshold (probabilities): a class
            the teacher is sure of keeps all points above ``max_confidence``; none goes below
            ``min_confidence`` however unsure the teacher is of it.
        voxel: edge of the world voxels of the consistency vote (metres).
        min_share: share of a voxel's per-frame labels (or of a track's points) that must agree
            with the refined class.
        min_track_frames: frames a track must be seen in to be consistent.
        instance_share: share of an instance's points in a frame that must pass their class's
            threshold for it to be an instance target.
    """

    keep: float = 0.5
    min_confidence: float = 0.3
    max_confidence: float = 0.9
    voxel: float = 0.5
    min_share: float = 0.6
    min_track_frames: int = 2
    instance_share: float = 0.5

    def __post_init__(self) -> None:
        checks = {
            "keep": 0.0 < self.keep <= 1.0,
            "min_confidence": 0.0 <= self.min_confidence <= self.max_confidence,
            "max_confidence": self.max_confidence <= 1.0,
            "voxel": self.voxel > 0.0,
            "min_share": 0.0 <= self.min_share <= 1.0,
            "min_track_frames": self.min_track_frames >= 1,
            "instance_share": 0.0 <= self.instance_share <= 1.0,
        }
        bad = [f"{k}={getattr(self, k)}" for k, ok in checks.items() if not ok]
        if bad:
            raise ConfigError(
                f"pseudo-label selection: bad {', '.join(bad)} (want 0 < keep ≤ 1, "
                "0 ≤ min_confidence ≤ max_confidence ≤ 1, voxel > 0, shares in [0, 1], min_track_frames ≥ 1)"
            )


class ConfidenceHistogram:
    """Per class, how many consistent points have each quantised confidence; its quantiles are the
    class thresholds. Sums of integer counts: the order of :meth:`add` calls does not matter.

    Args:
        num_classes: C, train ids 0..C-1 (0 = ignore).
    """

    def __init__(self, num_classes: int) -> None:
        self.counts = np.zeros((num_classes, LEVELS), np.int64)

    def add(self, sem: np.ndarray, conf: np.ndarray, mask: np.ndarray | None = None) -> None:
        """Count points.

        Args:
            sem: ``(N,) int64`` refined train ids.
            conf: ``(N,) uint8`` the teacher's probability of ``sem`` (``q / 255``).
            mask: ``(N,) bool`` the points to count (default all).
        """
        sem, conf = np.asarray(sem, np.int64), np.asarray(conf, np.int64)
        if mask is not None:
            sem, conf = sem[mask], conf[mask]
        idx = sem * LEVELS + conf
        self.counts += np.bincount(idx, minlength=self.counts.size).reshape(self.counts.shape)

    def merge(self, other: ConfidenceHistogram) -> None:
        self.counts += other.counts

    def thresholds(self, params: SelectionParams) -> np.ndarray:
        """``(C,) int64`` per class: the largest level ``t`` with at least ``keep`` of the class's
        counted points at ``t`` or above, clipped to the confidence bounds; :data:`NONE` for class 0
        and classes without points."""
        lo = math.ceil(params.min_confidence * (LEVELS - 1) - 1e-9)
        hi = math.floor(params.max_confidence * (LEVELS - 1) + 1e-9)
        out = np.full(self.counts.shape[0], NONE, np.int64)
        for c in range(1, self.counts.shape[0]):
            n = int(self.counts[c].sum())
            if n == 0:
                continue
            tail = np.cumsum(self.counts[c, ::-1])[::-1]  # tail[t]: points with level ≥ t
            need = math.ceil(params.keep * n - 1e-9)
            t = int(np.flatnonzero(tail >= need).max())
            out[c] = min(max(t, lo), hi)
        return out


def select_frame(
    sem: np.ndarray,
    inst: np.ndarray,
    conf: np.ndarray,
    consistent: np.ndarray,
    thresholds: np.ndarray,
    params: SelectionParams,
) -> tuple[np.ndarray, np.ndarray]:
    """One frame's pseudo-labels.

    Args:
        sem: ``(N,) int64`` refined train ids.
        inst: ``(N,) int64`` refined sequence-wide instance ids (0 = none).
        conf: ``(N,) uint8`` the teacher's probability of ``sem``.
        consistent: ``(N,) bool`` the points whose voxel (no instance) or track (instance) agrees
            (:func:`dsnet_core.adapt.consistency.frame_consistency`).
        thresholds: ``(C,)`` from :meth:`ConfidenceHistogram.thresholds`.

    Returns:
        ``(sem, inst)`` pseudo-labels, both ``(N,) int64``: the refined class where selected, else 0;
        the instance id on the points of instance targets, else 0.
    """
    sem, inst = np.asarray(sem, np.int64), np.asarray(inst, np.int64)
    passes = (sem > 0) & (np.asarray(conf, np.int64) >= thresholds[sem])
    point_ok = passes & consistent
    target = np.zeros(sem.shape, bool)
    tracked = inst > 0
    if tracked.any():
        _, inv = np.unique(inst[tracked], return_inverse=True)
        share = np.bincount(inv, weights=passes[tracked]) / np.bincount(inv)
        track_ok = np.bincount(inv, weights=consistent[tracked]) > 0  # consistent is per track
        whole = (share >= params.instance_share) & track_ok
        target[tracked] = whole[inv] & (sem[tracked] > 0)
        point_ok |= target
    return np.where(point_ok, sem, 0), np.where(target, inst, 0)

"""What a round of pseudo-labels looks like, for the model card: coverage per class, the thresholds,
instances kept, the teacher's confidence histogram, agreement with the previous round and, where
the log happens to carry ground truth, precision per class (recorded, never used for training).
"""

from __future__ import annotations

import numpy as np

from dsnet_core.adapt.selection import LEVELS, NONE

HIST_BINS = 20
"""Bins of the confidence histogram the card records (0.05 wide)."""


class SelectionStats:
    """Integer counts over every frame of a round (order-independent).

    Args:
        num_classes: C.
    """

    def __init__(self, num_classes: int) -> None:
        c = num_classes
        self.c = c
        self.candidates = np.zeros(c, np.int64)  # refined points per class
        self.consistent = np.zeros(c, np.int64)
        self.selected = np.zeros(c, np.int64)
        self.gt_scored = np.zeros(c, np.int64)  # selected points with a ground-truth class
        self.gt_correct = np.zeros(c, np.int64)
        self.gt_frames = 0
        self.instances = np.zeros(2, np.int64)  # (instances seen, instance targets) per frame
        self.hist = np.zeros(HIST_BINS, np.int64)
        self.agree = np.zeros(2, np.int64)  # (points selected in both rounds, with the same class)
        self.frames = 0
        self.points = 0

    def add(
        self,
        sem: np.ndarray,
        inst: np.ndarray,
        conf: np.ndarray,
        consistent: np.ndarray,
        pseudo_sem: np.ndarray,
        pseudo_inst: np.ndarray,
        gt_sem: np.ndarray | None = None,
        previous: np.ndarray | None = None,
    ) -> None:
        """One frame.

        Args:
            sem, inst: ``(N,) int64`` refined labels; conf: ``(N,) uint8``; consistent: ``(N,) bool``.
            pseudo_sem, pseudo_inst: ``(N,) int64`` the frame's pseudo-labels.
            gt_sem: ``(N,) int64`` ground-truth train ids when the log has them (scoring only).
            previous: ``(N,) int64`` the previous round's pseudo classes of the same points.
        """
        c = self.c
        self.frames += 1
        self.points += int(sem.size)
        self.candidates += np.bincount(sem, minlength=c)[:c]
        self.consistent += np.bincount(sem[consistent], minlength=c)[:c]
        chosen = pseudo_sem > 0
        self.selected += np.bincount(pseudo_sem[chosen], minlength=c)[:c]
        self.hist += np.bincount(
            np.minimum(conf.astype(np.int64) * HIST_BINS // LEVELS, HIST_BINS - 1), minlength=HIST_BINS
        )
        self.instances += [np.unique(inst[inst > 0]).size, np.unique(pseudo_inst[pseudo_inst > 0]).size]
        if gt_sem is not None:
            self.gt_frames += 1
            scored = chosen & (gt_sem > 0)
            self.gt_scored += np.bincount(pseudo_sem[scored], minlength=c)[:c]
            right = scored & (gt_sem == pseudo_sem)
            self.gt_correct += np.bincount(pseudo_sem[right], minlength=c)[:c]
        if previous is not None:
            both = chosen & (previous > 0)
            self.agree += [int(both.sum()), int((both & (previous == pseudo_sem)).sum())]

    def record(self, names: tuple[str, ...], thresholds: np.ndarray) -> dict:
        """The card's record of the round: per class name, coverage (selected / refined points),
        consistent share, threshold (probability) and, with ground truth, precision."""

        def per_class(num: np.ndarray, den: np.ndarray) -> dict[str, float]:
            return {names[k]: round(float(num[k] / den[k]), 4) for k in range(1, self.c) if den[k] > 0}

        out = {
            "frames": self.frames,
            "points": self.points,
            "selected": int(self.selected.sum()),
            "coverage": round(float(self.selected.sum() / max(self.points, 1)), 4),
            "coverage_per_class": per_class(self.selected, self.candidates),
            "consistent_per_class": per_class(self.consistent, self.candidates),
            "refined_points_per_class": {
                names[k]: int(self.candidates[k]) for k in range(1, self.c) if self.candidates[k]
            },
            "thresholds": {
                names[k]: round(int(t) / (LEVELS - 1), 4)
                for k, t in enumerate(thresholds)
                if k > 0 and t != NONE
            },
            "instances": int(self.instances[0]),
            "instance_targets": int(self.instances[1]),
            "confidence_histogram": self.hist.tolist(),
        }
        if self.agree[0]:
            out["agreement_with_previous_round"] = round(float(self.agree[1] / self.agree[0]), 4)
        if self.gt_frames and self.gt_scored.sum():
            out["precision_frames"] = self.gt_frames
            out["precision_per_class"] = per_class(self.gt_correct, self.gt_scored)
            out["precision"] = round(float(self.gt_correct.sum() / max(self.gt_scored.sum(), 1)), 4)
        return out

"""A minimal PQ^Th accumulator for the shifting tests and benchmarks (SemanticKITTI rules: a match
is IoU > 0.5 within a class; unmatched segments count as FP/FN only from ``min_points`` points).

A stand-in until the project's scorer (``dsnet_core.metrics``) lands on main; averages over the
thing classes present in the ground truth.
"""

from __future__ import annotations

import numpy as np


class ThingPQ:
    def __init__(self, thing_classes=range(1, 9), min_points: int = 50) -> None:
        self.classes = list(thing_classes)
        self.min_points = min_points
        self.iou = dict.fromkeys(self.classes, 0.0)
        self.tp = dict.fromkeys(self.classes, 0)
        self.fp = dict.fromkeys(self.classes, 0)
        self.fn = dict.fromkeys(self.classes, 0)
        self.seen: set[int] = set()

    def add(self, gt_sem, gt_inst, pred_sem, pred_inst) -> None:
        for c in self.classes:
            g = np.where(gt_sem == c, gt_inst + 1, 0)
            p = np.where(pred_sem == c, pred_inst + 1, 0)
            gid, gcount = np.unique(g[g > 0], return_counts=True)
            pid, pcount = np.unique(p[p > 0], return_counts=True)
            if gid.size:
                self.seen.add(c)
            both = (g > 0) & (p > 0)
            pairs, inter = np.unique(np.stack([g[both], p[both]], 1), axis=0, return_counts=True)
            gm = np.zeros(gid.size, bool)
            pm = np.zeros(pid.size, bool)
            for (a, b), n in zip(pairs, inter, strict=True):
                ia, ib = np.searchsorted(gid, a), np.searchsorted(pid, b)
                iou = n / (gcount[ia] + pcount[ib] - n)
                if iou > 0.5:
                    gm[ia] = pm[ib] = True
                    self.tp[c] += 1
                    self.iou[c] += iou
            self.fn[c] += int(np.sum(~gm & (gcount >= self.min_points)))
            self.fp[c] += int(np.sum(~pm & (pcount >= self.min_points)))

    def per_class(self) -> dict[int, float]:
        return {
            c: self.iou[c] / max(self.tp[c] + 0.5 * self.fp[c] + 0.5 * self.fn[c], 1e-15)
            for c in sorted(self.seen)
        }

    def pq_things(self) -> float:
        pc = self.per_class()
        return float(np.mean(list(pc.values()))) if pc else 0.0

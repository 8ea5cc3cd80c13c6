"""A literal, loop-per-class transcription of the 4D benchmark's LSTQ (docs/metrics.md, "LSTQ").

4D-PLS's ``Panoptic4DEval`` is not published on PyPI, so this slow re-implementation of its
per-class loop (dict tables, one mask per class, the same +1 shift and skipped id) is the
spec-derived stand-in the vectorised accumulator is checked against, and the speed baseline of
``bench/bench_metrics.py``. It keeps the reference's defect of not being idempotent.
"""

from __future__ import annotations

import math

import numpy as np


class Ref4DPLS:
    def __init__(self, n_classes: int = 20, ignore=(0,), min_points: int = 50, things=range(1, 9)) -> None:
        self.n = n_classes
        self.ignore = list(ignore)
        self.include = [c for c in range(n_classes) if c not in self.ignore]
        self.min_points = min_points
        self.things = list(things)
        self.offset = 2**32
        self.conf = np.zeros((n_classes, n_classes), dtype=np.int64)
        self.seqs: list[str] = []
        self.preds: dict[str, dict[int, int]] = {}
        self.gts: dict[str, list[dict[int, int]]] = {}
        self.inter: dict[str, list[dict[int, int]]] = {}
        self.aq_sum = 0.0

    @staticmethod
    def _bump(table: dict[int, int], ids: np.ndarray, counts: np.ndarray) -> None:
        for i, k in zip(ids.tolist(), counts.tolist(), strict=True):
            if i == 1:  # shifted id 0: "no instance"
                continue
            table[i] = table.get(i, 0) + k

    def add(self, seq, pred_sem, pred_inst, gt_sem, gt_inst) -> None:
        np.add.at(self.conf, (pred_sem, gt_sem), 1)
        if seq not in self.seqs:
            self.seqs.append(seq)
            self.preds[seq] = {}
            self.gts[seq] = [{} for _ in range(self.n)]
            self.inter[seq] = [{} for _ in range(self.n)]
        x_inst = pred_inst.astype(np.int64) + 1
        y_inst = gt_inst.astype(np.int64) + 1
        keep = ~np.isin(gt_sem, self.ignore)
        x_sem, y_sem, x_inst, y_inst = pred_sem[keep], gt_sem[keep], x_inst[keep], y_inst[keep]
        for c in self.include:
            x_c = x_inst * (x_sem == c)
            y_c = y_inst * (y_sem == c)
            ug, ng = np.unique(y_c[y_c > 0], return_counts=True)
            big = ng > self.min_points
            self._bump(self.gts[seq][c], ug[big], ng[big])
            y_c = y_c * np.isin(y_c, ug[big])
            up, npred = np.unique(x_c[x_c > 0], return_counts=True)
            self._bump(self.preds[seq], up, npred)
            both = (x_inst > 0) & (y_c > 0)
            uc, nc = np.unique(x_inst[both] + self.offset * y_c[both], return_counts=True)
            self._bump(self.inter[seq][c], uc, nc)

    def get(self) -> tuple[float, float, float, np.ndarray]:
        """``(LSTQ, S_assoc, S_cls, iou (C,))``; like the reference, a second call double counts."""
        n_tubes = [0] * self.n
        for seq in self.seqs:
            preds = self.preds[seq]
            for c in self.include:
                gts, inter = self.gts[seq][c], self.inter[seq][c]
                n_tubes[c] += len(gts)
                outer = 0.0
                for g, gsize in gts.items():
                    inner = 0.0
                    for p, psize in preds.items():
                        tpa = inter.get(p + self.offset * g)
                        if tpa is not None:
                            inner += tpa * (tpa / (gsize + psize - tpa))
                    outer += 1.0 / gsize * inner
                self.aq_sum += outer
        n_thing = sum(n_tubes[c] for c in self.things)
        with np.errstate(divide="ignore", invalid="ignore"):
            s_assoc = float(np.float64(self.aq_sum) / np.float64(n_thing))
        conf = self.conf.astype(np.float64)
        conf[:, self.ignore] = 0
        tp = conf.diagonal()
        union = conf.sum(axis=1) + conf.sum(axis=0) - tp
        iou = tp / np.maximum(union, 1e-15)
        s_cls = float(np.sum(iou) / np.count_nonzero(union))
        return math.sqrt(s_assoc * s_cls), s_assoc, s_cls, iou

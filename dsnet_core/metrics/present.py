"""Metric ``present``: mIoU and the PQ family averaged over the classes present.

The official means (metric ``panoptic``) run over every scored class and count a class the
ground truth lacks as 0, so a log without, say, 9 of the 19 SemanticKITTI classes can never
reach more than 10/19 of a perfect score. These means run over the classes present instead.

**The rule.** A scored class (not ignored) is *present* in a scope — a frame, a sequence, a run —
when the ground truth of that scope has at least one point of it: column ``c`` of the semantic
confusion ``conf[pred, gt]`` sums to more than 0. Points are counted after label decoding, so a
raw id the label map sends to the ignore class never makes a class present. Predictions play no
part: a class only predicted (false positives, no ground-truth point) is absent and left out,
though its false positives still lower the IoU and PQ of the classes whose ground truth they
cover. The per-class values averaged are exactly the official ones (``panoptic``'s per-class
IoU, PQ, SQ, RQ), so ``miou_present`` is the official per-class IoU averaged over the present
classes, and equals ``miou`` when every class is present.

:func:`present_class_means` is the same computation as a plain function, for a bench that has
per-class values and ground-truth point counts but no scorer.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from .panoptic import FramePQ, PanopticAccumulator, pq_terms, semantic_iou
from .registry import Column, Frame, Metric, OneAccumulator, Setup


def present_class_means(
    iou_per_class: np.ndarray | Mapping[str, float],
    gt_counts: np.ndarray | Mapping[str, int],
    pq: np.ndarray | Mapping[str, float] | None = None,
    sq: np.ndarray | Mapping[str, float] | None = None,
    rq: np.ndarray | Mapping[str, float] | None = None,
) -> dict[str, float]:
    """Means over the classes with ground-truth points (the rule in this module's docstring).

    Args:
        iou_per_class: ``(C,)`` per-class IoU of the scored classes, or ``{class: IoU}``.
        gt_counts: ground-truth points per class, ``(C,)`` aligned with ``iou_per_class`` or
            ``{class: points}`` (a class missing from the mapping has 0 points).
        pq, sq, rq: optional per-class PQ, SQ, RQ, aligned like ``iou_per_class``.

    Returns:
        ``miou_present`` (and ``pq_present``, ``sq_present``, ``rq_present`` for the arrays given)
        as floats, NaN when no class is present, and ``present_classes`` (the count, as a float).
    """
    names = list(iou_per_class) if isinstance(iou_per_class, Mapping) else None

    def arr(x, what: str) -> np.ndarray:
        if isinstance(x, Mapping):
            if names is None:
                raise ValueError(f"{what}: a mapping needs iou_per_class as a mapping too")
            return np.array([float(x.get(n, 0)) for n in names], dtype=np.float64)
        a = np.asarray(x, dtype=np.float64).reshape(-1)
        if names is not None and a.size != len(names):
            raise ValueError(f"{what} has {a.size} values for {len(names)} classes")
        return a

    iou = arr(iou_per_class, "iou_per_class")
    counts = arr(gt_counts, "gt_counts")
    if counts.shape != iou.shape:
        raise ValueError(f"gt_counts has {counts.size} values, iou_per_class {iou.size}")
    present = counts > 0
    n = int(present.sum())
    out = {"miou_present": _mean(iou, present)}
    for key, x in (("pq_present", pq), ("sq_present", sq), ("rq_present", rq)):
        if x is not None:
            vals = arr(x, key[:2])
            if vals.shape != iou.shape:
                raise ValueError(f"{key[:2]} has {vals.size} values, iou_per_class {iou.size}")
            out[key] = _mean(vals, present)
    out["present_classes"] = float(n)
    return out


def _mean(x: np.ndarray, mask: np.ndarray) -> float:
    return float(x[mask].mean()) if mask.any() else math.nan


def gt_points(conf: np.ndarray) -> np.ndarray:
    """``(C,) int64`` ground-truth points per class of a ``conf[pred, gt]`` matrix."""
    return np.asarray(conf, dtype=np.int64).sum(axis=0)


class PresentMetric(OneAccumulator):
    """Accumulator of metric ``present``. State: its own :class:`~.panoptic.PanopticAccumulator`
    fed the frames' PQ counts (the confusion gives the ground-truth points per class)."""

    def __init__(self, setup: Setup) -> None:
        self.spec = setup.spec
        self.acc = PanopticAccumulator(setup.spec, setup.min_points, setup.mode)

    def add(self, frame: Frame) -> dict[str, float]:
        self.acc.add_frame(frame.pq)
        return {k: v for k, v in self._means(frame.pq).items() if k in ("miou_present", "pq_present")}

    def _means(self, f: FramePQ | PanopticAccumulator) -> dict[str, float]:
        inc = self.spec.include
        iou_sum = f.iou_sum
        sq, rq, pq = pq_terms(iou_sum, f.tp, f.fp, f.fn)
        iou = semantic_iou(f.conf, self.spec.ignore)[0]
        return present_class_means(iou[inc], gt_points(f.conf)[inc], pq[inc], sq[inc], rq[inc])

    def values(self) -> dict[str, float]:
        return self._means(self.acc)

    def class_values(self) -> dict[str, dict[str, float]]:
        counts = gt_points(self.acc.conf)
        return {self.spec.names[k]: {"gt_points": int(counts[k])} for k in self.spec.include}


PRESENT = Metric(
    name="present",
    make=PresentMetric,
    columns=(
        Column("miou_present", "mIoU (present)", brief=True, help="mIoU over the classes with ground truth"),
        Column("pq_present", "PQ (present)", brief=True, help="PQ over the classes with ground truth"),
        Column("sq_present", "SQ (present)"),
        Column("rq_present", "RQ (present)"),
        Column("present_classes", "classes present", "count", help="classes with ground-truth points"),
    ),
    class_columns=(Column("gt_points", "GT points", "count", help="ground-truth points of the class"),),
    frame_columns=(
        Column("miou_present", "mIoU (present)", help="over the classes with ground truth in the frame"),
        Column("pq_present", "PQ (present)", help="over the classes with ground truth in the frame"),
    ),
    title="means over the classes present (ground-truth points in the scope scored)",
)

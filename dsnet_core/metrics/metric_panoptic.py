"""Metric ``panoptic``: the PQ family and mIoU (SemanticKITTI ``evaluate_panoptic.py`` semantics).

The registered face of :class:`~.panoptic.PanopticAccumulator`: means over every scored class,
absent classes counting 0 (the official means); per class PQ, SQ, RQ, IoU and the segment counts;
per frame PQ, SQ, RQ over the classes seen in the frame and mIoU over those with a union.
"""

from __future__ import annotations

import math

from .decode import ClassSpec
from .panoptic import FramePQ, PanopticAccumulator, pq_terms, semantic_iou
from .registry import Column, Frame, Metric, OneAccumulator, Setup

_KEYS = (
    "pq",
    "sq",
    "rq",
    "pq_dagger",
    "pq_things",
    "sq_things",
    "rq_things",
    "pq_stuff",
    "sq_stuff",
    "rq_stuff",
    "miou",
)


class PanopticMetric(OneAccumulator):
    """Accumulator of metric ``panoptic`` (state: one :class:`~.panoptic.PanopticAccumulator`)."""

    def __init__(self, setup: Setup) -> None:
        self.spec = setup.spec
        self.acc = PanopticAccumulator(setup.spec, setup.min_points, setup.mode)

    def add(self, frame: Frame) -> dict[str, float]:
        self.acc.add_frame(frame.pq)
        return frame_values(frame.pq, self.spec)

    def values(self) -> dict[str, float]:
        res = self.acc.result()
        return {k: float(getattr(res, k)) for k in _KEYS}

    def class_values(self) -> dict[str, dict[str, float]]:
        return {
            name: {"pq": c.pq, "sq": c.sq, "rq": c.rq, "iou": c.iou, "tp": c.tp, "fp": c.fp, "fn": c.fn}
            for name, c in self.acc.result().per_class.items()
        }


def frame_values(fpq: FramePQ, spec: ClassSpec) -> dict[str, float]:
    """One frame's PQ, SQ, RQ over the classes seen in it (tp + fp + fn > 0) and mIoU over the
    classes with a non-zero union; NaN where it has none."""
    inc = spec.include
    sq, rq, pq = pq_terms(fpq.iou_sum, fpq.tp, fpq.fp, fpq.fn)
    seen = inc[(fpq.tp + fpq.fp + fpq.fn)[inc] > 0]
    iou, union = semantic_iou(fpq.conf, spec.ignore)
    has = inc[union[inc] > 0]
    nan = math.nan
    return {
        "pq": float(pq[seen].mean()) if seen.size else nan,
        "sq": float(sq[seen].mean()) if seen.size else nan,
        "rq": float(rq[seen].mean()) if seen.size else nan,
        "miou": float(iou[has].mean()) if has.size else nan,
    }


PANOPTIC = Metric(
    name="panoptic",
    make=PanopticMetric,
    columns=(
        Column("pq", "PQ", brief=True, help="panoptic quality, mean over every class (absent: 0)"),
        Column("sq", "SQ", help="segmentation quality, mean over every class"),
        Column("rq", "RQ", help="recognition quality, mean over every class"),
        Column("pq_dagger", "PQ†", help="PQ for things, IoU for stuff"),
        Column("pq_things", "PQ things"),
        Column("sq_things", "SQ things"),
        Column("rq_things", "RQ things"),
        Column("pq_stuff", "PQ stuff"),
        Column("sq_stuff", "SQ stuff"),
        Column("rq_stuff", "RQ stuff"),
        Column("miou", "mIoU", brief=True, help="semantic IoU, mean over every class (absent: 0)"),
    ),
    class_columns=(
        Column("pq", "PQ"),
        Column("sq", "SQ"),
        Column("rq", "RQ"),
        Column("iou", "IoU"),
        Column("tp", "TP", "count"),
        Column("fp", "FP", "count"),
        Column("fn", "FN", "count"),
    ),
    frame_columns=(
        Column("pq", "PQ", help="mean over the classes seen in the frame"),
        Column("sq", "SQ"),
        Column("rq", "RQ"),
        Column("miou", "mIoU", help="mean over the classes with a non-zero union in the frame"),
    ),
    title="panoptic quality and mIoU (official means: every class, absent ones count 0)",
)

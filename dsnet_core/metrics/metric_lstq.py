"""Metric ``lstq``: LSTQ = sqrt(S_assoc · S_cls) and its parts (:class:`~.lstq.LSTQAccumulator`).

SemanticKITTI ground truth: the 4D-PLS ``Panoptic4DEval`` variant in the scorer's mode; Panoptic
nuScenes: the tracking evaluator's variant (official).
"""

from __future__ import annotations

from .lstq import LSTQAccumulator
from .registry import Column, Frame, Metric, OneAccumulator, Setup
from .report import Mode

_KEYS = ("lstq", "s_assoc", "s_cls", "iou_things", "iou_stuff")


class LSTQMetric(OneAccumulator):
    """Accumulator of metric ``lstq`` (state: one :class:`~.lstq.LSTQAccumulator`)."""

    def __init__(self, setup: Setup) -> None:
        if setup.benchmark == "panoptic-nuscenes":
            self.acc = LSTQAccumulator(setup.spec, setup.min_points, Mode.OFFICIAL, variant="nuscenes")
        else:
            self.acc = LSTQAccumulator(setup.spec, setup.min_points, setup.mode, variant="4dpls")

    def add(self, frame: Frame) -> dict[str, float]:
        self.acc.add(frame.cells, frame.sequence)
        return {}

    def values(self) -> dict[str, float]:
        res = self.acc.result()
        return {k: float(getattr(res, k)) for k in _KEYS}

    def class_values(self) -> dict[str, dict[str, float]]:
        return {}


LSTQ = Metric(
    name="lstq",
    make=LSTQMetric,
    columns=(
        Column("lstq", "LSTQ", brief=True, help="sqrt(S_assoc · S_cls)"),
        Column("s_assoc", "S_assoc", help="association score of the ground-truth tubes"),
        Column("s_cls", "S_cls", help="classification score"),
        Column("iou_things", "IoU things"),
        Column("iou_stuff", "IoU stuff"),
    ),
    title="LSTQ",
)

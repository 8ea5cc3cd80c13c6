"""Metrics of Panoptic nuScenes ground truth only (``Setup.benchmark == "panoptic-nuscenes"``).

* ``nuscenes_tracking``: PAT, TQ, PTQ and sPTQ of nuscenes-devkit's ``PanopticTrackingEval``
  (:class:`~.nuscenes_track.PanopticTrackingAccumulator`) over all challenge classes;
* ``expressible``: the headline numbers again over the classes the model's classes can express
  (``Setup.expressible``; the others ignored like class 0), as :class:`ClassSet`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .decode import ClassSpec
from .nuscenes_track import PanopticTrackingAccumulator
from .panoptic import PanopticAccumulator
from .registry import Column, Frame, Metric, OneAccumulator, Setup
from .report import Mode

NUSCENES = "panoptic-nuscenes"


class TrackingMetric(OneAccumulator):
    """Accumulator of ``nuscenes_tracking``: frames of a scene in time order, chunks merged in order."""

    def __init__(self, setup: Setup) -> None:
        self.acc = PanopticTrackingAccumulator(setup.spec, setup.min_points)

    def add(self, frame: Frame) -> dict[str, float]:
        self.acc.add(frame.cells, frame.sequence)
        return {}

    def values(self) -> dict[str, float]:
        tr = self.acc.result()
        return {"pat": tr.pat, "tq": tr.tq, "ptq": tr.ptq, "sptq": tr.sptq}

    def class_values(self) -> dict[str, dict[str, float]]:
        return {}


@dataclass
class ClassSet:
    """The accumulators of one set of scored classes: ``PanopticEval`` (PQ family, mIoU, float64
    IoUs) and ``PanopticTrackingEval`` (LSTQ, PTQ, sPTQ, TQ, PAT)."""

    spec: ClassSpec
    seg: PanopticAccumulator
    track: PanopticTrackingAccumulator

    @classmethod
    def make(cls, spec: ClassSpec, min_points: int) -> ClassSet:
        return cls(
            spec,
            PanopticAccumulator(spec, min_points, Mode.OFFICIAL),
            PanopticTrackingAccumulator(spec, min_points),
        )

    def add(self, frame: Frame) -> dict[str, float]:
        self.seg.add(frame.cells)
        self.track.add(frame.cells, frame.sequence)
        return {}

    def merge(self, other: ClassSet) -> None:
        self.seg.merge(other.seg)
        self.track.merge(other.track)

    def state(self) -> dict[str, np.ndarray]:
        return {**self.seg.state("seg_"), **self.track.state("track_")}

    def restore(self, state: dict[str, np.ndarray]) -> None:
        self.seg.restore(state, "seg_")
        self.track.restore(state, "track_")

    def values(self) -> dict[str, float]:
        p, tr = self.seg.result(), self.track.result()
        return {
            "pq_expressible": p.pq,
            "sq_expressible": p.sq,
            "rq_expressible": p.rq,
            "miou_expressible": p.miou,
            "lstq_expressible": tr.lstq,
            "pat_expressible": tr.pat,
        }

    def class_values(self) -> dict[str, dict[str, float]]:
        return {}


def _tracking(setup: Setup) -> TrackingMetric | None:
    return TrackingMetric(setup) if setup.benchmark == NUSCENES else None


def _expressible(setup: Setup) -> ClassSet | None:
    if setup.benchmark != NUSCENES or setup.expressible is None:
        return None
    return ClassSet.make(setup.expressible, setup.min_points)


NUSCENES_TRACKING = Metric(
    name="nuscenes_tracking",
    make=_tracking,
    columns=(
        Column("pat", "PAT", help="2·PQ·TQ / (PQ + TQ)"),
        Column("tq", "TQ", help="tracking quality of the ground-truth instances"),
        Column("ptq", "PTQ"),
        Column("sptq", "sPTQ"),
    ),
    title="Panoptic nuScenes tracking",
)
EXPRESSIBLE = Metric(
    name="expressible",
    make=_expressible,
    columns=(
        Column("pq_expressible", "PQ (expressible)"),
        Column("sq_expressible", "SQ (expressible)"),
        Column("rq_expressible", "RQ (expressible)"),
        Column("miou_expressible", "mIoU (expressible)"),
        Column("lstq_expressible", "LSTQ (expressible)"),
        Column("pat_expressible", "PAT (expressible)"),
    ),
    title="over the classes the model's classes can express",
)

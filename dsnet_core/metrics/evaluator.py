"""``PanopticEvaluator``: SemanticKITTI PQ family, mIoU and LSTQ from one pass over each frame.

Example::

    ev = PanopticEvaluator(load_label_map("semantic-kitti"), min_points=50, mode="official")
    for seq, frame, gt, pred in frames:           # gt, pred: (N,) uint32 raw labels
        ev.add(gt, pred, frame=frame, sequence=seq)
    res = ev.result()                               # EvalResult; res.to_dict() is the JSON report
    rows = ev.rows                                  # one FrameRow per frame

Raw labels are ``sem | inst << 16``; raw semantic ids missing from ``learning_map`` score as
class 0 (ignored). ``add_train`` takes already-mapped arrays (train class, instance id).
"""

from __future__ import annotations

import math

import numpy as np

from dsnet_core.labels import LabelMap

from .cells import Cells, check_labels
from .decode import ClassSpec, KittiDecoder, TrainDecoder, make_cells, train_labels
from .lstq import LSTQAccumulator
from .panoptic import FramePQ, PanopticAccumulator, pq_terms, semantic_iou
from .report import EvalResult, FrameRow, Mode, as_mode


class PanopticEvaluator:
    """Streaming SemanticKITTI scorer (PQ family + mIoU + LSTQ), mergeable across workers.

    Args:
        label_map: the dataset's label map (classes, things/stuff, ``learning_map``).
        min_points: minimum segment size; PQ counts unmatched segments with ≥ it, LSTQ keeps
            a gt id in a frame with > it (default: the label map's, 50 for SemanticKITTI).
        mode: ``official`` (benchmark-exact, quirks included) or ``corrected``.
        keep_rows: keep one :class:`FrameRow` per frame in :attr:`rows` (memory grows with frames).
        ignore: ignored train ids, the config's ``learning_ignore`` (default: class 0).
    """

    def __init__(
        self,
        label_map: LabelMap,
        min_points: int | None = None,
        mode: Mode | str = Mode.OFFICIAL,
        keep_rows: bool = True,
        ignore: tuple[int, ...] = (0,),
    ) -> None:
        self.label_map = label_map
        self.spec = ClassSpec.from_label_map(label_map, ignore)
        self.min_points = int(label_map.min_points if min_points is None else min_points)
        self.mode = as_mode(mode)
        self.keep_rows = keep_rows
        self.panoptic = PanopticAccumulator(self.spec, self.min_points, self.mode)
        self.lstq = LSTQAccumulator(self.spec, self.min_points, self.mode, variant="4dpls")
        self.rows: list[FrameRow] = []
        self.by_sequence: dict[str, PanopticAccumulator] = {}
        self._raw = KittiDecoder(label_map)
        self._train = TrainDecoder()

    @property
    def frames(self) -> int:
        return self.panoptic.frames

    def add(
        self, gt_label: np.ndarray, pred_label: np.ndarray, frame: str = "", sequence: str = ""
    ) -> FrameRow:
        """Score one frame of raw labels.

        Args:
            gt_label: ``(N,) uint32`` ground truth, ``sem | inst << 16``.
            pred_label: ``(N,) uint32`` prediction, same encoding and length.
            frame: frame name (for the per-frame row).
            sequence: sequence name; LSTQ tubes live within a sequence.

        Returns:
            The frame's :class:`FrameRow`.
        """
        gt = check_labels(gt_label, "gt_label")
        pred = check_labels(pred_label, "pred_label")
        if gt.shape != pred.shape:
            raise ValueError(f"gt has {gt.shape[0]} labels but pred has {pred.shape[0]} (frame {frame!r})")
        return self._add(make_cells(gt, pred, self._raw, self._raw), frame, sequence)

    def add_train(
        self,
        gt_sem: np.ndarray,
        gt_inst: np.ndarray,
        pred_sem: np.ndarray,
        pred_inst: np.ndarray,
        frame: str = "",
        sequence: str = "",
    ) -> FrameRow:
        """Score one frame given train classes ``(N,) int`` and instance ids ``(N,) int < 2¹⁶``.

        Segments are keyed by (class, instance), so thing points with instance 0 form one
        segment per class (there is no raw label to split them further).
        """
        n = self.spec.n_classes
        gt = train_labels(gt_sem, gt_inst, n, "ground truth")
        pred = train_labels(pred_sem, pred_inst, n, "prediction")
        if gt.shape != pred.shape:
            raise ValueError(f"gt has {gt.shape[0]} points but pred has {pred.shape[0]} (frame {frame!r})")
        return self._add(make_cells(gt, pred, self._train, self._train), frame, sequence)

    def _add(self, cells: Cells, frame: str, sequence: str) -> FrameRow:
        fpq = self.panoptic.add(cells)
        self._sequence_pq(str(sequence)).add_frame(fpq)
        self.lstq.add(cells, sequence)
        row = frame_row(fpq, self.spec, str(sequence), str(frame), cells.n_points)
        if self.keep_rows:
            self.rows.append(row)
        return row

    def merge(self, other: PanopticEvaluator) -> PanopticEvaluator:
        """Add ``other``'s state (same label map, min_points, mode) into this one; returns self."""
        self.panoptic.merge(other.panoptic)
        self.lstq.merge(other.lstq)
        for seq, acc in other.by_sequence.items():
            self._sequence_pq(seq).merge(acc)
        self.rows.extend(other.rows)
        return self

    def result(self) -> EvalResult:
        """All metrics so far; idempotent (the state is not modified)."""
        return EvalResult(self.mode, self.frames, self.panoptic.result(), self.lstq.result())

    def result_by_sequence(self) -> dict[str, EvalResult]:
        """The same metrics for each sequence alone (sorted by name)."""
        return {
            seq: EvalResult(self.mode, acc.frames, acc.result(), self.lstq.result(seq))
            for seq, acc in sorted(self.by_sequence.items())
        }

    def _sequence_pq(self, sequence: str) -> PanopticAccumulator:
        if sequence not in self.by_sequence:
            self.by_sequence[sequence] = PanopticAccumulator(self.spec, self.min_points, self.mode)
        return self.by_sequence[sequence]


def frame_row(fpq: FramePQ, spec: ClassSpec, sequence: str, frame: str, n_points: int) -> FrameRow:
    """One frame's row: PQ over the classes seen in the frame, mIoU over classes with a union."""
    inc = spec.include
    sq, rq, pq = pq_terms(fpq.iou_sum, fpq.tp, fpq.fp, fpq.fn)
    seen = inc[(fpq.tp + fpq.fp + fpq.fn)[inc] > 0]
    iou, union = semantic_iou(fpq.conf, spec.ignore)
    has = inc[union[inc] > 0]
    nan = math.nan
    return FrameRow(
        sequence=sequence,
        frame=frame,
        n_points=int(n_points),
        n_valid=int(fpq.n_valid),
        pq=float(pq[seen].mean()) if seen.size else nan,
        sq=float(sq[seen].mean()) if seen.size else nan,
        rq=float(rq[seen].mean()) if seen.size else nan,
        miou=float(iou[has].mean()) if has.size else nan,
        tp=int(fpq.tp.sum()),
        fp=int(fpq.fp.sum()),
        fn=int(fpq.fn.sum()),
    )

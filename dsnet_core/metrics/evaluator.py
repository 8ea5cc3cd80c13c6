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

import numpy as np

from dsnet_core.labels import LabelMap

from .cells import Cells, check_labels
from .decode import ClassSpec, KittiDecoder, TrainDecoder, make_cells, train_labels
from .lstq import LSTQAccumulator
from .panoptic import FramePQ, PanopticAccumulator
from .registry import Frame, MetricSet, Setup
from .report import EvalResult, FrameRow, Mode, as_mode

KIND = "semantic-kitti"


class PanopticEvaluator:
    """Streaming SemanticKITTI scorer (every registered metric: PQ family, mIoU, LSTQ, ...),
    mergeable across workers.

    Each sequence's frames go to that sequence's :class:`~.registry.MetricSet`; run-level numbers
    come from merging them (exact, so equal to one pass over every frame).

    Args:
        label_map: the dataset's label map (classes, things/stuff, ``learning_map``).
        min_points: minimum segment size; PQ counts unmatched segments with ≥ it, LSTQ keeps
            a gt id in a frame with > it (default: the label map's, 50 for SemanticKITTI).
        mode: ``official`` (benchmark-exact, quirks included) or ``corrected``.
        keep_rows: keep one :class:`FrameRow` per frame in :attr:`rows` (memory grows with frames).
        ignore: ignored train ids, the config's ``learning_ignore`` (default: class 0).
    """

    mapping = None  # no class mapping: predictions in the ground truth's own classes
    unexpressible: frozenset[int] = frozenset()  # every class can be predicted
    to_truth = None  # labels are already in the ground truth's classes

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
        self.setup = Setup(self.spec, self.min_points, self.mode, KIND)
        self.by_sequence: dict[str, MetricSet] = {}
        self._matcher = PanopticAccumulator(self.spec, self.min_points, self.mode)  # measure() only
        self._total: MetricSet | None = None
        self.rows: list[FrameRow] = []
        self._raw = KittiDecoder(label_map)
        self._train = TrainDecoder()

    @property
    def metrics(self) -> MetricSet:
        """Every sequence's metric set merged (computed when asked, kept until the next change)."""
        if self._total is None:
            total = MetricSet(self.setup)
            for seq in sorted(self.by_sequence):
                total.merge(self.by_sequence[seq])
            self._total = total
        return self._total

    @property
    def panoptic(self) -> PanopticAccumulator:
        """The PQ family's accumulator over every sequence (metric ``panoptic``)."""
        return self.metrics["panoptic"].acc

    @property
    def lstq(self) -> LSTQAccumulator:
        """LSTQ's accumulator over every sequence (metric ``lstq``)."""
        return self.metrics["lstq"].acc

    @property
    def frames(self) -> int:
        return sum(s["panoptic"].acc.frames for s in self.by_sequence.values())

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
        fpq = self._matcher.measure(cells)
        values = self._sequence(str(sequence)).add(Frame(cells, str(sequence), fpq))
        self._total = None
        row = frame_row(fpq, str(sequence), str(frame), cells.n_points, values)
        if self.keep_rows:
            self.rows.append(row)
        return row

    def merge(self, other: PanopticEvaluator) -> PanopticEvaluator:
        """Add ``other``'s state (same label map, min_points, mode) into this one; returns self."""
        if other.setup != self.setup:
            raise ValueError("cannot merge evaluators with different classes, min_points or mode")
        for seq, metrics in other.by_sequence.items():
            self._sequence(seq).merge(metrics)
        self._total = None
        self.rows.extend(other.rows)
        return self

    def result(self) -> EvalResult:
        """All metrics so far; idempotent (the state is not modified)."""
        return self._result(self.metrics)

    def result_by_sequence(self) -> dict[str, EvalResult]:
        """The same metrics for each sequence alone (sorted by name)."""
        return {seq: self._result(self.by_sequence[seq]) for seq in sorted(self.by_sequence)}

    def _result(self, metrics: MetricSet) -> EvalResult:
        pan = metrics["panoptic"].acc
        return EvalResult(
            self.mode,
            pan.frames,
            pan.result(),
            metrics["lstq"].acc.result(),
            values=metrics.values(),
            classes=metrics.class_values(),
        )

    def _sequence(self, sequence: str) -> MetricSet:
        if sequence not in self.by_sequence:
            self.by_sequence[sequence] = MetricSet(self.setup)
        return self.by_sequence[sequence]

    # -- state ------------------------------------------------------------------------------
    def state(self) -> dict[str, np.ndarray]:
        """The exact state as named arrays (rows excluded; ``np.savez`` ready).

        Keys: ``kind``, ``min_points``, ``mode``, ``ignore``, the metric set's ``format`` and
        ``metrics`` (:meth:`~.registry.MetricSet.header`), ``seqs`` (the sequence names) and
        sequence ``i``'s metric arrays under ``seq{i}/{metric}/*``.
        """
        seqs = sorted(self.by_sequence)
        out: dict[str, np.ndarray] = {
            "kind": np.array(KIND),
            "min_points": np.array(self.min_points, dtype=np.int64),
            "mode": np.array(str(self.mode)),
            "ignore": np.array(self.spec.ignore, dtype=np.int64),
            "classes": np.array(self.spec.names, dtype=str),
            **MetricSet(self.setup).header(),
            "seqs": np.array(seqs, dtype=str),
        }
        for i, seq in enumerate(seqs):
            out.update(self.by_sequence[seq].state(f"seq{i}/"))
        return out

    def restore(self, state: dict[str, np.ndarray]) -> PanopticEvaluator:
        """Load a :meth:`state` into this fresh evaluator (same label map and settings); returns self.

        Raises:
            ValueError: a state of another layout or set of metrics, another scorer's, or made
                with other classes, min_points, mode or ignored classes.
        """
        MetricSet(self.setup).check(state)  # the layout and the metrics first: an old state says so
        if str(state.get("kind", "")) != KIND:
            raise ValueError(f"scorer state: not a {KIND} scorer's (it is {str(state.get('kind', ''))!r})")
        classes = tuple(str(c) for c in np.asarray(state["classes"]).reshape(-1).tolist())
        if classes != self.spec.names:
            raise ValueError(
                f"scorer state: {len(classes)} classes ({', '.join(classes[:3])}, …), this scorer's "
                f"label map {self.label_map.name!r} has {self.spec.n_classes}"
            )
        got = (int(state["min_points"]), str(state["mode"]), tuple(int(i) for i in state["ignore"]))
        if got != (self.min_points, str(self.mode), self.spec.ignore):
            raise ValueError(
                f"scorer state: scored with min_points, mode, ignore {got}, this scorer has "
                f"{(self.min_points, str(self.mode), self.spec.ignore)}"
            )
        for i, seq in enumerate(np.asarray(state["seqs"]).reshape(-1).tolist()):
            self._sequence(str(seq)).restore(state, f"seq{i}/")
        self._total = None
        return self


def frame_row(fpq: FramePQ, sequence: str, frame: str, n_points: int, values: dict[str, float]) -> FrameRow:
    """One frame's row: its segment counts and every metric's per-frame ``values`` (``pq``, ``sq``,
    ``rq`` over the classes seen in the frame and ``miou`` over those with a union: ``panoptic``'s)."""
    nan = float("nan")
    return FrameRow(
        sequence=sequence,
        frame=frame,
        n_points=int(n_points),
        n_valid=int(fpq.n_valid),
        pq=values.get("pq", nan),
        sq=values.get("sq", nan),
        rq=values.get("rq", nan),
        miou=values.get("miou", nan),
        tp=int(fpq.tp.sum()),
        fp=int(fpq.fp.sum()),
        fn=int(fpq.fn.sum()),
        values=dict(values),
    )

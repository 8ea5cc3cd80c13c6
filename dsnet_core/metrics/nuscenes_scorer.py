"""Scoring a model's labels against a log's Panoptic nuScenes ground truth, in the nuScenes metrics.

Ground truth is the nuScenes reader's ``general class | instance << 16`` (instances 1..999 per
class and scene); predictions are the model's ``raw | instance << 16`` in its own label map,
taken to nuScenes general classes by the explicit :class:`~dsnet_core.label_mapping.ClassMapping`
and on to the 16 challenge classes by the nuScenes map's ``learning_map`` -- the classes of the
results ``dsnet export --format nuscenes`` writes for the devkit. A predicted instance id is kept
on thing classes only (stuff gets instance 0, as in those files), and a predicted segment is a
distinct (challenge class, instance id) pair, as the devkit's whole ``class * 1000 + instance``.

Metrics (``docs/metrics.md``, "Panoptic nuScenes"): the PQ family and mIoU of the devkit's
``PanopticEval`` (min points 15, float64 IoUs), and LSTQ, PTQ, sPTQ, TQ and PAT of its
``PanopticTrackingEval`` (:class:`~.nuscenes_track.PanopticTrackingAccumulator`), each twice: over
all 16 challenge classes, and over the classes the model's classes can express (the mapping's
:attr:`~dsnet_core.label_mapping.ClassMapping.expressible`; the others are ignored like class 0,
so ground-truth points of a class the model cannot name are not scored).

A scene's frames must be added in time order; chunks of a scene merge in order (block states).
"""

from __future__ import annotations

import math

import numpy as np

from dsnet_core.label_mapping import ClassMapping
from dsnet_core.labels import LabelMap

from .cells import Cells, check_labels
from .decode import ClassSpec, make_cells
from .evaluator import frame_row
from .metric_nuscenes import NUSCENES, ClassSet
from .nuscenes import NUSCENES_MIN_POINTS, NuScenesGtDecoder
from .nuscenes_track import TrackingResult
from .panoptic import PanopticAccumulator
from .registry import Frame, MetricSet, Setup
from .report import EvalResult, FrameRow, Mode

_CLASS_BITS = 5  # challenge classes < 32: a predicted cell label is instance << 5 | class


class _PredDecoder:
    """Predicted cell labels ``instance << 5 | challenge class``: class = low bits, id = whole label."""

    def classes(self, labels: np.ndarray) -> np.ndarray:
        return (labels & np.uint64((1 << _CLASS_BITS) - 1)).astype(np.int64)

    def ids(self, labels: np.ndarray) -> np.ndarray:
        return labels.astype(np.int64)


class NuScenesScorer:
    """Panoptic nuScenes scores of predictions in another label map, through a class mapping.

    Args:
        label_map: the ground truth's map (``panoptic-nuscenes``).
        mapping: from the model's classes to ``label_map``'s.
        min_points: minimum segment size (nuScenes: 15).

    Attributes:
        metrics: every registered metric for Panoptic nuScenes over the 16 challenge classes
            (``panoptic``, ``lstq`` of the nuScenes variant, ``nuscenes_tracking``, ...), and
            ``expressible``: the same over the classes the mapping reaches.
    """

    mode = Mode.OFFICIAL

    def __init__(
        self, label_map: LabelMap, mapping: ClassMapping, min_points: int = NUSCENES_MIN_POINTS
    ) -> None:
        if mapping.target.name != label_map.name:
            raise ValueError(
                f"mapping targets {mapping.target.name!r}, the ground truth is {label_map.name!r}"
            )
        self.label_map = label_map
        self.mapping = mapping
        self.min_points = int(min_points)
        spec = ClassSpec.from_label_map(label_map, label_map.ignore)
        hidden = tuple(sorted({*spec.ignore, *mapping.unexpressible}))
        self._spec = spec
        expressible = ClassSpec.from_label_map(label_map, hidden)
        self.metrics = MetricSet(Setup(spec, self.min_points, Mode.OFFICIAL, NUSCENES, expressible))
        self._matcher = PanopticAccumulator(spec, self.min_points, Mode.OFFICIAL)  # measure() only
        self._gt = NuScenesGtDecoder(label_map)
        self._pred = _PredDecoder()
        challenge = label_map.lut(label_map.max_raw_id + 1, fill=0).astype(np.int64)
        self._challenge = challenge[mapping.raw_lut()]  # model raw id -> challenge class
        self._thing = spec.mask(spec.things)

    # the interface the score stage and the report share with PanopticEvaluator
    @property
    def spec(self) -> ClassSpec:
        return self._spec

    @property
    def panoptic(self) -> PanopticAccumulator:
        return self.metrics["panoptic"].acc

    @property
    def expressible(self) -> ClassSet:
        """The accumulators over the classes the mapping reaches (metric ``expressible``)."""
        return self.metrics["expressible"]

    @property
    def frames(self) -> int:
        return self.panoptic.frames

    @property
    def unexpressible(self) -> frozenset[int]:
        """Challenge classes the model's classes cannot name (scored in ``all`` only)."""
        return frozenset(int(c) for c in self.mapping.unexpressible)

    @property
    def to_truth(self):
        """Model labels -> the ground truth's classes (the mapping's ``map_labels``)."""
        return self.mapping.map_labels

    def add(
        self, gt_label: np.ndarray, pred_label: np.ndarray, frame: str = "", sequence: str = ""
    ) -> FrameRow:
        """Score the next frame of scene ``sequence``.

        Args:
            gt_label: ``(N,) uint32`` general class | instance << 16 (the nuScenes reader's).
            pred_label: ``(N,) uint32`` the model's raw id | instance << 16.
        """
        pred = check_labels(pred_label, "pred_label").astype(np.uint32)
        challenge = self._challenge[(pred & np.uint32(0xFFFF)).astype(np.int64)]
        inst = np.where(self._thing[challenge], pred >> np.uint32(16), 0)
        return self.add_challenge(gt_label, challenge, inst, frame, sequence)

    def add_challenge(
        self,
        gt_label: np.ndarray,
        challenge: np.ndarray,
        instance: np.ndarray,
        frame: str = "",
        sequence: str = "",
    ) -> FrameRow:
        """Score a frame of predictions already in challenge classes ``(N,) int`` with instance ids
        ``(N,) int < 2¹⁶`` (a devkit results file: ``label // 1000``, ``label % 1000``)."""
        gt = check_labels(gt_label, "gt_label").astype(np.uint32)
        if gt.shape != np.shape(challenge):
            raise ValueError(f"gt has {gt.shape[0]} labels but pred has {len(challenge)} (frame {frame!r})")
        pan = (gt & np.uint32(0xFFFF)) * np.uint32(1000) + (gt >> np.uint32(16))
        key = (np.asarray(instance, dtype=np.uint32) << np.uint32(_CLASS_BITS)) | np.asarray(
            challenge, dtype=np.uint32
        )
        cells = make_cells(pan, key, self._gt, self._pred)
        return self._add(cells, str(frame), str(sequence))

    def _add(self, cells: Cells, frame: str, sequence: str) -> FrameRow:
        fpq = self._matcher.measure(cells)
        values = self.metrics.add(Frame(cells, sequence, fpq))
        return frame_row(fpq, sequence, frame, cells.n_points, values)

    def merge(self, other: NuScenesScorer) -> NuScenesScorer:
        """Append ``other``'s frames (a later chunk of the same scenes, or other scenes)."""
        if other.mapping.sha256 != self.mapping.sha256 or other.min_points != self.min_points:
            raise ValueError("cannot merge nuScenes scorers with different mappings or min_points")
        self.metrics.merge(other.metrics)
        return self

    # -- state ------------------------------------------------------------------------------
    def state(self) -> dict[str, np.ndarray]:
        """The exact state as named arrays: ``kind``, the mapping's sha256, min_points and the
        metric set's (:meth:`~.registry.MetricSet.state`)."""
        return {
            "kind": np.array(NUSCENES),
            "mapping_sha256": np.array(self.mapping.sha256),
            "min_points": np.array(self.min_points, dtype=np.int64),
            **self.metrics.header(),
            **self.metrics.state(),
        }

    def restore(self, state: dict[str, np.ndarray]) -> NuScenesScorer:
        """Load a :meth:`state` into this fresh scorer (same maps, mapping and min_points).

        Raises:
            ValueError: another layout or set of metrics, not a nuScenes scorer's state, or made
                with another mapping or min_points.
        """
        self.metrics.check(state)
        if str(state.get("kind", "")) != NUSCENES:
            raise ValueError(f"not a {NUSCENES} scorer state")
        if str(state["mapping_sha256"]) != self.mapping.sha256 or int(state["min_points"]) != self.min_points:
            raise ValueError("the state was scored with another class mapping or min_points")
        self.metrics.restore(state)
        return self

    # -- results ----------------------------------------------------------------------------
    def result(self, classes: str = "all") -> EvalResult:
        """PQ family and mIoU (``PanopticEval``) with the tracking evaluator's LSTQ; over all
        classes, also every registered metric's values."""
        if classes == "all":
            return EvalResult(
                self.mode,
                self.frames,
                self.panoptic.result(),
                self.metrics["lstq"].acc.result(),
                values=self.metrics.values(),
                classes=self.metrics.class_values(),
            )
        s = self._set(classes)
        return EvalResult(self.mode, s.seg.frames, s.seg.result(), s.track.lstq.result())

    def tracking(self, classes: str = "all") -> TrackingResult:
        """PAT, TQ, PTQ, sPTQ, LSTQ and the tracking evaluator's own (float32) PQ."""
        if classes == "all":
            return self.metrics["nuscenes_tracking"].acc.result()
        return self._set(classes).track.result()

    def summary(self) -> dict[str, object]:
        """JSON-ready (NaN as None): per class set the headline numbers, every registered metric's
        values by key (``scores``), the per-class scores, and the mapping."""
        out: dict[str, object] = {"metric": "panoptic-nuscenes", "min_points": self.min_points}
        for classes in ("all", "expressible"):
            res, tr = self.result(classes), self.tracking(classes)
            spec = self.spec if classes == "all" else self.expressible.spec
            out[classes] = {
                "classes": [self.spec.names[c] for c in spec.include],
                **{k: _json(v) for k, v in self._numbers(res, tr).items()},
            }
        out["scores"] = {k: _json(v) for k, v in self.metrics.values().items()}
        out["frames"] = self.frames
        out["per_class"] = {
            n: {k: _json(v) for k, v in vars(c).items()} for n, c in self.result().panoptic.per_class.items()
        }
        out["mapping"] = self.mapping.record()
        return out

    @staticmethod
    def _numbers(res: EvalResult, tr: TrackingResult) -> dict[str, float]:
        p = res.panoptic
        return {
            "pq": p.pq,
            "sq": p.sq,
            "rq": p.rq,
            "pq_dagger": p.pq_dagger,
            "pq_things": p.pq_things,
            "pq_stuff": p.pq_stuff,
            "miou": p.miou,
            "lstq": tr.lstq,
            "s_assoc": tr.s_assoc,
            "s_cls": tr.s_cls,
            "pat": tr.pat,
            "tq": tr.tq,
            "ptq": tr.ptq,
            "sptq": tr.sptq,
        }

    def _set(self, classes: str) -> ClassSet:
        if classes != "expressible":
            raise ValueError(f"classes must be 'all' or 'expressible', got {classes!r}")
        return self.expressible


def _json(x: float | int) -> float | int | None:
    return None if isinstance(x, float) and not math.isfinite(x) else x

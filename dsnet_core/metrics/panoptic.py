"""PQ / SQ / RQ (per class, things, stuff, PQ†) and mIoU: a streaming, mergeable accumulator.

Semantics are those of the SemanticKITTI ``PanopticEval`` as driven by ``evaluate_panoptic.py``
(see docs/metrics.md): segments are keyed by the whole label within a class, a match needs IoU > 0.5,
unmatched segments count when they have ≥ ``min_points`` points, absent classes count 0.

State is ``O(classes²)``: a confusion matrix and per-class tp/fp/fn counts and IoU sums.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cells import Cells, ExactSum, sums_from_state, sums_state
from .decode import ClassSpec
from .report import ClassScore, Mode, PQResult, as_mode

EPS = 1e-15
# The reference keys a (gt, pred) pair as (pred + 1) + 2**32 * (gt + 1) in int64: it overflows
# (and then fails with a KeyError) once gt + 1 ≥ 2**31, i.e. ground-truth instance ids ≥ 32768.
_OVERFLOW_LABEL = (1 << 31) - 1


class ReferenceOverflowError(ValueError):
    """``official`` mode met ground-truth ids the reference evaluator cannot score (ids ≥ 32768)."""


@dataclass(frozen=True)
class FramePQ:
    """One frame's panoptic counts (for per-frame rows). Arrays are ``(C,)``; ``conf`` is ``(C, C)``."""

    tp: np.ndarray
    fp: np.ndarray
    fn: np.ndarray
    iou_sum: np.ndarray
    conf: np.ndarray
    n_valid: int
    matches: Matches


@dataclass(frozen=True)
class Matches:
    """A frame's true-positive pairs (IoU > 0.5), ``(M,)`` each, sorted by (gt label, pred label)."""

    cls: np.ndarray
    gt: np.ndarray
    pred: np.ndarray
    iou: np.ndarray


class PanopticAccumulator:
    """Accumulates PQ-family counts and the semantic confusion matrix over frames.

    Args:
        spec: the scored classes.
        min_points: unmatched segments count as fp/fn only with ≥ this many points
            (SemanticKITTI 50, Panoptic nuScenes 15).
        mode: ``official`` or ``corrected`` (``corrected`` scores ground-truth ids ≥ 32768, which
            ``official`` refuses with :class:`ReferenceOverflowError` because the reference crashes).
        iou_dtype: float type of per-pair IoUs; ``float32`` reproduces the nuScenes tracking
            evaluator's PQ, ``float64`` every other evaluator.
    """

    def __init__(
        self,
        spec: ClassSpec,
        min_points: int = 50,
        mode: Mode | str = Mode.OFFICIAL,
        iou_dtype: type = np.float64,
    ) -> None:
        self.spec = spec
        self.min_points = int(min_points)
        self.mode = as_mode(mode)
        self.iou_dtype = np.dtype(iou_dtype)
        c = spec.n_classes
        self._ignored = spec.mask(spec.ignore)
        self._include = ~self._ignored
        self.conf = np.zeros((c, c), dtype=np.int64)
        self.tp = np.zeros(c, dtype=np.int64)
        self.fp = np.zeros(c, dtype=np.int64)
        self.fn = np.zeros(c, dtype=np.int64)
        self._iou = [ExactSum() for _ in range(c)]
        self.frames = 0

    # -- accumulation ---------------------------------------------------------------------
    def add(self, cells: Cells) -> FramePQ:
        """Add one frame given its cells; returns that frame's own counts."""
        frame = self.measure(cells)
        self.add_frame(frame)
        return frame

    def measure(self, cells: Cells) -> FramePQ:
        """One frame's counts (matching, confusion) without adding them (the state is unchanged)."""
        c = self.spec.n_classes
        if cells.count.size and (max(cells.gt_cls.max(), cells.pred_cls.max()) >= c):
            raise ValueError(f"class ids must be < {c}")
        conf = np.bincount(cells.pred_cls * c + cells.gt_cls, weights=cells.count, minlength=c * c)
        conf = conf.astype(np.int64).reshape(c, c)
        cl = cells.select(~self._ignored[cells.gt_cls])
        tp, fp, fn, iou_sum, matches = self._match(cl)
        return FramePQ(tp, fp, fn, iou_sum, conf, cl.n_points, matches)

    def add_frame(self, frame: FramePQ) -> None:
        """Add a frame's counts computed by another accumulator with the same settings."""
        self.conf += frame.conf
        self.tp += frame.tp
        self.fp += frame.fp
        self.fn += frame.fn
        for k in np.flatnonzero(frame.iou_sum):
            self._iou[k].add(frame.iou_sum[k])
        self.frames += 1

    def _match(self, cl: Cells) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, Matches]:
        c = self.spec.n_classes
        gm = self._include[cl.gt_cls]
        pm = self._include[cl.pred_cls]
        # ground-truth segments: cells are sorted by gt label, so segments are runs
        g_lab = cl.gt[gm]
        g_new = np.concatenate(([True], g_lab[1:] != g_lab[:-1])) if g_lab.size else np.zeros(0, bool)
        g_seg = np.cumsum(g_new) - 1
        g_area = np.bincount(g_seg, weights=cl.count[gm]).astype(np.int64)
        g_cls = cl.gt_cls[gm][g_new]
        p_keys, p_seg = np.unique(cl.pred[pm], return_inverse=True)
        p_area = np.bincount(p_seg, weights=cl.count[pm], minlength=p_keys.size).astype(np.int64)
        p_cls = np.zeros(p_keys.size, dtype=np.int64)
        p_cls[p_seg] = cl.pred_cls[pm]
        # intersections: same class on both sides
        g_idx = np.full(cl.count.size, -1, dtype=np.int64)
        g_idx[gm] = g_seg
        p_idx = np.full(cl.count.size, -1, dtype=np.int64)
        p_idx[pm] = p_seg
        im = gm & pm & (cl.gt_cls == cl.pred_cls)
        if self.mode is Mode.OFFICIAL and im.any() and cl.gt[im].max() >= _OVERFLOW_LABEL:
            bad = int(cl.gt[im][cl.gt[im] >= _OVERFLOW_LABEL][0])
            raise ReferenceOverflowError(
                f"ground-truth label {bad:#010x} (instance id {bad >> 16}) overflows the reference "
                "evaluator's int64 pair key (instance ids ≥ 32768); score in 'corrected' mode"
            )
        gi, pi, inter = g_idx[im], p_idx[im], cl.count[im]
        union = g_area[gi] + p_area[pi] - inter
        dt = self.iou_dtype.type
        iou = inter.astype(dt) / union.astype(dt)
        match = iou > 0.5
        cls_m = cl.gt_cls[im][match]
        iou_m = iou[match]
        tp = np.bincount(cls_m, minlength=c).astype(np.int64)
        iou_sum = np.zeros(c, dtype=np.float64)
        for k in np.unique(cls_m):
            # same values, same order (gt label, then pred label) and same np.sum as the reference
            iou_sum[k] = float(np.sum(iou_m[cls_m == k]))
        g_hit = np.zeros(g_area.size, dtype=bool)
        g_hit[gi[match]] = True
        p_hit = np.zeros(p_area.size, dtype=bool)
        p_hit[pi[match]] = True
        fn = np.bincount(g_cls[~g_hit & (g_area >= self.min_points)], minlength=c).astype(np.int64)
        fp = np.bincount(p_cls[~p_hit & (p_area >= self.min_points)], minlength=c).astype(np.int64)
        matches = Matches(cls_m, cl.gt[im][match], cl.pred[im][match], iou_m)
        return tp, fp, fn, iou_sum, matches

    def merge(self, other: PanopticAccumulator) -> PanopticAccumulator:
        """Add ``other``'s counts into this accumulator (same spec, min_points, mode); returns self."""
        if (other.spec, other.min_points, other.mode) != (self.spec, self.min_points, self.mode):
            raise ValueError("cannot merge accumulators with different classes, min_points or mode")
        self.conf += other.conf
        self.tp += other.tp
        self.fp += other.fp
        self.fn += other.fn
        for mine, theirs in zip(self._iou, other._iou, strict=True):
            mine.merge(theirs)
        self.frames += other.frames
        return self

    # -- state --------------------------------------------------------------------------------
    def state(self, prefix: str = "") -> dict[str, np.ndarray]:
        """The exact state as named arrays under ``prefix`` (``np.savez`` ready)."""
        return {
            f"{prefix}conf": self.conf.copy(),
            f"{prefix}tp": self.tp.copy(),
            f"{prefix}fp": self.fp.copy(),
            f"{prefix}fn": self.fn.copy(),
            **sums_state(self._iou, f"{prefix}partials"),
            f"{prefix}frames": np.array(self.frames, dtype=np.int64),
        }

    def restore(self, state: dict[str, np.ndarray], prefix: str = "") -> PanopticAccumulator:
        """Load a :meth:`state` of an accumulator with the same classes; returns self.

        Raises:
            ValueError: the state has another number of classes.
        """
        conf = np.asarray(state[f"{prefix}conf"])
        if conf.shape != self.conf.shape:
            raise ValueError(f"state has {conf.shape[0]} classes, label map {self.conf.shape[0]}")
        self.conf[:] = conf
        self.tp[:] = state[f"{prefix}tp"]
        self.fp[:] = state[f"{prefix}fp"]
        self.fn[:] = state[f"{prefix}fn"]
        self._iou = sums_from_state(state, f"{prefix}partials")
        self.frames = int(state[f"{prefix}frames"])
        return self

    # -- results --------------------------------------------------------------------------
    @property
    def iou_sum(self) -> np.ndarray:
        """``(C,) float64`` per-class sum of matched IoUs."""
        return np.array([s.value for s in self._iou], dtype=np.float64)

    def class_iou(self) -> np.ndarray:
        """``(C,) float64`` semantic IoU per class (ignored ground-truth columns zeroed)."""
        return semantic_iou(self.conf, self.spec.ignore)[0]

    def result(self) -> PQResult:
        """The PQ family and mIoU so far (does not change the state)."""
        spec = self.spec
        sq, rq, pq = pq_terms(self.iou_sum, self.tp, self.fp, self.fn)
        iou = self.class_iou()
        inc = spec.include
        th, st = np.array(spec.things, dtype=np.int64), np.array(spec.stuff, dtype=np.int64)
        per_class = {
            spec.names[k]: ClassScore(
                float(pq[k]),
                float(sq[k]),
                float(rq[k]),
                float(iou[k]),
                int(self.tp[k]),
                int(self.fp[k]),
                int(self.fn[k]),
                int(k) in spec.things,
            )
            for k in inc
        }
        return PQResult(
            mode=self.mode,
            pq=_mean(pq[inc]),
            sq=_mean(sq[inc]),
            rq=_mean(rq[inc]),
            pq_dagger=_mean(np.concatenate([pq[th], iou[st]])),
            pq_things=_mean(pq[th]),
            sq_things=_mean(sq[th]),
            rq_things=_mean(rq[th]),
            pq_stuff=_mean(pq[st]),
            sq_stuff=_mean(sq[st]),
            rq_stuff=_mean(rq[st]),
            miou=_mean(iou[inc]),
            per_class=per_class,
        )


def pq_terms(
    iou_sum: np.ndarray, tp: np.ndarray, fp: np.ndarray, fn: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-class ``(SQ, RQ, PQ)``, ``(C,) float64`` each, with the reference's eps guards."""
    tp = tp.astype(np.float64)
    sq = iou_sum.astype(np.float64) / np.maximum(tp, EPS)
    rq = tp / np.maximum(tp + 0.5 * fp.astype(np.float64) + 0.5 * fn.astype(np.float64), EPS)
    return sq, rq, sq * rq


def semantic_iou(conf: np.ndarray, ignore: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Per-class IoU and union from a ``conf[pred, gt]`` matrix whose ignored gt columns are zeroed.

    Returns:
        ``(iou, union)``, ``(C,) float64`` each; ``union`` is before the eps guard.
    """
    m = conf.astype(np.float64)
    m[:, list(ignore)] = 0
    tp = m.diagonal()
    fp = m.sum(axis=1) - tp
    fn = m.sum(axis=0) - tp
    union = tp + fp + fn
    return tp / np.maximum(union, EPS), union


def _mean(x: np.ndarray) -> float:
    return float(x.mean()) if x.size else float("nan")

"""Panoptic nuScenes tracking metrics: PQ (float32 IoUs), LSTQ variant, PTQ, sPTQ, TQ and PAT.

Semantics follow nuscenes-devkit's ``PanopticTrackingEval`` (docs/metrics.md, "Panoptic nuScenes"):

* PQ as ``PanopticEval`` but with float32 per-pair IoUs (as that evaluator computes them);
* PTQ/sPTQ: per thing class, an *ID switch* is a ground-truth segment matched (IoU > 0.5) in two
  consecutive frames of a scene to different predicted labels; PTQ_c = (ΣIoU − IDS)/TP · RQ_c,
  sPTQ subtracts the IoUs of the switching matches instead; means over classes with ground truth;
* TQ/PAT: per ground-truth thing instance (> min_points in a frame), the sequence of
  class-agnostic predicted labels matched frame by frame; PAT = 2·PQ·TQ / (PQ + TQ);
* LSTQ: the ``nuscenes`` variant of :class:`~.lstq.LSTQAccumulator`.

Streaming: per scene only the last frame's matches and per-instance track summaries are kept.
``merge(other)`` appends ``other``'s frames after this accumulator's for scenes they share, so
split a scene into consecutive chunks and merge them in temporal order.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from .cells import Cells, CountTable, ExactSum, sums_from_state, sums_state
from .decode import ClassSpec
from .lstq import LSTQAccumulator
from .panoptic import EPS, Matches, PanopticAccumulator, pq_terms
from .report import Mode

_NONE = 1  # the reference's "unmatched" entry (labels are shifted by +1, so label 0 collides)


@dataclass
class _Track:
    """Summary of one ground-truth instance's per-frame matched predictions (shifted labels)."""

    length: int
    switches: int
    first: int
    last: int
    counts: dict[int, int] = field(default_factory=dict)

    def extend(self, other: _Track) -> None:
        self.switches += other.switches + _switch(self.last, other.first)
        self.length += other.length
        self.last = other.last
        for k, v in other.counts.items():
            self.counts[k] = self.counts.get(k, 0) + v


def _switch(prev: int, cur: int) -> int:
    return int(cur != prev or prev == _NONE)


@dataclass
class _Scene:
    first: Matches | None = None
    last: Matches | None = None
    pred_frames: CountTable = field(default_factory=CountTable)  # shifted pred label -> frames
    tracks: dict[int, _Track] = field(default_factory=dict)  # gt label -> track


@dataclass(frozen=True)
class TrackingResult:
    """Panoptic nuScenes tracking metrics (official semantics)."""

    mode: Mode
    pat: float
    pq: float
    tq: float
    ptq: float
    sptq: float
    lstq: float
    s_assoc: float
    s_cls: float
    miou: float
    per_class_ptq: dict[str, float]
    per_class_sptq: dict[str, float]

    def to_dict(self) -> dict[str, object]:
        """JSON-ready values (NaN/inf as null)."""
        out: dict[str, object] = {"mode": str(self.mode)}
        for key, value in asdict(self).items():
            if isinstance(value, float):
                out[key] = value if math.isfinite(value) else None
            elif isinstance(value, dict):
                out[key] = {k: (v if math.isfinite(v) else None) for k, v in value.items()}
        return out


class PanopticTrackingAccumulator:
    """Streaming Panoptic nuScenes tracking scorer over frames given as cells (see ``NuScenesCells``).

    Args:
        spec: the Panoptic nuScenes classes.
        min_points: 15 for the benchmark.
    """

    def __init__(self, spec: ClassSpec, min_points: int = 15) -> None:
        self.spec = spec
        self.min_points = int(min_points)
        self.mode = Mode.OFFICIAL
        c = spec.n_classes
        self._thing = spec.mask(spec.things)
        self._ignored = spec.mask(spec.ignore)
        self.pq = PanopticAccumulator(spec, min_points, Mode.OFFICIAL, iou_dtype=np.float32)
        self.lstq = LSTQAccumulator(spec, min_points, Mode.OFFICIAL, variant="nuscenes")
        self.ids = np.zeros(c, dtype=np.int64)
        self._soft = [ExactSum() for _ in range(c)]
        self.scenes: dict[str, _Scene] = {}

    # -- accumulation ---------------------------------------------------------------------
    def add(self, cells: Cells, scene: str) -> None:
        """Add the next frame (in time) of ``scene``."""
        fpq = self.pq.add(cells)
        self.lstq.add(cells, scene)
        s = self.scenes.setdefault(str(scene), _Scene())
        cur = self._thing_matches(fpq.matches)
        if s.last is not None:
            self._count_switches(s.last, cur)
        else:
            s.first = cur
        s.last = cur
        self._add_tracks(cells.select(~self._ignored[cells.gt_cls]), s)

    def _thing_matches(self, m: Matches) -> Matches:
        keep = self._thing[m.cls]
        order = np.argsort(m.gt[keep], kind="stable")
        return Matches(m.cls[keep][order], m.gt[keep][order], m.pred[keep][order], m.iou[keep][order])

    def _count_switches(self, prev: Matches, cur: Matches) -> None:
        for k in np.unique(cur.cls):
            p, c = prev.cls == k, cur.cls == k
            _, ip, ic = np.intersect1d(prev.gt[p], cur.gt[c], return_indices=True)
            changed = prev.pred[p][ip] != cur.pred[c][ic]
            if not changed.any():
                continue
            self.ids[k] += int(changed.sum())
            soft = np.float32(0.0)
            for v in cur.iou[c][ic][changed]:  # float32, in gt-label order, as the reference
                soft = np.float32(soft + v)
            self._soft[k].add(float(soft))

    def _add_tracks(self, cl: Cells, s: _Scene) -> None:
        p_keys, p_inv = np.unique(cl.pred, return_inverse=True)
        p_area = np.bincount(p_inv, weights=cl.count, minlength=p_keys.size).astype(np.int64)
        big = p_area > self.min_points
        s.pred_frames.add(p_keys[big] + np.uint64(1), np.ones(int(big.sum()), dtype=np.int64))
        gm = self._thing[cl.gt_cls]
        g_keys, g_inv = np.unique(cl.gt[gm], return_inverse=True)
        g_area = np.bincount(g_inv, weights=cl.count[gm], minlength=g_keys.size).astype(np.int64)
        union = g_area[g_inv] + p_area[p_inv[gm]] - cl.count[gm]
        iou = cl.count[gm].astype(np.float32) / union.astype(np.float32)
        hit = (iou > 0.5) & (g_area[g_inv] > self.min_points)
        entry = np.full(g_keys.size, _NONE, dtype=np.int64)
        entry[g_inv[hit]] = cl.pred[gm][hit].astype(np.int64) + 1
        qualified = g_area > self.min_points
        for g, e in zip(g_keys[qualified].tolist(), entry[qualified].tolist(), strict=True):
            t = _Track(1, 0, e, e, {e: 1})
            if g in s.tracks:
                s.tracks[g].extend(t)
            else:
                s.tracks[g] = t

    def merge(self, other: PanopticTrackingAccumulator) -> PanopticTrackingAccumulator:
        """Append ``other``'s frames after this accumulator's (scene by scene); returns self."""
        if (other.spec, other.min_points) != (self.spec, self.min_points):
            raise ValueError("cannot merge accumulators with different classes or min_points")
        self.pq.merge(other.pq)
        self.lstq.merge(other.lstq)
        self.ids += other.ids
        for mine, theirs in zip(self._soft, other._soft, strict=True):
            mine.merge(theirs)
        for name, o in other.scenes.items():
            s = self.scenes.get(name)
            if s is None:
                self.scenes[name] = _copy_scene(o)
                continue
            if s.last is not None and o.first is not None:
                self._count_switches(s.last, o.first)
            s.last = o.last if o.last is not None else s.last
            s.pred_frames.merge(o.pred_frames)
            for g, t in o.tracks.items():
                if g in s.tracks:
                    s.tracks[g].extend(t)
                else:
                    s.tracks[g] = _Track(t.length, t.switches, t.first, t.last, dict(t.counts))
        return self

    # -- state --------------------------------------------------------------------------------
    def state(self, prefix: str = "") -> dict[str, np.ndarray]:
        """The exact state as named arrays under ``prefix`` (scenes and their tracks in insertion
        order, since TQ sums over them in that order)."""
        out = {**self.pq.state(f"{prefix}pq_"), f"{prefix}ids": self.ids.copy()}
        out.update(sums_state(self._soft, f"{prefix}soft"))
        out.update(self.lstq.state(f"{prefix}lstq_"))
        scenes = list(self.scenes)
        out[f"{prefix}scenes"] = np.array(scenes, dtype=str)
        for i, name in enumerate(scenes):
            s, key = self.scenes[name], f"{prefix}scene{i}_"
            out.update(_matches_state(s.first, f"{key}first"))
            out.update(_matches_state(s.last, f"{key}last"))
            out.update(s.pred_frames.state(f"{key}pf"))
            gts = list(s.tracks)
            tracks = [s.tracks[g] for g in gts]
            out[f"{key}tracks"] = np.array(
                [[g, t.length, t.switches, t.first, t.last] for g, t in zip(gts, tracks, strict=True)],
                dtype=np.int64,
            ).reshape(-1, 5)
            counts = [(j, k, v) for j, t in enumerate(tracks) for k, v in sorted(t.counts.items())]
            out[f"{key}counts"] = np.array(counts, dtype=np.int64).reshape(-1, 3)
        return out

    def restore(self, state: dict[str, np.ndarray], prefix: str = "") -> PanopticTrackingAccumulator:
        """Load a :meth:`state` into this (fresh) accumulator of the same classes; returns self."""
        self.pq.restore(state, f"{prefix}pq_")
        self.ids[:] = state[f"{prefix}ids"]
        self._soft = sums_from_state(state, f"{prefix}soft")
        self.lstq.restore(state, f"{prefix}lstq_")
        for i, name in enumerate(np.asarray(state[f"{prefix}scenes"]).reshape(-1).tolist()):
            key = f"{prefix}scene{i}_"
            s = _Scene(_restore_matches(state, f"{key}first"), _restore_matches(state, f"{key}last"))
            s.pred_frames = CountTable.from_state(state, f"{key}pf")
            rows = np.asarray(state[f"{key}tracks"]).reshape(-1, 5).tolist()
            tracks = [_Track(int(n), int(sw), int(a), int(b), {}) for _, n, sw, a, b in rows]
            for j, k, v in np.asarray(state[f"{key}counts"]).reshape(-1, 3).tolist():
                tracks[j].counts[int(k)] = int(v)
            s.tracks = {int(r[0]): t for r, t in zip(rows, tracks, strict=True)}
            self.scenes[str(name)] = s
        return self

    # -- results --------------------------------------------------------------------------
    def tq(self) -> float:
        """Mean tracking quality over ground-truth instance tracks (NaN without any)."""
        total, norm = 0.0, 0
        for s in self.scenes.values():
            pk, pv = s.pred_frames.items()
            for t in s.tracks.values():
                uid = np.array(sorted(k for k in t.counts if k != _NONE), dtype=np.int64)
                cnt = np.array([t.counts[k] for k in uid.tolist()], dtype=np.int64)
                fp = np.zeros(uid.size, dtype=np.int64)
                if pk.size:
                    idx = np.minimum(np.searchsorted(pk, uid.astype(np.uint64)), pk.size - 1)
                    found = pk[idx] == uid.astype(np.uint64)
                    fp[found] = pv[idx[found]] - cnt[found]
                aq = np.sum(cnt**2 / np.double(t.length + fp)) / np.double(t.length)
                is_ = 1.0 - t.switches / np.double(t.length - 1) if t.length > 1 else 1.0
                total += np.sqrt(aq * is_)
                norm += 1
        return float(total / norm) if norm else float("nan")

    def result(self) -> TrackingResult:
        spec = self.spec
        inc = spec.include
        _, _, pq_all = pq_terms(self.pq.iou_sum, self.pq.tp, self.pq.fp, self.pq.fn)
        pq = float(pq_all[inc].mean())
        tq = self.tq()
        pat = 2 * pq * tq / (pq + tq) if pq + tq > 0 else float("nan")
        tp = self.pq.tp.astype(np.float64)
        denom = np.maximum(tp, EPS)
        rq_ = tp / np.maximum(tp + 0.5 * self.pq.fp + 0.5 * self.pq.fn, EPS)
        soft = np.array([s.value for s in self._soft])
        ptq_all = ((self.pq.iou_sum - self.ids) / denom) * rq_
        sptq_all = ((self.pq.iou_sum - soft) / denom) * rq_
        valid = np.zeros(spec.n_classes, dtype=bool)
        valid[inc] = (tp + self.pq.fn)[inc] > 0.5
        nan = float("nan")
        lq = self.lstq.result()
        return TrackingResult(
            mode=self.mode,
            pat=pat,
            pq=pq,
            tq=tq,
            ptq=float(ptq_all[valid].mean()) if valid.any() else nan,
            sptq=float(sptq_all[valid].mean()) if valid.any() else nan,
            lstq=lq.lstq,
            s_assoc=lq.s_assoc,
            s_cls=lq.s_cls,
            miou=self.pq.result().miou,
            per_class_ptq={spec.names[k]: float(ptq_all[k]) for k in inc},
            per_class_sptq={spec.names[k]: float(sptq_all[k]) for k in inc},
        )


def _matches_state(m: Matches | None, key: str) -> dict[str, np.ndarray]:
    if m is None:
        return {}
    return {f"{key}_{f}": np.asarray(getattr(m, f)).copy() for f in ("cls", "gt", "pred", "iou")}


def _restore_matches(state: dict[str, np.ndarray], key: str) -> Matches | None:
    if f"{key}_cls" not in state:
        return None
    return Matches(*(np.asarray(state[f"{key}_{f}"]) for f in ("cls", "gt", "pred", "iou")))


def _copy_scene(o: _Scene) -> _Scene:
    s = _Scene(o.first, o.last)
    s.pred_frames.merge(o.pred_frames)
    s.tracks = {g: _Track(t.length, t.switches, t.first, t.last, dict(t.counts)) for g, t in o.tracks.items()}
    return s


__all__ = ["PanopticTrackingAccumulator", "TrackingResult"]

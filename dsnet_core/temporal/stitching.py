"""Cross-volume instance-id stitching (4D-DS-Net): one id per object over a whole sequence.

A 4D volume is k consecutive scans fused into one cloud; its instance ids are local to it.
Consecutive volumes overlap in at least one frame. On the overlap frames the previous
volume's *tracked* ids are matched with the new volume's raw ids by point IoU over thing
points; a pair with IoU > ``min_iou`` (0.5, strict) is the same object and the raw id inherits
the tracked id. The assignment is one-to-one (Hungarian on IoU, then the threshold). Every
other raw id gets a fresh id from one counter per sequence (the reference code restarts from the
previous frame's maximum), so an id is not reused after its object has left until the 65 535 ids
of a label are exhausted; then an id unused for more than ``reuse_after`` frames is handed out
again (:class:`~dsnet_core.temporal.ids.IdPool`; never one still carried). Inside the stitcher a
track is named by its key ``id | generation << 16`` (:mod:`dsnet_core.temporal.ids`); its labels
carry the id.

Ownership rule: **a frame is owned by the first volume that contains it.** Its final label is
written once, when that volume is stitched, and never changes. Reasons: (1) streaming — a
frame is final as soon as it is first seen, nothing waits for a later volume, and a resumed run
never rewrites a written frame; (2) anchoring — the new volume's predictions on overlap frames
serve only to match ids, so every written id chain starts from labels already written; (3) the
state to carry is just the previous volume's tracked thing points on its frames that a later
volume may share. Volumes must advance: each one starts after the previous one's first frame
and does not end before the previous one's last frame; a frame in no volume is never emitted.

Overlap 0 (k = 1, the 3D pipeline) is allowed: nothing matches, so ids are per-frame fresh.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from dsnet_core.errors import DsnetError
from dsnet_core.labels import LabelMap, load_label_map
from dsnet_core.temporal.ids import REUSE_AFTER, IdPool, key_generation, key_id
from dsnet_core.temporal.ids import pack as _pack
from dsnet_core.temporal.ids import unpack as _unpack

log = logging.getLogger(__name__)

STATE_VERSION = 3  # 2: no id pool (ids never reused)


class StitchError(DsnetError):
    """Volumes that cannot be stitched (out of order, inconsistent arrays)."""


@dataclass(frozen=True)
class VolumeLabels:
    """The panoptic result of one 4D volume (after ``fuse``): the stitcher's input.

    Attributes:
        frames: ``(k,) int64`` absolute frame indices the volume covers, ascending and contiguous
            (frames without points are listed too).
        source_frame: ``(N,) int`` absolute frame index of each point (``align``'s array).
        source_index: ``(N,) int`` index of each point in its source scan (``align``'s array).
        semantic: ``(N,) int`` train ids (0 = ignore).
        instance: ``(N,) int`` raw instance ids, 0 = none; local to this volume.
        thing: ``(N,) bool`` thing mask, or None to derive it from ``semantic``.
        frame_sizes: ``(k,) int64`` points of each source scan, or None when every scan's points
            are all present (sizes = max point index + 1). Points absent from the volume get 0.
        scores: raw id -> instance confidence in [0, 1] (fusion's), or None.
    """

    frames: np.ndarray
    source_frame: np.ndarray
    source_index: np.ndarray
    semantic: np.ndarray
    instance: np.ndarray
    thing: np.ndarray | None = None
    frame_sizes: np.ndarray | None = None
    scores: Mapping[int, float] | None = None


@dataclass(frozen=True)
class FinishedFrame:
    """A frame's final label: ``label`` is ``(n,) uint32`` raw semantic | id << 16."""

    frame: int
    label: np.ndarray


@dataclass(frozen=True)
class TrackTable:
    """Per-track summary (one row per track with written points) and a long points-per-frame table.

    A track is one hand-out of an id: once ids are reused (:mod:`dsnet_core.temporal.ids`) an id
    has several rows, told apart by ``generation`` and by their frames (which never overlap).

    Attributes:
        id, generation, semantic, first_frame, last_frame, n_points, n_frames: ``(T,) int64``,
            rows sorted by (id, generation); ``semantic`` is the majority train id over the
            track's written points (ties: lowest id).
        confidence: ``(T,) float64`` point-weighted mean of the volumes' instance scores (NaN
            when no scores were given).
        min_link_iou: ``(T,) float64`` lowest IoU that carried the id into a later volume (NaN
            when the id never crossed a volume boundary).
        frame_track, frame_index, frame_points: ``(R,) int64`` long table: points of a track
            (its key ``id | generation << 16``) in a frame.
    """

    id: np.ndarray
    generation: np.ndarray
    semantic: np.ndarray
    first_frame: np.ndarray
    last_frame: np.ndarray
    n_points: np.ndarray
    n_frames: np.ndarray
    confidence: np.ndarray
    min_link_iou: np.ndarray
    frame_track: np.ndarray
    frame_index: np.ndarray
    frame_points: np.ndarray

    def columns(self, label_map: LabelMap) -> dict[str, list]:
        """The columns of the store's ``tracks`` table: one row per track, per-frame counts as
        lists (``frames``, ``frame_points``) and ``raw_class`` through ``learning_map_inv``."""
        keys = (self.id | (self.generation << 16)).tolist()
        per: dict[int, tuple[list[int], list[int]]] = {t: ([], []) for t in keys}
        for t, f, n in zip(
            self.frame_track.tolist(), self.frame_index.tolist(), self.frame_points.tolist(), strict=True
        ):
            per[t][0].append(f)
            per[t][1].append(n)
        return {
            "id": self.id.tolist(),
            "generation": self.generation.tolist(),
            "class_id": self.semantic.tolist(),
            "raw_class": label_map.to_raw(self.semantic).tolist(),
            "first_frame": self.first_frame.tolist(),
            "last_frame": self.last_frame.tolist(),
            "n_points": self.n_points.tolist(),
            "n_frames": self.n_frames.tolist(),
            "confidence": self.confidence.tolist(),
            "min_link_iou": self.min_link_iou.tolist(),
            "frames": [per[t][0] for t in keys],
            "frame_points": [per[t][1] for t in keys],
        }


@dataclass
class _Track:
    classes: dict[int, int] = field(default_factory=dict)
    frames: dict[int, int] = field(default_factory=dict)
    conf_sum: float = 0.0
    conf_w: int = 0
    min_link_iou: float = math.nan


def overlap_iou(
    prev_keys: np.ndarray, prev_ids: np.ndarray, new_keys: np.ndarray, new_ids: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Point IoU between two labelings of the same points.

    Args:
        prev_keys, new_keys: ``(P,)``/``(Q,) int64`` unique point keys (frame << 32 | point).
        prev_ids, new_ids: ``(P,)``/``(Q,) int64`` ids (> 0) of those points.

    Returns:
        ``(prev_uniq (A,), new_uniq (B,), iou (A, B) float64)``.
    """
    pa, pinv = np.unique(prev_ids, return_inverse=True)
    nb, ninv = np.unique(new_ids, return_inverse=True)
    iou = np.zeros((pa.size, nb.size))
    if pa.size == 0 or nb.size == 0:
        return pa, nb, iou
    _, ip, iq = np.intersect1d(prev_keys, new_keys, assume_unique=True, return_indices=True)
    inter = np.zeros_like(iou)
    np.add.at(inter, (pinv[ip], ninv[iq]), 1.0)
    size_a = np.bincount(pinv, minlength=pa.size).astype(np.float64)
    size_b = np.bincount(ninv, minlength=nb.size).astype(np.float64)
    iou = inter / (size_a[:, None] + size_b[None, :] - inter)
    return pa, nb, iou


def match_ids(iou: np.ndarray, min_iou: float = 0.5) -> list[tuple[int, int]]:
    """One-to-one matching: Hungarian assignment maximising total IoU, then IoU > ``min_iou``.

    With ``min_iou >= 0.5`` on two partitions the matching is unique (a set cannot overlap two
    disjoint sets by more than half each), so greedy and Hungarian agree; below 0.5 they differ.

    Returns:
        ``(row, col)`` pairs, sorted by row.
    """
    if iou.size == 0:
        return []
    rows, cols = linear_sum_assignment(iou, maximize=True)
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if iou[r, c] > min_iou]


def _keys(frame: np.ndarray, point: np.ndarray) -> np.ndarray:
    return (frame.astype(np.int64) << 32) | point.astype(np.int64)


class Stitcher:
    """Streaming stitcher for one sequence: ``add_volume`` returns the frames it finishes.

    Args:
        label_map: dataset label map (default SemanticKITTI) for ``learning_map_inv`` and things.
        min_iou: a match needs IoU strictly above this (the paper's 0.5).
        reuse_after: once the 65 535 ids are exhausted, an id is handed out again only after this
            many frames (frame numbers of the volumes) without it.
    """

    def __init__(
        self, label_map: LabelMap | None = None, *, min_iou: float = 0.5, reuse_after: int = REUSE_AFTER
    ) -> None:
        self.label_map = label_map or load_label_map("semantic-kitti")
        self.min_iou = float(min_iou)
        self.ids = IdPool(reuse_after)
        self.n_volumes = 0
        self._first: int | None = None  # first frame of the previous volume
        self._last: int | None = None  # last frame written
        self._carry_keys = np.zeros(0, np.int64)  # previous volume's tracked thing points
        self._carry_ids = np.zeros(0, np.int64)  # their track keys
        self._tracks: dict[int, _Track] = {}  # by track key

    @property
    def next_id(self) -> int:
        """The id the counter hands out next (beyond 65 535: ids are reused)."""
        return self.ids.next_id

    # ------------------------------------------------------------------ stitching
    def add_volume(self, volume: VolumeLabels) -> list[FinishedFrame]:
        """Stitch one volume; return the frames it owns (first volume containing them), in order.

        Raises:
            StitchError: a volume out of order, inconsistent arrays.
            IdSpaceExhausted: all 65 535 ids were used within the last ``reuse_after`` frames.
        """
        frames, frame, point, sem, inst, thing, sizes = self._check(volume)
        has_id = thing & (inst > 0)
        keys = _keys(frame, point)

        # 1. match raw ids with the previous volume's tracked ids on the overlap frames
        links: dict[int, tuple[int, float]] = {}
        if self._carry_keys.size and has_id.any():
            on_overlap = has_id & (frame <= self._last)
            shared = (self._carry_keys >> 32) >= frames[0]
            pa, nb, iou = overlap_iou(
                self._carry_keys[shared], self._carry_ids[shared], keys[on_overlap], inst[on_overlap]
            )
            for r, c in match_ids(iou, self.min_iou):
                links[int(nb[c])] = (int(pa[r]), float(iou[r, c]))
        mapping: dict[int, int] = {}  # raw id -> track key
        first, last = int(frames[0]), int(frames[-1])
        for raw in np.unique(inst[has_id]).tolist():
            mapping[raw] = links[raw][0] if raw in links else self.ids.take(first, until=last)
        self.ids.touch(mapping.values(), last)  # in use (matched or carried) through this volume
        raws = np.array(sorted(mapping), dtype=np.int64)
        tracked = np.zeros(inst.shape, np.int64)
        if raws.size:
            lut = np.array([mapping[r] for r in raws.tolist()], dtype=np.int64)
            tracked[has_id] = lut[np.searchsorted(raws, inst[has_id])]
        for tid, value in links.values():
            t = self._tracks.setdefault(tid, _Track())
            t.min_link_iou = value if math.isnan(t.min_link_iou) else min(t.min_link_iou, value)

        # 2. write the frames this volume owns
        owned_from = frames[0] if self._last is None else max(self._last + 1, int(frames[0]))
        out = []
        raw_sem = self.label_map.to_raw(sem)
        order = np.argsort(frame, kind="stable")
        bounds = [*np.searchsorted(frame[order], frames, side="left").tolist(), order.size]
        for j, f in enumerate(frames.tolist()):
            if f < owned_from:
                continue
            sel = order[bounds[j] : bounds[j + 1]]
            label = np.zeros(int(sizes[j]), np.uint32)
            label[point[sel]] = raw_sem[sel] | (key_id(tracked[sel]).astype(np.uint32) << 16)
            self._account(f, tracked[sel], sem[sel], inst[sel], volume.scores)
            out.append(FinishedFrame(frame=f, label=label))

        # 3. carry the tracked thing points of frames a later volume may share
        keep = has_id & (frame > frames[0])
        order = np.argsort(keys[keep], kind="stable")  # sorted: the state encodes it by deltas
        self._carry_keys, self._carry_ids = keys[keep][order], tracked[keep][order]
        self._first = int(frames[0])
        self._last = int(frames[-1]) if self._last is None else max(self._last, int(frames[-1]))
        self.n_volumes += 1
        return out

    def _account(
        self, f: int, ids: np.ndarray, sem: np.ndarray, raw: np.ndarray, scores: Mapping[int, float] | None
    ) -> None:
        nz = ids > 0
        if not nz.any():
            return
        tids = ids[nz]
        keys, counts = np.unique((tids << 32) | sem[nz].astype(np.int64), return_counts=True)
        for key, n in zip(keys.tolist(), counts.tolist(), strict=True):
            t = self._tracks.setdefault(key >> 32, _Track())
            c = key & 0xFFFFFFFF
            t.classes[c] = t.classes.get(c, 0) + n
            t.frames[f] = t.frames.get(f, 0) + n
        if scores:
            keys, counts = np.unique((tids << 32) | raw[nz].astype(np.int64), return_counts=True)
            for key, n in zip(keys.tolist(), counts.tolist(), strict=True):
                score = scores.get(key & 0xFFFFFFFF)
                if score is not None and math.isfinite(score):
                    self._tracks[key >> 32].conf_sum += float(score) * n
                    self._tracks[key >> 32].conf_w += n

    def _check(self, v: VolumeLabels) -> tuple[np.ndarray, ...]:
        frames = np.asarray(v.frames, dtype=np.int64)
        frame = np.asarray(v.source_frame, dtype=np.int64)
        point = np.asarray(v.source_index, dtype=np.int64)
        sem = np.asarray(v.semantic, dtype=np.int64)
        inst = np.asarray(v.instance, dtype=np.int64)
        n = frame.shape[0]
        if frames.ndim != 1 or frames.size == 0 or (np.diff(frames) != 1).any():
            raise StitchError(f"volume frames must be contiguous ascending indices, got {frames.tolist()}")
        for name, arr in (("source_index", point), ("semantic", sem), ("instance", inst)):
            if arr.shape != (n,):
                raise StitchError(f"volume '{name}' has shape {arr.shape}, expected ({n},) like 'frame'")
        if n and (frame.min() < frames[0] or frame.max() > frames[-1]):
            raise StitchError(f"point frame indices outside the volume's frames {frames.tolist()}")
        if self._first is not None and (frames[0] <= self._first or frames[-1] < self._last):
            raise StitchError(
                f"volume {frames.tolist()} does not advance past the previous one (first frame "
                f"{self._first}, last written {self._last}): volumes of one sequence, in order"
            )
        thing = self.label_map.is_thing()[sem] if v.thing is None else np.asarray(v.thing, dtype=bool)
        if v.frame_sizes is None:
            sizes = np.zeros(frames.size, np.int64)
            np.maximum.at(sizes, frame - frames[0], point + 1)
            if np.bincount(frame - frames[0], minlength=frames.size).tolist() != sizes.tolist():
                raise StitchError("without frame_sizes every scan's points 0..n-1 must be present once")
        else:
            sizes = np.asarray(v.frame_sizes, dtype=np.int64)
            if sizes.shape != frames.shape or (n and (point >= sizes[frame - frames[0]]).any()):
                raise StitchError("frame_sizes must give one size per frame, larger than its point indices")
        return frames, frame, point, sem, inst, thing, sizes

    # ------------------------------------------------------------------ outputs and state
    def track_table(self) -> TrackTable:
        """The tracks written so far (keys with at least one written point), sorted by (id, generation)."""
        keys = sorted((t for t, tr in self._tracks.items() if tr.frames), key=lambda t: (key_id(t), t))
        rows = [self._tracks[t] for t in keys]
        ft = [(t, f, n) for t in keys for f, n in sorted(self._tracks[t].frames.items())]
        i64 = np.int64
        key = np.array(keys, i64)
        return TrackTable(
            id=key_id(key),
            generation=key_generation(key),
            semantic=np.array([min(r.classes, key=lambda c: (-r.classes[c], c)) for r in rows], i64),
            first_frame=np.array([min(r.frames) for r in rows], i64),
            last_frame=np.array([max(r.frames) for r in rows], i64),
            n_points=np.array([sum(r.frames.values()) for r in rows], i64),
            n_frames=np.array([len(r.frames) for r in rows], i64),
            confidence=np.array([r.conf_sum / r.conf_w if r.conf_w else math.nan for r in rows]),
            min_link_iou=np.array([r.min_link_iou for r in rows], np.float64),
            frame_track=np.array([x[0] for x in ft], i64),
            frame_index=np.array([x[1] for x in ft], i64),
            frame_points=np.array([x[2] for x in ft], i64),
        )

    def state_dict(self) -> dict:
        """JSON-serialisable state; ``Stitcher.from_state`` continues identically.

        Size: O(thing points of the previous volume's shared frames + track-frames), no scan data;
        the carried points are delta-encoded and zlib-compressed (7 KB for the 16 000 points a
        4-scan VLP-32 volume carries, ~300 KB as JSON lists); the track statistics grow with the
        track-frames (~60 KB after 40 VLP-32 frames); the id pool is two compressed arrays of at
        most 65 535 ids (a few KB until ids are reused, ~200 KB after).
        """
        return {
            "version": STATE_VERSION,
            "label_map": self.label_map.name,
            "min_iou": self.min_iou,
            "ids": self.ids.state_dict(),
            "n_volumes": self.n_volumes,
            "first": self._first,
            "last": self._last,
            "carry_keys": _pack(np.diff(self._carry_keys, prepend=np.int64(0))),
            "carry_ids": _pack(self._carry_ids),
            "tracks": [
                {
                    "key": tid,
                    "classes": [[c, n] for c, n in sorted(t.classes.items())],
                    "frames": [[f, n] for f, n in sorted(t.frames.items())],
                    "conf_sum": t.conf_sum,
                    "conf_w": t.conf_w,
                    "min_link_iou": None if math.isnan(t.min_link_iou) else t.min_link_iou,
                }
                for tid, t in sorted(self._tracks.items())
            ],
        }

    @classmethod
    def from_state(cls, state: Mapping, label_map: LabelMap | None = None) -> Stitcher:
        """Rebuild a stitcher from :meth:`state_dict` output (e.g. after ``json.loads``).

        Raises:
            StitchError: unknown state version or a different label map.
        """
        version = state.get("version")
        if version != STATE_VERSION:
            raise StitchError(f"stitch state version {version!r}, expected {STATE_VERSION}")
        s = cls(label_map, min_iou=state["min_iou"])
        if s.label_map.name != state["label_map"]:
            raise StitchError(
                f"stitch state is for label map {state['label_map']!r}, not {s.label_map.name!r}"
            )
        s.ids, s.n_volumes = IdPool.from_state(state["ids"]), int(state["n_volumes"])
        s._first, s._last = state["first"], state["last"]
        s._carry_keys = np.cumsum(_unpack(state["carry_keys"]))
        s._carry_ids = _unpack(state["carry_ids"])
        for t in state["tracks"]:
            s._tracks[int(t["key"])] = _Track(
                classes={int(c): int(n) for c, n in t["classes"]},
                frames={int(f): int(n) for f, n in t["frames"]},
                conf_sum=float(t["conf_sum"]),
                conf_w=int(t["conf_w"]),
                min_link_iou=math.nan if t["min_link_iou"] is None else float(t["min_link_iou"]),
            )
        return s

"""Whole-sequence decisions about tracks, made once before any frame is refined: one class per
track, which short stuff-like tracks dissolve, which tracks are joined, and which stay put.

:func:`decide_tracks` turns a :class:`~dsnet_core.refine.history.TrackSummary` into
:class:`TrackDecisions`, a small table over the sequence's original ids that every block of
frames applies identically (it round-trips through JSON for a stage's plan).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dsnet_core.refine.classes import ClassSets
from dsnet_core.refine.history import TrackSummary
from dsnet_core.refine.joining import Join, chain_heads, join_tracks, keep_ids_apart
from dsnet_core.refine.motion import is_static
from dsnet_core.refine.params import TrackParams
from dsnet_core.temporal.ids import key_generation, key_id

_COLUMNS = ("ids", "final_id", "class_id", "static", "dissolved", "confidence", "first", "last", "n_frames",
            "n_points")  # fmt: skip
_KEPT = ("kept_key", "kept_frame", "kept_mask")
MAX_CLASSES = 63
"""The most train ids a label map may have here (kept classes are bit masks in an int64)."""


@dataclass(frozen=True)
class TrackDecisions:
    """What happens to each original track (arrays ``(T,)`` over ``ids``).

    Attributes:
        ids: the original tracks' keys ``id | generation << 16`` (the ids, until a temporal stage
            reused ids), sorted (int64).
        final_id: the key its points get: the earliest key of its chain of joins; 0 when dissolved.
        class_id: the train id all its points take (its joined track's vote; for a dissolved
            track its strongest stuff class); -1: its points keep their own classes (a track
            without any thing vote that does not dissolve).
        static: its (joined) track stays put: its points vote in, and (dissolved) take, the
            static vote. False for moving tracks and tracks of unknown motion.
        dissolved: it dissolved into the static vote.
        confidence: its confidence in [0, 1] (the temporal stage's, else its vote's thing share).
        first, last, n_frames, n_points: its sightings before the joins.
        kept_key, kept_frame, kept_mask: ``(K,) int64``, sorted by (frame, key): the sightings
            (track key, frame) whose points of the thing classes in ``kept_mask`` (bit ``c`` for
            train id ``c``) keep their own class instead of ``class_id`` (:func:`kept_classes`).
        joins: the joins made.
        refused: joins refused because they would have stretched a reused id over another track.
    """

    ids: np.ndarray
    final_id: np.ndarray
    class_id: np.ndarray
    static: np.ndarray
    dissolved: np.ndarray
    confidence: np.ndarray
    first: np.ndarray
    last: np.ndarray
    n_frames: np.ndarray
    n_points: np.ndarray
    kept_key: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    kept_frame: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    kept_mask: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    joins: tuple[Join, ...] = field(default_factory=tuple)
    refused: int = 0

    def lookup(self, inst: np.ndarray) -> np.ndarray:
        """``(N,) int64``: the row of each point's id in this table, -1 for 0 and unknown ids."""
        inst = np.asarray(inst, np.int64)
        if self.ids.size == 0:
            return np.full(inst.shape, -1, np.int64)
        pos = np.clip(np.searchsorted(self.ids, inst), 0, self.ids.size - 1)
        return np.where((inst > 0) & (self.ids[pos] == inst), pos, -1)

    def gather(self, column: str, row: np.ndarray, fill) -> np.ndarray:
        """``column`` at rows ``row`` (from :meth:`lookup`), ``fill`` where a row is -1."""
        values = getattr(self, column)
        if values.size == 0:
            return np.full(row.shape, fill, dtype=values.dtype)
        return np.where(row >= 0, values[np.maximum(row, 0)], fill)

    def kept_in(self, frame: int, inst: np.ndarray) -> np.ndarray:
        """``(N,) int64``: the kept-class mask of each point's sighting in ``frame`` (0: none)."""
        lo, hi = np.searchsorted(self.kept_frame, [frame, frame + 1])
        out = np.zeros(np.shape(inst), np.int64)
        if hi > lo:
            keys, masks = self.kept_key[lo:hi], self.kept_mask[lo:hi]
            pos = np.clip(np.searchsorted(keys, inst), 0, keys.size - 1)
            hit = keys[pos] == inst
            out[hit] = masks[pos[hit]]
        return out

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able form (lists of numbers)."""
        out: dict[str, Any] = {k: getattr(self, k).tolist() for k in _COLUMNS + _KEPT}
        out["joins"] = [[j.earlier, j.later, j.gap, round(j.distance, 6)] for j in self.joins]
        out["refused"] = self.refused
        return out

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrackDecisions:
        kinds = {"static": bool, "dissolved": bool, "confidence": np.float64}
        cols = {k: np.asarray(d[k], kinds.get(k, np.int64)) for k in _COLUMNS + _KEPT}
        joins = tuple(Join(int(a), int(b), int(g), float(x)) for a, b, g, x in d.get("joins", []))
        return cls(**cols, joins=joins, refused=int(d.get("refused", 0)))


def _groups(labels: np.ndarray, keep: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """The rows of ``keep`` grouped by their label, as ``np.unique(labels[keep])`` orders them, each
    group's rows ascending (what ``np.flatnonzero((labels == l) & keep)`` gives, in one sort)."""
    rows = np.flatnonzero(keep)
    if rows.size == 0:
        return []
    rows = rows[np.argsort(labels[rows], kind="stable")]
    return [(int(labels[g[0]]), g) for g in np.split(rows, np.flatnonzero(np.diff(labels[rows])) + 1)]


def _masked_argmax(votes: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per row of ``votes`` ``(T, C)`` the column of ``mask`` with the most votes (ties: lower id)."""
    v = np.where(mask[None, :], votes, -1)
    return np.argmax(v, axis=1).astype(np.int64) if votes.size else np.zeros(votes.shape[0], np.int64)


def kept_classes(
    track: np.ndarray, sightings: np.ndarray, winner: int, thing: np.ndarray, margin: float
) -> np.ndarray:
    """``(R,) int64``: per sighting, the bit mask (bit ``c`` for train id ``c``) of the thing
    classes whose points in it keep their class instead of the track's.

    A class ``c`` (not the ``winner`` of the track's vote) is kept in a sighting when both the
    track's vote does not beat it clearly, ``track[winner] < margin * track[c]``, and the sighting
    prefers it clearly, ``sighting[c] >= margin * sighting[winner]`` with ``sighting[c] > 0`` (with
    the one-hot votes of hard labels a sighting whose points are all ``c`` prefers it clearly).
    ``margin`` 0 keeps none.

    Args:
        track: ``(C,)`` the (joined) track's votes.
        sightings: ``(R, C)`` its sightings' votes (each the sum over its points).
        winner: the track's class. thing: ``(C,) bool``. margin: ``class_margin``.
    """
    t = np.asarray(track, np.float64)
    v = np.asarray(sightings, np.float64).reshape(-1, t.size)
    held = (thing & (t[winner] < margin * t))[None, :] & (v > 0) & (v >= margin * v[:, winner : winner + 1])
    held[:, winner] = False
    bits = np.int64(1) << np.arange(t.size, dtype=np.int64)
    return (held * bits[None, :]).sum(axis=1, dtype=np.int64)


def decide_tracks(
    s: TrackSummary,
    sets: ClassSets,
    params: TrackParams,
    confidence: dict[int, float] | None = None,
    world: bool = True,
) -> TrackDecisions:
    """Decide every track of a sequence.

    Args:
        s: the sequence's tracks.
        sets: the label map's class sets.
        params: the track settings.
        confidence: ``{track key: confidence}`` from the temporal stage, where it has one.
        world: poses are known; without them tracks are neither joined nor judged static.

    Raises:
        ValueError: the label map has more than :data:`MAX_CLASSES` train ids.
    """
    if sets.num_classes > MAX_CLASSES:
        raise ValueError(
            f"refinement handles at most {MAX_CLASSES} classes, the label map has {sets.num_classes}"
        )
    votes = np.where(sets.ignore[None, :], 0, s.votes)
    thing_mass = votes[:, sets.thing].sum(axis=1)
    stuff_mass = votes[:, sets.stuff].sum(axis=1)
    total = votes.sum(axis=1)
    share = np.where(total > 0, thing_mass / np.maximum(total, 1), 0.0)
    conf = share.copy()
    for k, i in enumerate(s.ids.tolist()):
        if confidence and i in confidence:
            conf[k] = float(confidence[i])
    thing_class = _masked_argmax(votes, sets.thing)
    stuff_class = _masked_argmax(votes, sets.stuff)
    n_frames = s.n_frames
    dissolved = (
        (stuff_mass > thing_mass) & (n_frames <= params.dissolve_frames) & (conf < params.dissolve_confidence)
    )
    group = sets.group[thing_class]
    joins = (
        join_tracks(s, ~dissolved, group, params.join_gap, params.join_distance, params.velocity_frames)
        if world
        else []
    )
    joins, refused = keep_ids_apart(s, joins, ~dissolved)
    heads = chain_heads(s.ids, joins)
    final_id = np.where(dissolved, 0, heads)
    class_id = np.where(dissolved, stuff_class, -1)
    static = dissolved.copy()
    kept: list[tuple[int, int, int]] = []  # (frame, key, mask)
    for _, members in _groups(heads, ~dissolved):
        merged = votes[members].sum(axis=0)
        if merged[sets.thing].sum() > 0:
            winner = int(_masked_argmax(merged[None, :], sets.thing)[0])
            class_id[members] = winner
            rows = np.concatenate([np.arange(s.start[m], s.start[m + 1]) for m in members])
            masks = kept_classes(merged, s.sighting_votes[rows], winner, sets.thing, params.class_margin)
            key = np.repeat(s.ids[members], np.diff(s.start)[members])
            kept.extend(
                (int(s.frame[r]), int(k), int(x))
                for r, k, x in zip(rows[masks > 0], key[masks > 0], masks[masks > 0], strict=True)
            )
        if world:
            rows = np.concatenate([np.arange(s.start[m], s.start[m + 1]) for m in members])
            rows = rows[np.argsort(s.frame[rows], kind="stable")]
            static[members] = is_static(
                s.centre[rows], s.extent[rows], params.min_static_frames, params.moving_distance,
                params.moving_extent,
            )  # fmt: skip
    return TrackDecisions(
        ids=s.ids.astype(np.int64),
        final_id=final_id.astype(np.int64),
        class_id=class_id.astype(np.int64),
        static=static.astype(bool),
        dissolved=dissolved.astype(bool),
        confidence=conf.astype(np.float64),
        first=s.first.astype(np.int64),
        last=s.last.astype(np.int64),
        n_frames=n_frames.astype(np.int64),
        n_points=s.n_points.astype(np.int64),
        kept_key=np.asarray([k for _, k, _ in sorted(kept)], np.int64),
        kept_frame=np.asarray([f for f, _, _ in sorted(kept)], np.int64),
        kept_mask=np.asarray([m for _, _, m in sorted(kept)], np.int64),
        joins=tuple(joins),
        refused=refused,
    )


def track_rows(d: TrackDecisions) -> list[dict[str, Any]]:
    """One row per track after refinement (joined tracks as one; dissolved tracks omitted), sorted
    by (id, generation): id and generation (its earliest track's), class_id (-1: mixed),
    kept_classes (the thing classes whose points keep theirs in some sighting), first/last frame,
    n_frames, n_points, moving, joined and joined_generation (its original tracks), confidence
    (point-weighted mean)."""
    rows = []
    kept_by_key: dict[int, int] = {}
    for k, mask in zip(d.kept_key.tolist(), d.kept_mask.tolist(), strict=True):
        kept_by_key[k] = kept_by_key.get(k, 0) | mask
    groups = dict(_groups(d.final_id, d.final_id > 0))
    for head in sorted(groups, key=lambda k: (key_id(k), k)):
        m = groups[head]
        pts = d.n_points[m]
        rows.append(
            {
                "id": int(key_id(head)),
                "generation": int(key_generation(head)),
                "class_id": int(d.class_id[m[0]]),
                "kept_classes": _bits(_union(kept_by_key.get(int(k), 0) for k in d.ids[m])),
                "first_frame": int(d.first[m].min()),
                "last_frame": int(d.last[m].max()),
                "n_frames": int(d.n_frames[m].sum()),
                "n_points": int(pts.sum()),
                "moving": not bool(d.static[m[0]]),
                "joined": key_id(d.ids[m]).tolist(),
                "joined_generation": key_generation(d.ids[m]).tolist(),
                "confidence": float((d.confidence[m] * pts).sum() / max(int(pts.sum()), 1)),
            }
        )
    return rows


def _union(masks) -> int:
    out = 0
    for m in masks:
        out |= m
    return out


def _bits(mask: int) -> list[int]:
    """The train ids set in ``mask``, ascending."""
    return [c for c in range(MAX_CLASSES) if mask >> c & 1]

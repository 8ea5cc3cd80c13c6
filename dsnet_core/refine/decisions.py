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

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able form (lists of numbers)."""
        out: dict[str, Any] = {k: getattr(self, k).tolist() for k in _COLUMNS}
        out["joins"] = [[j.earlier, j.later, j.gap, round(j.distance, 6)] for j in self.joins]
        out["refused"] = self.refused
        return out

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrackDecisions:
        kinds = {"static": bool, "dissolved": bool, "confidence": np.float64}
        cols = {k: np.asarray(d[k], kinds.get(k, np.int64)) for k in _COLUMNS}
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
    """
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
    for _, members in _groups(heads, ~dissolved):
        merged = votes[members].sum(axis=0)
        if merged[sets.thing].sum() > 0:
            class_id[members] = int(_masked_argmax(merged[None, :], sets.thing)[0])
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
        joins=tuple(joins),
        refused=refused,
    )


def track_rows(d: TrackDecisions) -> list[dict[str, Any]]:
    """One row per track after refinement (joined tracks as one; dissolved tracks omitted), sorted
    by (id, generation): id and generation (its earliest track's), class_id (-1: mixed), first/last
    frame, n_frames, n_points, moving, joined and joined_generation (its original tracks),
    confidence (point-weighted mean)."""
    rows = []
    groups = dict(_groups(d.final_id, d.final_id > 0))
    for head in sorted(groups, key=lambda k: (key_id(k), k)):
        m = groups[head]
        pts = d.n_points[m]
        rows.append(
            {
                "id": int(key_id(head)),
                "generation": int(key_generation(head)),
                "class_id": int(d.class_id[m[0]]),
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

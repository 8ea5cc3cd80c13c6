"""What refinement gathers about every track over the whole sequence (one pass, little memory):
per sighting its centre, extent and class votes, and per track its summed class votes.

:func:`frame_tracks` reduces one frame; :class:`TrackHistory` collects frames in any order and
:meth:`TrackHistory.summary` returns the sequence's :class:`TrackSummary`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dsnet_core.refine.frame import Confidence, FrameInput, range_weights
from dsnet_core.refine.kernels import group_box, group_votes


@dataclass(frozen=True)
class FrameTracks:
    """The tracks of one frame (arrays over its ``M`` ids).

    Attributes:
        frame: frame index. time: seconds.
        ids: ``(M,) int64`` sorted.
        n_points: ``(M,) int64``.
        centre: ``(M, 3) float64`` centroid of the points, world frame, metres.
        extent: ``(M,) float64`` diagonal of their horizontal bounding box, metres.
        votes: ``(M, C) int64`` summed votes of their points.
    """

    frame: int
    time: float
    ids: np.ndarray
    n_points: np.ndarray
    centre: np.ndarray
    extent: np.ndarray
    votes: np.ndarray


def frame_tracks(
    frame: FrameInput, confidence: Confidence, range_ref: float | None, n_classes: int
) -> FrameTracks:
    """Reduce one frame to its tracks (points with an id > 0)."""
    sel = np.flatnonzero(frame.inst > 0)
    ids, inv = np.unique(frame.inst[sel], return_inverse=True)
    inv = inv.reshape(-1)
    m = ids.size
    world = frame.world_columns(sel)
    n = np.bincount(inv, minlength=m).astype(np.int64)
    centre = np.stack([np.bincount(inv, weights=world[a], minlength=m) for a in range(3)], 1).astype(
        np.float64
    )
    centre /= np.maximum(n, 1)[:, None]
    lo, hi = group_box(inv, m, world[0], world[1])
    extent = np.hypot(*(hi - lo).T) if m else np.zeros(0)
    use_conf = frame.probs is None
    weight = range_weights(frame, range_ref, sel) * confidence.point_weights(frame.inst[sel], use_conf)
    probs = None if frame.probs is None else frame.probs[sel]
    votes = group_votes(inv, m, frame.sem[sel], probs, weight, n_classes)
    return FrameTracks(frame.index, float(frame.time), ids, n, centre, extent, votes)


@dataclass(frozen=True)
class TrackSummary:
    """Every track of a sequence.

    Attributes:
        ids: ``(T,) int64`` sorted.
        votes: ``(T, C) int64`` summed votes over the track's life.
        n_points: ``(T,) int64``.
        start: ``(T + 1,) int64`` offsets of each track's sightings in the row arrays.
        frame, time, centre, extent, points: per sighting (rows sorted by id, then frame).
        sighting_votes: ``(R, C) int64`` per sighting, the summed votes of its points.
    """

    ids: np.ndarray
    votes: np.ndarray
    n_points: np.ndarray
    start: np.ndarray
    frame: np.ndarray
    time: np.ndarray
    centre: np.ndarray
    extent: np.ndarray
    points: np.ndarray
    sighting_votes: np.ndarray

    def rows(self, t: int) -> slice:
        """The sightings of track number ``t`` (an index into ``ids``)."""
        return slice(int(self.start[t]), int(self.start[t + 1]))

    @property
    def n_frames(self) -> np.ndarray:
        return np.diff(self.start)

    @property
    def first(self) -> np.ndarray:
        return self.frame[self.start[:-1]] if self.ids.size else np.zeros(0, np.int64)

    @property
    def last(self) -> np.ndarray:
        return self.frame[self.start[1:] - 1] if self.ids.size else np.zeros(0, np.int64)


class TrackHistory:
    """Collects :class:`FrameTracks` (in any frame order) into a :class:`TrackSummary`."""

    def __init__(self, n_classes: int) -> None:
        self.n_classes = n_classes
        self._rows: list[tuple[int, float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self._votes: dict[int, np.ndarray] = {}

    def add(self, tracks: FrameTracks) -> None:
        self._rows.append(
            (
                tracks.frame,
                tracks.time,
                tracks.ids,
                tracks.n_points,
                tracks.centre,
                tracks.extent,
                tracks.votes,
            )
        )
        for i, v in zip(tracks.ids.tolist(), tracks.votes, strict=True):
            self._votes[i] = self._votes[i] + v if i in self._votes else v.copy()

    def summary(self) -> TrackSummary:
        rows = self._rows
        if not rows or not sum(r[2].size for r in rows):
            z, zc = np.zeros(0, np.int64), np.zeros((0, self.n_classes), np.int64)
            return TrackSummary(z, zc, z, np.zeros(1, np.int64), z, np.zeros(0), np.zeros((0, 3)),
                                np.zeros(0), z, zc.copy())  # fmt: skip
        ids = np.concatenate([r[2] for r in rows])
        frame = np.concatenate([np.full(r[2].size, r[0], np.int64) for r in rows])
        time = np.concatenate([np.full(r[2].size, r[1], np.float64) for r in rows])
        points = np.concatenate([r[3] for r in rows])
        centre = np.concatenate([r[4] for r in rows])
        extent = np.concatenate([r[5] for r in rows])
        sighting = np.concatenate([r[6] for r in rows]).astype(np.int64, copy=False)
        order = np.lexsort((frame, ids))
        ids, frame, time, centre, extent, points, sighting = (
            a[order] for a in (ids, frame, time, centre, extent, points, sighting)
        )
        uniq, first = np.unique(ids, return_index=True)
        start = np.append(first, ids.size).astype(np.int64)
        votes = np.stack([self._votes[int(i)] for i in uniq])
        return TrackSummary(
            uniq, votes, np.add.reduceat(points, first), start, frame, time, centre, extent, points, sighting
        )

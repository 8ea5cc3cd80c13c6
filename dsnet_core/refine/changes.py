"""What refinement changed in one frame: points changed (by which step), class transitions, and
the tracks joined into and dissolved in the frame."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class FrameChange:
    """One frame's change record.

    Attributes:
        index: the frame.
        n_points: its points.
        changed: points whose label (class or id) changed.
        class_changed: points whose class changed.
        id_changed: points whose instance id changed.
        by_track: points changed by their track's decision (class, join or dissolving).
        by_static: points given the static vote's class.
        by_ground: points corrected by the ground prior.
        transitions: ``{(from train id, to train id): points}`` of the class changes.
        tracks_joined: joins whose later track starts in this frame.
        tracks_dissolved: dissolved tracks with points in this frame.
    """

    index: int
    n_points: int
    changed: int
    class_changed: int
    id_changed: int
    by_track: int
    by_static: int
    by_ground: int
    transitions: dict[tuple[int, int], int] = field(default_factory=dict)
    tracks_joined: int = 0
    tracks_dissolved: int = 0

    def row(self) -> dict[str, Any]:
        """A table row: the counts, and the transitions as three parallel lists."""
        keys = sorted(self.transitions)
        return {
            "index": self.index,
            "n_points": self.n_points,
            "changed": self.changed,
            "class_changed": self.class_changed,
            "id_changed": self.id_changed,
            "by_track": self.by_track,
            "by_static": self.by_static,
            "by_ground": self.by_ground,
            "tracks_joined": self.tracks_joined,
            "tracks_dissolved": self.tracks_dissolved,
            "from_class": [a for a, _ in keys],
            "to_class": [b for _, b in keys],
            "transitions": [self.transitions[k] for k in keys],
        }


def frame_change(
    index: int,
    before: tuple[np.ndarray, np.ndarray],
    after: tuple[np.ndarray, np.ndarray],
    by_track: np.ndarray,
    by_static: np.ndarray,
    by_ground: np.ndarray,
    tracks_joined: int = 0,
    tracks_dissolved: int = 0,
) -> FrameChange:
    """The change record of one frame from its (class, id) arrays ``(N,)`` before and after and the
    ``(N,) bool`` masks of the points each step changed. Ids may be track keys: the label's id is
    their lower 16 bits (:mod:`dsnet_core.temporal.ids`), and only a change of it counts."""
    sem0, inst0 = before
    sem1, inst1 = after
    cls = sem0 != sem1
    ids = (np.asarray(inst0) & 0xFFFF) != (np.asarray(inst1) & 0xFFFF)
    pairs = sem0[cls].astype(np.int64) * 65536 + sem1[cls].astype(np.int64)
    uniq, counts = np.unique(pairs, return_counts=True)
    transitions = {(int(p >> 16), int(p & 0xFFFF)): int(c) for p, c in zip(uniq, counts, strict=True)}
    return FrameChange(
        index=int(index),
        n_points=int(sem0.size),
        changed=int((cls | ids).sum()),
        class_changed=int(cls.sum()),
        id_changed=int(ids.sum()),
        by_track=int(by_track.sum()),
        by_static=int(by_static.sum()),
        by_ground=int(by_ground.sum()),
        transitions=transitions,
        tracks_joined=int(tracks_joined),
        tracks_dissolved=int(tracks_dissolved),
    )

"""Offline refinement of a sequence in two passes.

1. :func:`plan_refinement` reads every frame once and decides the tracks
   (:func:`~dsnet_core.refine.decisions.decide_tracks`): a :class:`RefinePlan`, small and JSON-able.
2. :func:`refine_block` refines any set of frames ("a block") from the plan and the frames within
   ±W of them: each point takes its track's decision, then points without an instance take the
   static vote of the window (and, optionally, the ground prior).

A frame's result depends only on the plan and the frames of its own window (the votes are integer
sums), so blocks can run in any order, in parallel, or again after a kill, and agree exactly with
one block over the whole sequence. Memory is flat in the sequence's length: a block holds the
votes of at most ``2W + 1`` frames and the labels of at most ``W + 1`` frames awaiting their window.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from dsnet_core.refine.changes import FrameChange, frame_change
from dsnet_core.refine.classes import ClassSets
from dsnet_core.refine.decisions import TrackDecisions, decide_tracks
from dsnet_core.refine.frame import Confidence, FrameInput, range_weights
from dsnet_core.refine.ground import GroundSegmenter, ground_correction
from dsnet_core.refine.history import TrackHistory, frame_tracks
from dsnet_core.refine.params import RefineParams
from dsnet_core.refine.voxels import FrameVotes, SortedKeys, VoxelGrid, grouped_votes, window_consensus
from dsnet_core.temporal.ids import key_id


@dataclass(frozen=True)
class RefinePlan:
    """The whole-sequence part of refinement.

    Attributes:
        frames: the refinable frames, ascending.
        decisions: what happens to each track.
        confidence: the temporal stage's instance confidences (vote weights of hard labels).
        world: every frame has a pose (without, there is no static vote, joining or motion).
        origin: the voxel grid's origin, world frame, metres.
    """

    frames: tuple[int, ...]
    decisions: TrackDecisions
    confidence: Confidence
    world: bool
    origin: tuple[float, float, float]

    def to_dict(self) -> dict[str, Any]:
        return {
            "frames": list(self.frames),
            "decisions": self.decisions.to_dict(),
            "confidence": [self.confidence.ids.tolist(), self.confidence.weight.tolist()],
            "world": self.world,
            "origin": list(self.origin),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RefinePlan:
        ids, weight = d["confidence"]
        return cls(
            frames=tuple(int(f) for f in d["frames"]),
            decisions=TrackDecisions.from_dict(d["decisions"]),
            confidence=Confidence(np.asarray(ids, np.int64), np.asarray(weight, np.int64)),
            world=bool(d["world"]),
            origin=tuple(float(x) for x in d["origin"]),  # type: ignore[arg-type]
        )


def plan_refinement(
    frames: Iterable[FrameInput],
    sets: ClassSets,
    params: RefineParams,
    confidence: dict[int, float] | None = None,
) -> RefinePlan:
    """Read every frame of a sequence once and decide its tracks.

    Args:
        frames: the sequence's refinable frames (any order; read once, not kept).
        sets: the label map's class sets.
        params: the settings.
        confidence: ``{track key: confidence}`` from the temporal stage, where it has one (keys
            ``id | generation << 16`` as in the frames' ``inst``).
    """
    conf = Confidence.from_mapping(confidence)
    history = TrackHistory(sets.num_classes)
    indices: list[int] = []
    world = True
    origin: tuple[float, float, float] | None = None
    for frame in frames:
        indices.append(frame.index)
        if frame.pose is None:
            world = False
        elif origin is None:
            origin = tuple(float(np.round(v)) for v in np.asarray(frame.pose)[:3, 3])  # type: ignore[assignment]
        history.add(frame_tracks(frame, conf, params.vote.range_ref, sets.num_classes))
    decisions = decide_tracks(history.summary(), sets, params.track, confidence, world)
    return RefinePlan(tuple(sorted(indices)), decisions, conf, world, origin or (0.0, 0.0, 0.0))


@dataclass(frozen=True)
class RefinedFrame:
    """One refined frame: train ids and ids ``(N,) int64`` and what changed."""

    index: int
    sem: np.ndarray
    inst: np.ndarray
    change: FrameChange


@dataclass
class _Pending:
    """A target frame waiting for the rest of its window."""

    frame: FrameInput
    sem: np.ndarray
    inst: np.ndarray
    by_track: np.ndarray
    takers: np.ndarray
    groups: tuple[np.ndarray, np.ndarray]  # the takers' voxels: sorted unique keys, inverse
    dissolved: int  # dissolved tracks with points in the frame


@dataclass(frozen=True)
class _Tracked:
    """A frame after its tracks' decisions: ``sem``, ``inst`` ``(N,) int64``, ``static`` and
    ``changed`` ``(N,) bool``, and the points with a known track (``points``) with their rows in
    the decision table (``rows``)."""

    sem: np.ndarray
    inst: np.ndarray
    static: np.ndarray
    changed: np.ndarray
    points: np.ndarray
    rows: np.ndarray


def _apply(frame: FrameInput, d: TrackDecisions) -> _Tracked:
    """A frame's classes, ids, static flags and changed points after its tracks' decisions
    (looking up only the points with an id)."""
    nz = np.flatnonzero(frame.inst > 0)
    row = d.lookup(frame.inst[nz])
    has = row >= 0
    points, rows = nz[has], row[has]
    sem, inst = frame.sem.copy(), frame.inst.copy()
    inst[points] = d.final_id[rows]
    cls = d.class_id[rows]
    kept = d.kept_in(frame.index, frame.inst[points])
    take = (cls >= 0) & (((kept >> frame.sem[points]) & 1) == 0)  # a kept class keeps its points
    sem[points[take]] = cls[take]
    static = np.zeros(inst.shape, bool)
    static[points] = d.static[rows]
    changed = (sem != frame.sem) | (key_id(inst) != key_id(frame.inst))
    return _Tracked(sem, inst, static, changed, points, rows)


def _voters(sem: np.ndarray, inst: np.ndarray, static: np.ndarray, sets: ClassSets) -> np.ndarray:
    """``(N,) bool``: points of a stuff class without an instance, and points of static tracks."""
    return ~sets.ignore[sem] & (((inst == 0) & sets.stuff[sem]) | ((inst > 0) & static))


def refine_block(
    load: Callable[[int], FrameInput],
    targets: Sequence[int],
    plan: RefinePlan,
    sets: ClassSets,
    params: RefineParams,
    ground: GroundSegmenter | None = None,
) -> Iterator[RefinedFrame]:
    """Refine the frames ``targets`` (a subset of ``plan.frames``), in ascending order.

    Args:
        load: reads one frame of the sequence by index (called once per frame the block needs:
            the targets and the frames within ±W of them).
        targets: the frames to refine.
        plan: the sequence's plan.
        sets: the label map's class sets.
        params: the settings (the same as the plan's).
        ground: the ground segmenter, when ``params.ground.enabled``.

    Raises:
        ValueError: a target is not one of the plan's frames; the ground prior is on without a
            segmenter or without ground classes in the label map.
    """
    known = set(plan.frames)
    bad = [t for t in targets if t not in known]
    if bad:
        raise ValueError(f"frames {bad[:10]} are not refinable frames of this sequence")
    if params.ground.enabled and (ground is None or not sets.ground.any()):
        raise ValueError(
            "the ground prior needs a ground segmenter and a label map that declares ground classes"
        )
    todo = sorted(set(targets))
    if not todo:
        return
    w = params.vote.window
    voting = params.vote.enabled and plan.world
    needed = [f for f in plan.frames if todo[0] - w <= f <= todo[-1] + w] if voting else todo
    grid = VoxelGrid(params.vote.voxel, plan.origin)
    votes: deque[FrameVotes] = deque()
    pending: deque[_Pending] = deque()
    wanted = set(todo)
    joined = _joins_by_frame(plan.decisions)
    none = (np.zeros(0, np.int64), np.zeros(0, np.int64))
    for k, g in enumerate(needed):
        frame = load(g)
        if frame.index != g:
            raise ValueError(f"load({g}) returned frame {frame.index}")
        t = _apply(frame, plan.decisions)
        sem, inst = t.sem, t.inst
        takes = (inst == 0) & ~sets.ignore[sem] if voting and g in wanted else None
        if voting:
            # one sort of the voxel keys of every voter and taker serves both groupings
            voters = _voters(sem, inst, t.static, sets)
            used = voters if takes is None else voters | takes
            rows = np.flatnonzero(used)
            keys = SortedKeys(grid.keys_of(*frame.world_columns(rows)))
            weight = range_weights(frame, params.vote.range_ref, rows[voters[rows]])
            weight = weight * plan.confidence.point_weights(frame.inst[voters], frame.probs is None)
            probs = None if frame.probs is None else frame.probs[voters]
            uniq, inv = keys.groups(voters[rows])
            votes.append(
                grouped_votes(g, uniq, inv, sem[voters], probs, weight, sets.num_classes, params.vote.top_k)
            )
        if g in wanted:
            takers = np.flatnonzero(takes) if takes is not None else np.zeros(0, np.int64)
            groups = keys.groups(takes[rows]) if takes is not None else none
            dissolved = np.unique(frame.inst[t.points[plan.decisions.dissolved[t.rows]]]).size
            pending.append(_Pending(frame, sem, inst, t.changed, takers, groups, dissolved))
        last = k == len(needed) - 1
        while pending and (last or pending[0].frame.index + w <= g):
            p = pending.popleft()
            window = [v for v in votes if abs(v.index - p.frame.index) <= w]
            yield _finish(p, window, sets, params, ground, joined.get(p.frame.index, 0))
            keep_from = (pending[0].frame.index if pending else g + 1) - w
            while votes and votes[0].index < keep_from:
                votes.popleft()


def _joins_by_frame(d: TrackDecisions) -> dict[int, int]:
    """``{frame: joins whose later track starts there}``."""
    if not d.joins:
        return {}
    later = d.lookup(np.asarray([j.later for j in d.joins], np.int64))
    firsts = d.first[later].tolist()
    return {int(f): firsts.count(f) for f in set(firsts)}


def _finish(
    p: _Pending,
    window: list[FrameVotes],
    sets: ClassSets,
    params: RefineParams,
    ground: GroundSegmenter | None,
    joined: int,
) -> RefinedFrame:
    """Static vote (and ground prior) on one pending frame, and its change record."""
    frame, sem, inst = p.frame, p.sem.copy(), p.inst
    by_static = np.zeros(sem.size, bool)
    if p.takers.size:
        uniq, inv = p.groups
        c = window_consensus(uniq, window, sets.num_classes)
        v = params.vote
        ok = c.supported(v.min_frames, v.min_share, v.min_votes)
        cls = np.where(ok, c.cls, -1)[inv]
        take = (cls >= 0) & sets.stuff[np.maximum(cls, 0)] & (cls != sem[p.takers])
        sem[p.takers[take]] = cls[take]
        by_static[p.takers[take]] = True
    by_ground = np.zeros(sem.size, bool)
    if params.ground.enabled and ground is not None and frame.probs is not None:
        verdict = ground(frame.xyz, frame.intensity)
        sem, by_ground = ground_correction(
            sem, inst, frame.probs, verdict, sets, params.ground.max_confidence, frozen=by_static
        )
    change = frame_change(
        frame.index,
        (frame.sem, frame.inst),
        (sem, inst),
        p.by_track,
        by_static,
        by_ground,
        joined,
        p.dissolved,
    )
    return RefinedFrame(frame.index, sem, inst, change)


def refine_sequence(
    frames: Sequence[FrameInput],
    sets: ClassSets,
    params: RefineParams,
    confidence: dict[int, float] | None = None,
    ground: GroundSegmenter | None = None,
) -> list[RefinedFrame]:
    """Plan and refine a whole sequence held in memory (tests, small logs)."""
    by_index = {f.index: f for f in frames}
    plan = plan_refinement(frames, sets, params, confidence)
    return list(refine_block(by_index.__getitem__, plan.frames, plan, sets, params, ground))

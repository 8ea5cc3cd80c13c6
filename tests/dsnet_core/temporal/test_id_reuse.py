"""Sequences that need more than the 65 535 ids of a label: the stitcher and the tracker reuse ids
only outside the reuse window and never one still carried or coasting, keep every other id as
before, resume identically after a reuse, and their track tables tell the hand-outs of an id apart.

The scenes are small and synthetic: thousands of one-point fragments per frame (a model's short
fragments), a few persistent objects and some objects that cross volume boundaries."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dsnet_core.labels import load_label_map
from dsnet_core.temporal.ids import MAX_ID, Generations, IdSpaceExhausted, key_id, track_key
from dsnet_core.temporal.stitching import Stitcher, VolumeLabels
from dsnet_core.temporal.tracking import Tracker

LM = load_label_map("semantic-kitti")
CAR, ROAD = 1, 9
RAW_CAR, RAW_ROAD = int(LM.learning_map_inv[CAR]), int(LM.learning_map_inv[ROAD])
PERSISTENT = 8  # objects 1..8 in every frame
FRAGMENTS = 3000  # one-point objects in each odd frame
R = 10  # reuse window, frames


class Scene:
    """Per frame ``(gt (N,) int64 object ids, 0 = road)``: persistent objects (3 points each),
    objects living 3 frames from each odd frame (2 points each, they cross volume boundaries),
    and :data:`FRAGMENTS` one-point objects in odd frames."""

    def __init__(self, n_frames: int) -> None:
        self.frames: list[np.ndarray] = []
        next_gt = 1000
        crossing: list[tuple[int, int]] = []  # (gt id, last frame)
        for f in range(n_frames):
            parts = [np.zeros(3, np.int64), np.repeat(np.arange(1, PERSISTENT + 1), 3)]
            if f % 2:
                crossing += [(next_gt + i, f + 2) for i in range(20)]
                next_gt += 20
            crossing = [(g, end) for g, end in crossing if end >= f]
            parts.append(np.repeat(np.array([g for g, _ in crossing], np.int64), 2))
            if f % 2:
                parts.append(np.arange(next_gt, next_gt + FRAGMENTS))
                next_gt += FRAGMENTS
            self.frames.append(np.concatenate(parts))
        self.n_objects = next_gt - 1000 + PERSISTENT

    def volume(self, start: int, k: int = 3) -> VolumeLabels:
        """Frames start..start+k-1; raw ids local to the volume (gt id + an offset)."""
        frames = np.arange(start, min(start + k, len(self.frames)))
        gt = [self.frames[f] for f in frames]
        cat = np.concatenate
        g = cat(gt)
        return VolumeLabels(
            frames=frames,
            source_frame=cat([np.full(x.size, f) for f, x in zip(frames, gt, strict=True)]),
            source_index=cat([np.arange(x.size) for x in gt]),
            semantic=np.where(g > 0, CAR, ROAD),
            instance=np.where(g > 0, g + 10_000_000 * (start + 1), 0),
        )


def stitch(scene: Scene, starts, stitcher: Stitcher, out: dict[int, np.ndarray]) -> Stitcher:
    for st in starts:
        for ff in stitcher.add_volume(scene.volume(st)):
            assert ff.frame not in out
            out[ff.frame] = ff.label
    return stitcher


def check_labels(scene: Scene, labels: dict[int, np.ndarray]) -> np.ndarray:
    """Valid labels: classes kept, one id per object and frame, distinct objects distinct ids, the
    persistent objects one id throughout. Returns the ``(U, 3)`` uses (frame, object, id)."""
    uses = []
    persistent = None
    for f in sorted(labels):
        label, gt = labels[f], scene.frames[f]
        assert label.dtype == np.uint32 and label.shape == gt.shape
        assert ((label & 0xFFFF) == np.where(gt > 0, RAW_CAR, RAW_ROAD)).all()
        ids = (label >> 16).astype(np.int64)
        assert ((ids > 0) == (gt > 0)).all() and ids.max() <= MAX_ID
        pairs = np.unique(np.stack([gt[gt > 0], ids[gt > 0]], 1), axis=0)
        assert np.unique(pairs[:, 0]).size == pairs.shape[0], f"frame {f}: an object with two ids"
        assert np.unique(pairs[:, 1]).size == pairs.shape[0], f"frame {f}: two objects share an id"
        now = pairs[:PERSISTENT, 1].tolist()  # objects 1..PERSISTENT sort first
        assert persistent is None or now == persistent, f"frame {f}: a persistent object changed id"
        persistent = now
        uses.append(np.concatenate([np.full((pairs.shape[0], 1), f), pairs], 1))
    return np.concatenate(uses)


def check_window(uses: np.ndarray) -> int:
    """An id passes to another object only more than R frames after its last use; the hand-overs."""
    u = uses[np.lexsort((uses[:, 0], uses[:, 2]))]  # by id, then frame
    same_id = u[1:, 2] == u[:-1, 2]
    other = same_id & (u[1:, 1] != u[:-1, 1])
    gaps = (u[1:, 0] - u[:-1, 0])[other]
    assert (gaps > R).all(), f"an id passed to another object {gaps.min()} frames after its last use"
    return int(other.sum())


def check_table(table, labels: dict[int, np.ndarray], uses: np.ndarray) -> None:
    """One row per (id, generation), generations of an id apart by more than R frames, rows that
    add up to the labels, and :class:`Generations` of the rows naming each object's track."""
    keys = track_key(table.id, table.generation)
    assert np.unique(keys).size == keys.size and (table.id >= 1).all() and (table.id <= MAX_ID).all()
    order = np.lexsort((table.generation, table.id))
    assert (order == np.arange(keys.size)).all(), "rows sorted by (id, generation)"
    for i in np.unique(table.id[table.generation > 0]).tolist():
        rows = np.flatnonzero(table.id == i)
        assert table.generation[rows].tolist() == list(range(rows.size))
        assert (table.first_frame[rows[1:]] - table.last_frame[rows[:-1]] > R).all()
    assert int(table.n_points.sum()) == sum(int((lab >> 16 > 0).sum()) for lab in labels.values())
    gens = Generations(table.id, table.generation, table.first_frame)
    key_of_use = np.concatenate(
        [gens.keys(uses[uses[:, 0] == f, 2], f) for f in np.unique(uses[:, 0]).tolist()]
    )  # uses are in frame order
    pairs = np.unique(np.stack([uses[:, 1], key_of_use], 1), axis=0)  # (object, key)
    assert np.unique(pairs[:, 0]).size == pairs.shape[0], "an object spans two tracks"
    assert np.unique(pairs[:, 1]).size == pairs.shape[0], "two objects share a track"
    assert set(pairs[:, 1].tolist()) == set(keys.tolist())


def test_stitching_past_65535_ids_reuses_only_outside_the_window_and_resumes_identically():
    scene = Scene(51)
    starts = list(range(0, 49, 2))
    cut = 23  # ids run out in volume 21
    labels: dict[int, np.ndarray] = {}
    s = stitch(scene, starts[:cut], Stitcher(LM, reuse_after=R), labels)
    assert s.ids.reused > 0
    state = json.loads(json.dumps(s.state_dict()))  # what a killed run kept
    stitch(scene, starts[cut:], s, labels)
    assert sorted(labels) == list(range(51)) and scene.n_objects > MAX_ID + 9_000
    uses = check_labels(scene, labels)
    assert s.ids.reused == scene.n_objects - MAX_ID  # every object has its own track
    assert check_window(uses) > 9_000
    table = s.track_table()
    check_table(table, labels, uses)
    cols = table.columns(LM)
    assert max(cols["generation"]) == 1 and len(cols["id"]) == scene.n_objects
    # resumed from the state: identical labels and table
    resumed: dict[int, np.ndarray] = {}
    r = stitch(scene, starts[cut:], Stitcher.from_state(state, LM), resumed)
    assert sorted(resumed) == list(range(min(resumed), 51))
    assert all((resumed[f] == labels[f]).all() for f in resumed)
    a = r.track_table()
    for name in a.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(a, name), getattr(table, name))
    assert r.ids.reused == s.ids.reused


def test_stitching_fails_in_one_typed_line_when_no_id_can_be_freed():
    n = MAX_ID + 1  # objects in one frame: more than a label can tell apart
    crowd = VolumeLabels(
        frames=np.array([0]),
        source_frame=np.zeros(n, np.int64),
        source_index=np.arange(n),
        semantic=np.full(n, CAR),
        instance=np.arange(1, n + 1),
    )
    with pytest.raises(IdSpaceExhausted, match=r"no instance id free at frame 0: all 65535 ids .* last 1 "):
        Stitcher(LM, reuse_after=1).add_volume(crowd)


def _detections(f: int, n: int) -> np.ndarray:
    """``n`` fragments of frame ``f`` far from each other and from every other frame's."""
    return np.stack([np.full(n, 1000.0 + 50.0 * f), 10.0 * np.arange(n), np.zeros(n)], 1)


PARKED = np.array([[0.0, 0.0, 0.0], [0.0, -20.0, 0.0]])  # parked cars, seen in every frame
N = 100  # fragments per frame: ids run out in frame 655


def track(t: Tracker, frames: range, hidden: frozenset[int] = frozenset()) -> list[np.ndarray]:
    """Per frame the keys of: the parked cars (the second one unseen in ``hidden`` frames), then
    :data:`N` fragments."""
    out = []
    for f in frames:
        parked = PARKED[:1] if f in hidden else PARKED
        cent = np.concatenate([parked, _detections(f, N)])
        out.append(t.add_detections(cent, np.full(len(cent), CAR), time=float(f)))
    return out


def test_tracking_past_65535_ids_never_hands_out_a_coasting_tracks_id():
    hidden = frozenset({680, 681})  # the second parked car coasts 2 frames after ids ran out
    t = Tracker(LM, max_age=2, reuse_after=1)
    keys = track(t, range(700), hidden)
    assert t.ids.reused > 0 and t.next_id == MAX_ID + 1
    parked = [k[:2].tolist() for f, k in enumerate(keys) if f not in hidden]
    assert parked == [[1, 2]] * 698  # both keep their ids, the coasting one after 2 frames unseen
    last_seen: dict[int, tuple[int, int]] = {}  # id -> (frame, key)
    for f, k in enumerate(keys):
        ids = key_id(k)
        assert np.unique(ids).size == ids.size and (ids >= 1).all() and (ids <= MAX_ID).all()
        for key in k.tolist():
            i = key_id(key)
            if i in last_seen and last_seen[i][1] != key:  # a new hand-out: after max_age + reuse_after
                assert f - last_seen[i][0] > 2 + 1, f"id {i} reused {f - last_seen[i][0]} frames later"
            last_seen[i] = (f, key)
    assert all(2 not in key_id(keys[f]).tolist() for f in hidden)


def test_tracking_resumes_identically_after_a_reuse_and_fails_typed_when_no_id_is_free():
    t = Tracker(LM, max_age=0, reuse_after=2)
    got = track(t, range(680))
    assert t.ids.reused > 0
    state = json.loads(json.dumps(t.state_dict()))
    got += track(t, range(680, 700))
    resumed = track(Tracker.from_state(state, LM), range(680, 700))
    assert all((a == b).all() for a, b in zip(got[680:], resumed, strict=True))
    assert key_id(np.concatenate(got)).max() == MAX_ID
    wide = Tracker.from_state({**state, "ids": {**state["ids"], "reuse_after": 1000}}, LM)
    with pytest.raises(IdSpaceExhausted, match="last 1000 frames"):
        track(wide, range(680, 700))

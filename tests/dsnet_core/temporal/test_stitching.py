"""Cross-volume id stitching: ownership, one-to-one matching, fresh ids, resume."""

import json
from dataclasses import replace

import numpy as np
import pytest

from dsnet_core.labels import load_label_map
from dsnet_core.temporal.stitching import (
    FinishedFrame,
    Stitcher,
    StitchError,
    VolumeLabels,
    _unpack,
    match_ids,
    overlap_iou,
)

LM = load_label_map("semantic-kitti")
ROAD, CAR, PERSON = 9, 1, 6


def scene(frames: list[dict[int, int]], n_stuff: int = 5) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per frame: (semantic, gt object id) arrays; ``frames[f]`` maps object id -> point count.

    Objects with an even id are cars, odd ids are persons; ``n_stuff`` road points come first.
    """
    out = []
    for objs in frames:
        sem = [ROAD] * n_stuff
        gid = [0] * n_stuff
        for o, n in sorted(objs.items()):
            sem += [CAR if o % 2 == 0 else PERSON] * n
            gid += [o] * n
        out.append((np.array(sem, np.int64), np.array(gid, np.int64)))
    return out


def volume(frames_data, start: int, k: int, relabel=None, scores=None) -> VolumeLabels:
    """A volume over frames start..start+k-1; raw ids = ``relabel(frame, gt id array)``.

    By default raw ids are the gt ids shifted by +100·(start+1), so they are local to the volume.
    """
    fr, pt, sem, inst = [], [], [], []
    for f in range(start, min(start + k, len(frames_data))):
        s, g = frames_data[f]
        raw = g + 100 * (start + 1) * (g > 0) if relabel is None else relabel(f, g)
        fr.append(np.full(s.size, f))
        pt.append(np.arange(s.size))
        sem.append(s)
        inst.append(raw)
    frames = np.arange(start, min(start + k, len(frames_data)))
    cat = np.concatenate
    return VolumeLabels(frames, cat(fr), cat(pt), cat(sem), cat(inst), scores=scores)


def run(frames_data, k: int, stride: int, stitcher=None, **kw) -> dict[int, np.ndarray]:
    s = stitcher or Stitcher(LM)
    out = {}
    for start in range(0, len(frames_data) - k + stride, stride):
        for ff in s.add_volume(volume(frames_data, start, k, **kw)):
            assert ff.frame not in out, "a frame is written twice"
            out[ff.frame] = ff.label
    return out


def ids_of(label: np.ndarray, gid: np.ndarray) -> dict[int, int]:
    """gt id -> the single predicted id of its points (asserts it is single)."""
    inst = label >> 16
    res = {}
    for g in np.unique(gid[gid > 0]).tolist():
        u = np.unique(inst[gid == g])
        assert u.size == 1, f"gt object {g} carries ids {u.tolist()}"
        res[g] = int(u[0])
    return res


@pytest.mark.parametrize(("k", "stride"), [(2, 1), (3, 1), (4, 1), (3, 2), (4, 3)])
def test_persistent_objects_keep_one_id(k, stride):
    data = scene([{2: 30, 3: 20, 4: 40}] * 9)
    out = run(data, k, stride)
    assert sorted(out) == list(range(9))
    per_frame = [ids_of(out[f], data[f][1]) for f in range(9)]
    assert all(p == per_frame[0] for p in per_frame)
    assert sorted(per_frame[0].values()) == [1, 2, 3]
    # semantic half is the raw id through learning_map_inv; stuff has instance 0
    sem = out[0] & 0xFFFF
    assert (sem[:5] == LM.learning_map_inv[ROAD]).all() and ((out[0] >> 16)[:5] == 0).all()
    assert set(np.unique(sem[5:]).tolist()) == {LM.learning_map_inv[CAR], LM.learning_map_inv[PERSON]}


def test_first_volume_owns_the_overlap_frame():
    data = scene([{2: 30}] * 3)

    def relabel(f, g):  # the second volume calls everything instance 7 — only matching uses it
        return np.where(g > 0, 7, 0)

    s = Stitcher(LM)
    first = s.add_volume(volume(data, 0, 2))
    v2 = volume(data, 1, 2, relabel=relabel)
    v2 = replace(v2, semantic=np.where(v2.semantic == CAR, PERSON, v2.semantic))
    second = s.add_volume(v2)
    assert [f.frame for f in first] == [0, 1] and [f.frame for f in second] == [2]
    assert ((first[1].label & 0xFFFF)[5:] == LM.learning_map_inv[CAR]).all()  # not overwritten
    assert ((second[0].label & 0xFFFF)[5:] == LM.learning_map_inv[PERSON]).all()
    assert (first[1].label >> 16)[5] == (second[0].label >> 16)[5] == 1


def test_object_leaving_and_reentering_gets_a_fresh_id_never_reused():
    # object 2 in frames 0-2, gone 3-4, back 5-7; object 4 enters at frame 4 after 2 left
    frames = [{2: 30, 3: 10}] * 3 + [{3: 10}] + [{3: 10, 4: 20}] + [{2: 30, 3: 10, 4: 20}] * 3
    data = scene(frames)
    out = run(data, 2, 1)
    ids = [ids_of(out[f], data[f][1]) for f in range(8)]
    first_id, person = ids[0][2], ids[0][3]
    assert all(i[3] == person for i in ids)  # the steady object keeps its id throughout
    assert ids[4][4] not in (first_id, person)
    reentered = ids[5][2]
    assert reentered not in (first_id, person, ids[4][4]) and reentered == max(ids[5].values())
    assert all(i[2] == reentered for i in ids[5:])


def test_split_larger_part_inherits_smaller_part_fresh():
    data = scene([{2: 100}] * 3)

    def split(cut):
        def relabel(f, g):
            raw = np.where(g > 0, 1, 0)
            idx = np.flatnonzero(g > 0)
            raw[idx[cut:]] = 2
            return raw

        return relabel

    s = Stitcher(LM)
    s.add_volume(volume(data, 0, 2))
    out = s.add_volume(volume(data, 1, 2, relabel=split(70)))[0].label >> 16
    assert out[5:75].tolist() == [1] * 70 and out[75:].tolist() == [2] * 30
    # an even split: IoU exactly 0.5 is not a match (strict), both halves are fresh
    s = Stitcher(LM)
    s.add_volume(volume(data, 0, 2))
    out = s.add_volume(volume(data, 1, 2, relabel=split(50)))[0].label >> 16
    assert sorted(set(out[5:].tolist())) == [2, 3]


def test_merge_larger_object_keeps_its_id_smaller_one_ends():
    data = scene([{2: 60, 4: 40}] * 3)
    s = Stitcher(LM)
    v1 = s.add_volume(volume(data, 0, 2))
    a, b = ids_of(v1[0].label, data[0][1])[2], ids_of(v1[0].label, data[0][1])[4]
    merged = s.add_volume(volume(data, 1, 2, relabel=lambda f, g: np.where(g > 0, 5, 0)))
    assert set((merged[0].label >> 16)[5:].tolist()) == {a}
    assert s.track_table().last_frame[s.track_table().id == b].tolist() == [1]


def test_hungarian_beats_greedy_below_half_and_equals_it_at_half():
    # rows: previous ids, columns: new ids. First-come greedy gives row 0 column 0 (0.45) and
    # then row 1 has nothing left above 0.3; the assignment takes 0.44 + 0.40.
    iou = np.array([[0.45, 0.44], [0.40, 0.0]])

    def greedy_first_come(m, t):
        used, pairs = set(), []
        for r in range(m.shape[0]):
            for c in np.argsort(-m[r]).tolist():
                if c not in used and m[r, c] > t:
                    used.add(c)
                    pairs.append((r, c))
                    break
        return pairs

    assert greedy_first_come(iou, 0.3) == [(0, 0)]
    assert match_ids(iou, 0.3) == [(0, 1), (1, 0)]
    rng = np.random.default_rng(0)
    for _ in range(200):  # at 0.5 on two partitions the match is unique: both agree
        n = 60
        a = rng.integers(1, 6, n)
        b = np.where(rng.random(n) < rng.random(), a, rng.integers(1, 6, n))
        keys = np.arange(n, dtype=np.int64)
        _, _, m = overlap_iou(keys, a, keys, b)
        assert sorted(greedy_first_come(m, 0.5)) == match_ids(m, 0.5)


def test_stitcher_uses_the_assignment_not_first_come():
    # overlap frame 1: A = points 0..99 (id 1), B = points 100..139 (id 2). The new volume calls
    # A[0:60] + B raw 1 (IoU 0.43 with A, 0.40 with B) and A[60:100] raw 2 (IoU 0.40 with A).
    # Greedy by best IoU: raw 1 -> A, raw 2 fresh (total 0.43); the assignment: raw 1 -> B,
    # raw 2 -> A (total 0.80).
    data = scene([{2: 100, 4: 40}] * 3, n_stuff=0)

    def relabel(f, g):
        raw = np.where(g > 0, 1, 0)
        raw[60:100] = 2
        return raw

    s = Stitcher(LM, min_iou=0.3)
    s.add_volume(volume(data, 0, 2))
    ids = s.add_volume(volume(data, 1, 2, relabel=relabel))[0].label >> 16
    assert ids[:60].tolist() == [2] * 60 and ids[60:100].tolist() == [1] * 40
    assert ids[100:].tolist() == [2] * 40 and s.next_id == 3


def test_empty_frames_and_empty_volume():
    data = scene([{2: 30}, {}, {2: 30}, {2: 30}, {2: 30}, {2: 30}])
    data[3] = (np.zeros(0, np.int64), np.zeros(0, np.int64))  # a scan with no points at all
    out = run(data, 2, 1)
    assert out[3].shape == (0,) and out[1].tolist() == [LM.learning_map_inv[ROAD]] * 5
    ids = [set((out[f] >> 16).tolist()) - {0} for f in range(6)]
    # frame 1 has no object, so the object seen again at frame 2 is a new id; frame 3 is
    # empty, so frame 4 starts another
    assert ids == [{1}, set(), {2}, set(), {3}, {3}]
    s = Stitcher(LM)
    empty = VolumeLabels(np.array([0, 1]), *(np.zeros(0, np.int64) for _ in range(4)))
    res = s.add_volume(empty)
    assert [(f.frame, f.label.size) for f in res] == [(0, 0), (1, 0)]
    assert s.next_id == 1 and s.track_table().id.size == 0


def test_sequence_boundaries_and_order_errors():
    data = scene([{2: 30}] * 4)
    s = Stitcher(LM)
    s.add_volume(volume(data, 0, 2))
    s.add_volume(volume(data, 1, 2))
    with pytest.raises(StitchError, match="does not advance"):
        s.add_volume(volume(data, 0, 2))  # the next sequence's first volume fed to this stitcher
    s2 = Stitcher(LM)  # a new sequence: its own counter from 1
    assert (s2.add_volume(volume(data, 0, 2))[0].label >> 16)[5] == 1
    # k = 1 volumes do not overlap: every frame's instances are fresh
    out = run(data, 1, 1)
    assert [int((out[f] >> 16)[5]) for f in range(4)] == [1, 2, 3, 4]
    with pytest.raises(StitchError, match="contiguous"):
        Stitcher(LM).add_volume(VolumeLabels(np.array([0, 2]), *(np.zeros(0, np.int64) for _ in range(4))))
    bad = volume(data, 0, 2)
    with pytest.raises(StitchError, match="'instance' has shape"):
        Stitcher(LM).add_volume(replace(bad, instance=bad.instance[:-1]))
    with pytest.raises(StitchError, match=r"points 0\.\.n-1"):
        Stitcher(LM).add_volume(replace(bad, source_index=bad.source_index * 2))


def test_track_table():
    frames = [{2: 30, 3: 10}] * 3 + [{3: 12}] * 2
    data = scene(frames)
    s = Stitcher(LM)
    for start in range(4):
        scores = {100 * (start + 1) + 2: 0.5 if start != 1 else float("nan"), 100 * (start + 1) + 3: 1.0}
        s.add_volume(volume(data, start, 2, scores=scores))
    t = s.track_table()
    assert t.id.tolist() == [1, 2]
    assert t.semantic.tolist() == [CAR, PERSON]
    assert t.first_frame.tolist() == [0, 0] and t.last_frame.tolist() == [2, 4]
    assert t.n_points.tolist() == [90, 54] and t.n_frames.tolist() == [3, 5]
    np.testing.assert_allclose(t.confidence, [0.5, 1.0])
    np.testing.assert_allclose(t.min_link_iou, [1.0, 1.0])
    cols = t.columns(LM)
    assert cols["raw_class"] == [10, 30] and cols["frames"] == [[0, 1, 2], [0, 1, 2, 3, 4]]
    assert cols["frame_points"] == [[30, 30, 30], [10, 10, 10, 12, 12]]
    rows = list(zip(t.frame_track.tolist(), t.frame_index.tolist(), t.frame_points.tolist(), strict=True))
    assert rows == [
        (1, 0, 30),
        (1, 1, 30),
        (1, 2, 30),
        (2, 0, 10),
        (2, 1, 10),
        (2, 2, 10),
        (2, 3, 12),
        (2, 4, 12),
    ]


def _noisy_sequence(seed: int, n_frames: int = 12):
    rng = np.random.default_rng(seed)
    frames = []
    for f in range(n_frames):
        objs = {o: int(rng.integers(5, 40)) for o in range(2, 9) if rng.random() < 0.7 or f % 5 == 0}
        frames.append(objs)
    data = scene(frames)

    def relabel(f, g):  # local ids, random splits of some objects
        r = np.random.default_rng([seed, f])
        raw = np.where(g > 0, g * 10 + (r.random(g.size) < 0.2), 0)
        return raw

    return data, relabel


@pytest.mark.parametrize(("k", "stride"), [(2, 1), (4, 1), (3, 2)])
def test_resume_from_state_is_identical(k, stride):
    data, relabel = _noisy_sequence(3)
    starts = list(range(0, len(data) - k + stride, stride))
    ref = Stitcher(LM)
    ref_frames = [ff for st in starts for ff in ref.add_volume(volume(data, st, k, relabel=relabel))]
    for cut in range(1, len(starts)):
        s = Stitcher(LM)
        got: list[FinishedFrame] = []
        for st in starts[:cut]:
            got += s.add_volume(volume(data, st, k, relabel=relabel))
        state = json.loads(json.dumps(s.state_dict()))  # a killed run kept only this
        s = Stitcher.from_state(state, LM)
        for st in starts[cut:]:
            got += s.add_volume(volume(data, st, k, relabel=relabel))
        assert [f.frame for f in got] == [f.frame for f in ref_frames]
        assert all((a.label == b.label).all() for a, b in zip(got, ref_frames, strict=True))
        ta, tb = s.track_table(), ref.track_table()
        for name in ta.__dataclass_fields__:
            np.testing.assert_array_equal(getattr(ta, name), getattr(tb, name))
    with pytest.raises(StitchError, match="version"):
        Stitcher.from_state({"version": 99})


def test_state_is_compact_and_round_trips_and_older_versions_are_refused():
    data, relabel = _noisy_sequence(4)
    ref, s = Stitcher(LM), Stitcher(LM)
    for st in range(3):
        ref.add_volume(volume(data, st, 3, relabel=relabel))
        s.add_volume(volume(data, st, 3, relabel=relabel))
    state = s.state_dict()
    assert isinstance(state["carry_keys"], str) and state["version"] == 3
    assert np.cumsum(_unpack(state["carry_keys"])).size > 100
    with pytest.raises(StitchError, match="stitch state version 2, expected 3"):
        Stitcher.from_state(dict(state, version=2), LM)
    s2 = Stitcher.from_state(json.loads(json.dumps(state)), LM)
    for st in range(3, len(data) - 2):
        a = ref.add_volume(volume(data, st, 3, relabel=relabel))
        b = s2.add_volume(volume(data, st, 3, relabel=relabel))
        assert [x.frame for x in a] == [x.frame for x in b]
        assert all((x.label == y.label).all() for x, y in zip(a, b, strict=True))


def test_ids_never_reused_on_a_random_sequence():
    data, relabel = _noisy_sequence(7, n_frames=20)
    out = run(data, 2, 1, relabel=relabel)
    # each id lives on one contiguous run of frames: once gone, it never comes back
    seen_last: dict[int, int] = {}
    for f in range(20):
        for i in set((out[f] >> 16).tolist()) - {0}:
            assert seen_last.get(i, f - 1) == f - 1, f"id {i} reappears at frame {f}"
            seen_last[i] = f

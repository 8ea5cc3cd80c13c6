"""Class-balanced pseudo-label selection: per-class quantile thresholds (golden values), instance
targets only from confident, consistent tracks, and the voxel and track consistency votes."""

import numpy as np
import pytest

from dsnet_core.adapt import (
    ConfidenceHistogram,
    SelectionParams,
    SelectionStats,
    TrackVotes,
    VoxelVotes,
    frame_consistency,
    select_frame,
)
from dsnet_core.adapt.selection import NONE
from dsnet_core.errors import ConfigError

ROAD, CAR, PERSON, POLE = 9, 1, 6, 18


def test_each_class_keeps_its_own_most_confident_share():
    """Road is sure of itself, person is not: a global 0.9 threshold would keep road only; per-class
    quantiles keep half of each."""
    hist = ConfidenceHistogram(20)
    road_conf = np.repeat(np.arange(150, 250), 10)  # 1000 points, 10 per level 150..249
    person_conf = np.arange(100, 110)  # 10 points, levels 100..109
    hist.add(np.full(1000, ROAD), road_conf)
    hist.add(np.full(10, PERSON), person_conf)
    hist.add(np.full(5, POLE), np.full(5, 250))  # all sure: capped at max_confidence
    hist.add(np.full(5, CAR), np.full(5, 10))  # all unsure: raised to min_confidence
    t = hist.thresholds(SelectionParams(keep=0.5, min_confidence=0.3, max_confidence=0.9))
    assert t[ROAD] == 200 and t[PERSON] == 105  # exactly half of each at or above
    assert t[POLE] == 229 and t[CAR] == 77  # floor(0.9 · 255), ceil(0.3 · 255)
    assert t[0] == NONE and t[2] == NONE  # the ignore class, a class without points
    assert (road_conf >= t[ROAD]).sum() == 500 and (person_conf >= t[PERSON]).sum() == 5
    assert (np.full(5, 10) >= t[CAR]).sum() == 0


def test_ties_are_kept_together_and_order_does_not_matter():
    a, b = ConfidenceHistogram(20), ConfidenceHistogram(20)
    sem, conf = np.full(10, ROAD), np.array([200] * 4 + [100] * 6)
    a.add(sem, conf)
    for i in range(10)[::-1]:
        b.add(sem[i : i + 1], conf[i : i + 1])
    t = a.thresholds(SelectionParams(keep=0.3, min_confidence=0.0, max_confidence=1.0))
    assert t[ROAD] == 200  # 3 wanted, the 4 tied at 200 are kept
    assert np.array_equal(b.counts, a.counts)
    masked = ConfidenceHistogram(20)
    masked.add(sem, conf, mask=conf > 150)
    assert masked.counts[ROAD, 200] == 4 and masked.counts.sum() == 4


def test_frame_selection_keeps_confident_consistent_points_and_whole_instances():
    params = SelectionParams(instance_share=0.5)
    thresholds = np.full(20, NONE)
    thresholds[ROAD], thresholds[CAR] = 200, 150
    sem = np.array([ROAD] * 4 + [CAR] * 5 + [CAR] * 5 + [CAR] * 2)
    inst = np.array([0] * 4 + [7] * 5 + [8] * 5 + [9] * 2)
    conf = np.array([250, 199, 250, 250, 200, 200, 200, 10, 10, 200, 200, 10, 10, 10, 255, 255])
    consistent = np.array([True, True, False, True, *[True] * 10, False, False])
    out_sem, out_inst = select_frame(sem, inst, conf, consistent, thresholds, params)
    # road: confident and consistent only; car 7: 3/5 pass → whole instance target (its unsure
    # points too); car 8: 2/5 pass → its confident points keep the class but no instance target;
    # car 9: an inconsistent track → nothing
    assert out_sem.tolist() == [ROAD, 0, 0, ROAD] + [CAR] * 5 + [CAR, CAR, 0, 0, 0] + [0, 0]
    assert out_inst.tolist() == [0] * 4 + [7] * 5 + [0] * 5 + [0, 0]


def test_bad_selection_settings_are_refused_in_one_line():
    with pytest.raises(ConfigError, match="keep=0"):
        SelectionParams(keep=0.0)
    with pytest.raises(ConfigError, match=r"min_confidence=0\.95"):
        SelectionParams(min_confidence=0.95, max_confidence=0.9)


def test_voxel_share_counts_every_frame_in_any_order():
    """One voxel sees road in three frames and sidewalk in one: road is 3/4 of its votes."""
    xyz = np.array([[0.1, 0.1, 0.1], [0.2, 0.2, 0.2], [5.0, 5.0, 0.0]])
    frames = [(xyz[:1], [ROAD]), (xyz[1:2], [ROAD]), (xyz[:1], [2]), (xyz[1:], [ROAD, POLE])]
    shares = []
    for order in (frames, frames[::-1]):
        votes = VoxelVotes(20, voxel=0.5, reduce_every=2)
        for pts, sem in order:
            votes.add(pts, np.array(sem))
        votes.add(xyz, np.zeros(3, np.int64))  # ignored labels do not vote
        votes.finish()
        shares.append(votes.share(xyz, np.array([ROAD, 2, POLE])))
    assert np.allclose(shares[0], [0.75, 0.25, 1.0]) and np.array_equal(shares[0], shares[1])
    assert votes.share(np.array([[50.0, 0, 0]]), np.array([ROAD])).tolist() == [0.0]  # an empty voxel


def test_tracks_must_be_seen_long_enough_and_agree_with_their_class():
    tracks = TrackVotes()
    # track 3: 2 frames, 4 of 5 points agree; track 4: 2 frames, 1 of 4; track 5: one frame
    tracks.add(np.array([3, 3, 3, 4, 4, 5]), np.full(6, CAR), np.array([CAR, CAR, CAR, CAR, 2, CAR]))
    tracks.add(np.array([3, 3, 4, 4, 0]), np.full(5, CAR), np.array([CAR, 2, 2, 2, 9]))
    ids, ok = tracks.consistent(SelectionParams(min_share=0.6, min_track_frames=2))
    assert ids.tolist() == [3, 4, 5] and ok.tolist() == [True, False, False]
    sem = np.array([ROAD, ROAD, CAR, CAR, CAR])
    inst = np.array([0, 0, 3, 4, 6])
    world = np.array([[0.1, 0.1, 0.1], [9.0, 9.0, 9.0], [0, 0, 0], [0, 0, 0], [0, 0, 0]])
    votes = VoxelVotes(20, 0.5)
    votes.add(world[:1], np.array([ROAD]))
    votes.finish()
    got = frame_consistency(sem, inst, world, votes, (ids, ok), SelectionParams())
    assert got.tolist() == [True, False, True, False, False]  # unknown track 6 is not consistent
    no_poses = frame_consistency(sem, inst, None, None, (ids, ok), SelectionParams())
    assert no_poses.tolist() == [True, True, True, False, False]


def test_statistics_record_coverage_and_precision_per_class():
    names = tuple(f"c{i}" for i in range(20))
    stats = SelectionStats(20)
    sem = np.array([ROAD] * 4 + [CAR] * 2)
    pseudo = np.array([ROAD, ROAD, 0, 0, CAR, 0])
    gt = np.array([ROAD, 2, ROAD, ROAD, CAR, 0])
    conf = np.array([255, 128, 0, 10, 250, 30], np.uint8)
    stats.add(
        sem,
        np.array([0, 0, 0, 0, 5, 5]),
        conf,
        np.ones(6, bool),
        pseudo,
        np.array([0] * 4 + [5, 0]),
        gt,
        previous=np.array([ROAD, 2, 0, ROAD, 0, 0]),
    )
    t = np.full(20, NONE)
    t[ROAD] = 255
    rec = stats.record(names, t)
    assert rec["coverage_per_class"] == {f"c{ROAD}": 0.5, f"c{CAR}": 0.5}
    assert rec["precision_per_class"] == {f"c{ROAD}": 0.5, f"c{CAR}": 1.0} and rec["precision"] == 0.6667
    assert rec["thresholds"] == {f"c{ROAD}": 1.0} and rec["instance_targets"] == 1 and rec["instances"] == 1
    assert rec["agreement_with_previous_round"] == 0.5  # two points selected in both rounds, one agrees
    assert sum(rec["confidence_histogram"]) == 6 and rec["confidence_histogram"][19] == 2

"""The DS-Net + tracking baseline on hand-built moving objects."""

import json

import numpy as np
import pytest

from dsnet_core.labels import load_label_map
from dsnet_core.temporal.stitching import StitchError
from dsnet_core.temporal.tracking import Tracker, instance_centroids

LM = load_label_map("semantic-kitti")
CAR, TRUCK, PERSON, ROAD = 1, 4, 6, 9


def yaw_pose(theta: float, tx: float, ty: float) -> np.ndarray:
    p = np.eye(4)
    c, s = np.cos(theta), np.sin(theta)
    p[:2, :2] = [[c, -s], [s, c]]
    p[:2, 3] = tx, ty
    return p


def frame(objects, pose, rng, raw_offset=0):
    """Points of objects given as (world centre, class, gt id) in the sensor frame of ``pose``.

    Raw instance ids are local to the frame (gt id + ``raw_offset``), as a 3D clusterer gives.
    """
    pts, sem, inst = [rng.uniform(-20, 20, (50, 3))], [np.full(50, ROAD)], [np.zeros(50, np.int64)]
    for centre, cls, gid in objects:
        pts.append(np.asarray(centre) + rng.normal(0, 0.3, (40, 3)))
        sem.append(np.full(40, cls))
        inst.append(np.full(40, gid + raw_offset))
    world = np.concatenate(pts)
    inv = np.linalg.inv(pose)
    sensor = world @ inv[:3, :3].T + inv[:3, 3]
    return sensor, np.concatenate(sem), np.concatenate(inst)


def ids(label, inst, gid):
    u = np.unique((label >> 16)[inst == gid])
    assert u.size == 1
    return int(u[0])


def test_centroids_and_majority_class():
    xyz = np.array([[0, 0, 0], [2, 0, 0], [10, 0, 0], [5, 5, 5]], float)
    i, c, k = instance_centroids(xyz, np.array([1, 4, 6, 9]), np.array([3, 3, 7, 0]), np.ones(4, bool))
    assert i.tolist() == [3, 7] and k.tolist() == [1, 6]
    np.testing.assert_allclose(c, [[1, 0, 0], [10, 0, 0]])


def run(tracker, frames_objs, poses, rng, use_pose=True):
    """Track frames; return per frame {gt id: track id}."""
    out = []
    for f, (objs, pose) in enumerate(zip(frames_objs, poses, strict=True)):
        xyz, sem, inst = frame(objs, pose, rng, raw_offset=10 * f)
        label = tracker.add_frame(xyz, sem, inst, pose if use_pose else None)
        out.append({g: ids(label, inst, g + 10 * f) for _, _, g in objs})
    return out


def test_ego_motion_compensation_keeps_ids():
    # the ego turns and drives 2 m/frame; a parked car and a walking person (0.3 m/frame)
    poses = [yaw_pose(0.1 * f, 2.0 * f, 0.1 * f * f) for f in range(10)]
    objs = [[((8.0, 3.0, 0.0), CAR, 1), ((5.0 + 0.3 * f, -4.0, 0.0), PERSON, 2)] for f in range(10)]
    got = run(Tracker(LM), objs, poses, np.random.default_rng(0))
    assert got == [{1: 1, 2: 2}] * 10
    # without ego-motion compensation sensor-frame centroids jump: ids break in most frames
    got = run(Tracker(LM, constant_velocity=False), objs, poses, np.random.default_rng(0), use_pose=False)
    assert len({i for g in got for i in g.values()}) >= 15  # vs 2 with compensation
    # (a constant-velocity prediction recovers part of it, as the apparent motion is smooth)
    got = run(Tracker(LM), objs, poses, np.random.default_rng(0), use_pose=False)
    assert 2 < len({i for g in got for i in g.values()}) < 20


def test_constant_velocity_bridges_an_occlusion():
    # a car at 1.2 m/frame is hidden in frames 4-5; reappears 3.6 m from where it was last seen
    poses = [np.eye(4)] * 10
    objs = [[((1.2 * f, 0.0, 0.0), CAR, 1)] if f not in (4, 5) else [] for f in range(10)]
    cv = run(Tracker(LM, max_age=2), objs, poses, np.random.default_rng(1))
    assert {i for g in cv for i in g.values()} == {1}
    still = run(Tracker(LM, max_age=2, constant_velocity=False), objs, poses, np.random.default_rng(1))
    assert [g.get(1) for g in still] == [1, 1, 1, 1, None, None, 2, 2, 2, 2]


def test_ids_never_reused_after_a_track_ends():
    poses = [np.eye(4)] * 8
    # object 1 visible 0-1, gone 2-5 (longer than max_age), back at 6-7 in the same place;
    # object 2 appears at frame 4
    objs = [[((0.0, 0.0, 0.0), CAR, 1)] if f in (0, 1, 6, 7) else [] for f in range(8)]
    for f in (4, 5, 6, 7):
        objs[f] = [*objs[f], ((10.0, 0.0, 0.0), CAR, 2)]
    got = run(Tracker(LM, max_age=2), objs, poses, np.random.default_rng(2))
    assert [g.get(1) for g in got] == [1, 1, None, None, None, None, 3, 3]
    assert [g.get(2) for g in got] == [None] * 4 + [2] * 4


def test_class_compatibility_and_greedy_closest_first():
    poses = [np.eye(4)] * 3
    # a person walks right past a parked car: never associated across incompatible classes
    objs = [[((0.0, 0.0, 0.0), CAR, 1), ((1.0 - 0.5 * f, 0.2, 0.0), PERSON, 2)] for f in range(3)]
    got = run(Tracker(LM, constant_velocity=False), objs, poses, np.random.default_rng(3))
    assert got == [{1: 1, 2: 2}] * 3
    # a car predicted as truck in one frame stays on its track (vehicle group)
    objs = [[((5.0, 0.0, 0.0), CAR if f != 1 else TRUCK, 1)] for f in range(3)]
    got = run(Tracker(LM), objs, poses, np.random.default_rng(4))
    assert got == [{1: 1}] * 3
    # two cars following each other 1.8 m apart: greedy closest-first with velocity keeps them
    poses = [np.eye(4)] * 6
    objs = [[((0.5 * f, 0.0, 0.0), CAR, 1), ((0.5 * f - 1.8, 0.0, 0.0), CAR, 2)] for f in range(6)]
    got = run(Tracker(LM), objs, poses, np.random.default_rng(5))
    assert got == [{1: 1, 2: 2}] * 6


@pytest.mark.parametrize("cut", [1, 4, 7])
def test_resume_from_state(cut):
    poses = [yaw_pose(0.05 * f, 1.0 * f, 0.0) for f in range(10)]
    objs = [[((8.0 + 0.8 * f, 3.0, 0.0), CAR, 1)] if f != 5 else [] for f in range(10)]
    ref = run(Tracker(LM), objs, poses, np.random.default_rng(6))
    rng = np.random.default_rng(6)
    t = Tracker(LM)
    first = run(t, objs[:cut], poses[:cut], rng)
    t = Tracker.from_state(json.loads(json.dumps(t.state_dict())), LM)
    assert first + run(t, objs[cut:], poses[cut:], rng) == ref


def test_class_groups_come_from_the_label_map():
    kitti = Tracker(LM)
    assert kitti._group[[1, 4, 5]].tolist() == [kitti._group[1]] * 3 and kitti._group[6] != kitti._group[1]
    nus = load_label_map("panoptic-nuscenes")
    assert nus.track_groups == ((3, 4, 5, 9, 10), (2, 6), (7,), (1,), (8,))
    g = Tracker(nus)._group
    assert g[4] == g[10] == g[9] and g[2] == g[6] and len({g[4], g[2], g[7], g[1], g[8]}) == 5
    # a car of one frame and a truck of the next share a track with nuScenes' groups too
    car, truck = 4, 10
    t = Tracker(nus)
    first = t.add_detections(np.array([[10.0, 0, 0]]), np.array([car]))
    second = t.add_detections(np.array([[10.5, 0, 0]]), np.array([truck]))
    assert first.tolist() == second.tolist() == [1]


def test_learned_velocity_associates_fast_objects_from_their_first_frame():
    # a car at 25 m/s (2.5 m per 0.1 s frame, beyond the 2 m gate) seen from its first frame:
    # the constant-velocity model has no velocity for a new track, so it never links it; the
    # learned velocity displaces each detection back onto the previous position
    centres = [np.array([[10.0 + 2.5 * f, 3.0, 0.0]]) for f in range(5)]
    cls = np.array([CAR])
    cv = Tracker(LM)
    ids_cv = [cv.add_detections(c, cls, time=0.1 * f).tolist() for f, c in enumerate(centres)]
    assert ids_cv == [[1], [2], [3], [4], [5]]
    learned = Tracker(LM)
    vel = np.array([[25.0, 0.0]])
    ids = [
        learned.add_detections(c, cls, time=0.1 * f, velocities=vel).tolist() for f, c in enumerate(centres)
    ]
    assert ids == [[1]] * 5
    # velocities are in the sensor frame: with the ego turned 90°, the same world motion is -y
    turned = Tracker(LM)
    pose = yaw_pose(np.pi / 2, 0.0, 0.0)
    world = [np.array([[10.0 + 2.5 * f, 3.0, 0.0]]) for f in range(3)]
    inv = np.linalg.inv(pose)
    sensor = [w @ inv[:3, :3].T + inv[:3, 3] for w in world]
    v_sensor = np.array([[0.0, -25.0]])
    got = [turned.add_detections(s, cls, pose, 0.1 * f, v_sensor).tolist() for f, s in enumerate(sensor)]
    assert got == [[1]] * 3


def test_learned_velocity_bridges_occlusion_and_state_round_trips():
    vel = np.array([[12.0, 0.0]])
    t = Tracker(LM, max_age=2)
    out = []
    for f in range(8):
        if f in (3, 4):
            out.append(
                t.add_detections(
                    np.zeros((0, 3)), np.zeros(0, np.int64), time=0.1 * f, velocities=np.zeros((0, 2))
                ).tolist()
            )
            continue
        if f == 5:
            t = Tracker.from_state(json.loads(json.dumps(t.state_dict())), LM)
        out.append(
            t.add_detections(
                np.array([[1.2 * f, 0.0, 0.0]]), np.array([CAR]), time=0.1 * f, velocities=vel
            ).tolist()
        )
    assert out == [[1], [1], [1], [], [], [1], [1], [1]]
    with pytest.raises(StitchError, match="label map 'panoptic-nuscenes'"):
        Tracker.from_state({**t.state_dict(), "label_map": "panoptic-nuscenes"}, LM)

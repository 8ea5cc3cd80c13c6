"""MOST targets: modal centres, shrink-wrapped and MAX extents, centred-difference velocities,
and the heatmap targets' Gaussian peaks at projected modal centres."""

import numpy as np
import pytest

from dsnet_core.most.config import BevGrid
from dsnet_core.most.heatmap import bev_targets, cell_centre, cell_of, gaussian_sigma
from dsnet_core.most.targets import (
    ObjectTargets,
    frame_objects,
    max_extents,
    sequence_targets,
    transform_targets,
)

CAR, PERSON = 1, 6


def key(cls, i):
    return (cls << 32) | i


def cloud(rng, objects):
    """Points of boxes given as (key, centre, half-size, n)."""
    pts, keys = [], []
    for k, c, h, n in objects:
        pts.append(np.asarray(c) + rng.uniform(-1, 1, (n, 3)) * h)
        keys.append(np.full(n, k))
    pts.append(rng.uniform(-30, 30, (200, 3)))
    keys.append(np.zeros(200, np.int64))
    return np.concatenate(pts), np.concatenate(keys)


def test_modal_centre_is_the_mean_and_extent_the_largest_deviation():
    xyz = np.array([[0, 0, 0], [4, 0, 0], [1, 3, 1], [9, 9, 9]], float)
    keys = np.array([key(CAR, 2)] * 3 + [0])
    fo = frame_objects(xyz, keys)
    assert fo.keys.tolist() == [key(CAR, 2)] and fo.classes.tolist() == [CAR] and fo.counts.tolist() == [3]
    np.testing.assert_allclose(fo.centres, [[5 / 3, 1, 1 / 3]])
    np.testing.assert_allclose(fo.extents, [[4 - 5 / 3, 2, 2 / 3]])
    assert len(frame_objects(xyz, keys, min_points=4)) == 0


def test_max_extents_are_the_per_instance_maxima_over_time():
    rng = np.random.default_rng(0)
    frames = []
    for f in range(6):  # the car is seen whole, then only its rear; the person grows and shrinks
        car = (key(CAR, 1), (10.0 + f, 2.0, 0.0), (2.2 if f < 2 else 0.4, 0.9, 0.7), 150)
        person = (key(PERSON, 7), (-5.0, 1.0, 0.0), (0.3, 0.2 + 0.1 * (f % 3), 0.8), 60)
        frames.append(frame_objects(*cloud(rng, [car, person] if f != 3 else [car])))
    got = max_extents(frames)
    for k in (key(CAR, 1), key(PERSON, 7)):
        per_frame = np.stack([fo.extents[fo.keys == k][0] for fo in frames if k in fo.keys])
        np.testing.assert_array_equal(got[k], per_frame.max(0))
    targets = sequence_targets(frames)
    for fo, t in zip(frames, targets, strict=True):
        np.testing.assert_array_equal(t.keys, fo.keys)
        np.testing.assert_array_equal(t.centres, fo.centres)  # modal, per frame
        for k, r in zip(t.keys.tolist(), t.extents, strict=True):
            np.testing.assert_array_equal(r, got[k])  # MAX, the same in every frame
    assert got[key(CAR, 1)][0] > 2.0  # the rear-only frames keep the full length


def test_velocities_are_centred_differences_in_the_sensor_frame():
    # the ego turns 90° and drives; a car moves at (3, 1) m/s in the world, sampled every 0.1 s
    rng = np.random.default_rng(1)
    times = [0.0, 0.1, 0.2, 0.35]
    poses, frames = [], []
    for f, t in enumerate(times):
        pose = np.eye(4)
        yaw = 0.5 * np.pi * f / 3
        pose[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
        pose[:3, 3] = [5.0 * t, 1.0, 0.2]
        world = np.array([20.0 + 3.0 * t, 4.0 + 1.0 * t, -0.5])
        sensor = np.linalg.solve(pose, np.r_[world, 1.0])[:3]
        pts = sensor + rng.normal(0, 0.01, (30, 3))
        pts -= pts.mean(0) - sensor  # the modal centre is exactly the object's position
        poses.append(pose)
        frames.append(frame_objects(pts, np.full(30, key(CAR, 3))))
    targets = sequence_targets(frames, np.stack(poses), times)
    for f, t in enumerate(targets):
        assert t.has_velocity.tolist() == [True]
        yaw = 0.5 * np.pi * f / 3
        rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
        np.testing.assert_allclose(t.velocity[0], rot.T @ [3.0, 1.0], atol=1e-9)
    # alone in its sequence, an object has no velocity target
    single = sequence_targets(frames[:1], np.stack(poses[:1]), times[:1])
    assert single[0].has_velocity.tolist() == [False] and single[0].velocity.tolist() == [[0.0, 0.0]]


def test_augmentation_maps_centres_and_velocities_exactly():
    t = ObjectTargets(
        np.array([key(CAR, 1)]),
        np.array([CAR]),
        np.array([[10.0, 2.0, -0.5]]),
        np.array([[2.0, 1.0, 0.7]]),
        np.array([[3.0, 0.0]]),
        np.array([True]),
    )
    a = np.array([[0.0, -1.0], [1.0, 0.0]]) * 1.1  # 90° and scale 1.1
    out = transform_targets(t, a, np.array([0.5, -0.5, 0.1]), 1.1)
    np.testing.assert_allclose(out.centres, [[-2.2 + 0.5, 11.0 - 0.5, -0.55 + 0.1]])
    np.testing.assert_allclose(out.extents, [[1.1, 2.2, 0.77]])  # axes swap under 90°
    np.testing.assert_allclose(out.velocity, [[0.0, 3.3]])
    yaw45 = np.array([[1.0, -1.0], [1.0, 1.0]]) / np.sqrt(2)
    np.testing.assert_allclose(
        transform_targets(t, yaw45, np.zeros(3), 1.0).extents[0, :2], [3 / np.sqrt(2)] * 2
    )


def test_heatmap_peaks_at_projected_modal_centres():
    grid = BevGrid(half_extent=20.0, cell=0.5)
    t = ObjectTargets(
        np.array([key(CAR, 1), key(CAR, 2), key(PERSON, 3), key(CAR, 4)]),
        np.array([CAR, CAR, PERSON, CAR]),
        np.array([[5.3, -2.1, -0.8], [-12.6, 7.9, -1.0], [3.05, 3.2, -0.9], [25.0, 0.0, 0.0]]),
        np.array([[2.0, 0.9, 0.7], [1.0, 1.0, 0.7], [0.3, 0.3, 0.9], [2.0, 1.0, 0.7]]),
        np.array([[1.0, 0.5], [0.0, 0.0], [0.2, 0.1], [0.0, 0.0]]),
        np.array([True, False, True, True]),
    )
    tg = bev_targets(t, grid, (1, 2, 3, 4, 5, 6, 7, 8))
    assert tg.heatmap.shape == (8, 80, 80)
    assert tg.keys.tolist() == [key(CAR, 1), key(CAR, 2), key(PERSON, 3)]  # the 4th is off the grid
    cells = cell_of(t.centres[:3, :2], grid)
    for (ix, iy), ch in zip(cells, [0, 0, 5], strict=True):
        heat = tg.heatmap[ch]
        assert heat[ix, iy] == 1.0
        win = heat[ix - 1 : ix + 2, iy - 1 : iy + 2]
        assert (win <= 1.0).all() and (win == 1.0).sum() == 1  # a single peak
    assert (tg.heatmap == 1.0).sum() == 3 and tg.heatmap[[1, 2, 3, 4, 6, 7]].max() == 0.0
    # the blob is a Gaussian with σ = max(‖r_xy‖ / 3, 0.8 cell)
    sig = gaussian_sigma(t.extents[:1], grid)[0]
    assert sig == pytest.approx(np.hypot(2.0, 0.9) / 3 / 0.5)
    ix, iy = cells[0]
    for d in (1, 2, 3):
        assert tg.heatmap[0, ix + d, iy] == pytest.approx(np.exp(-(d**2) / (2 * sig**2)), rel=1e-6)
    assert gaussian_sigma(t.extents[2:3], grid)[0] == 0.8  # a person gets the floor
    # regression targets: sub-cell offsets, heights, extents, velocities at the centre cells
    np.testing.assert_allclose(tg.offset + cell_centre(cells, grid), t.centres[:3, :2], atol=1e-6)
    np.testing.assert_allclose(tg.height, t.centres[:3, 2], atol=1e-6)
    assert tg.index.tolist() == (cells[:, 0] * 80 + cells[:, 1]).tolist()
    assert tg.vel_mask.tolist() == [True, False, True] and tg.cls.tolist() == [0, 0, 5]

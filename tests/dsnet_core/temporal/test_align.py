"""Eq. 7 alignment: windows, the transform, a parked car coinciding, and exact splits."""

import numpy as np
import pytest

from dsnet_core.temporal.align import build_volume, plan_windows, split_volume, to_reference
from tests.logs import NOISE, car_world, pose


def test_plan_windows_cover_every_frame():
    assert plan_windows(7, 1, 1) == [(i,) for i in range(7)]
    assert plan_windows(7, 3, 2) == [(0, 1, 2), (2, 3, 4), (4, 5, 6)]
    # the stride does not land on the end: a last window ends at the last frame
    assert plan_windows(8, 3, 2) == [(0, 1, 2), (2, 3, 4), (4, 5, 6), (5, 6, 7)]
    assert plan_windows(2, 4, 3) == [(0, 1)]
    assert plan_windows(0, 2, 1) == []
    with pytest.raises(ValueError, match="stride 3 > scans 2"):
        plan_windows(5, 2, 3)


def test_eq7_row_vector_form():
    rng = np.random.default_rng(3)
    p = rng.normal(size=(20, 3)) * 10
    src, ref = pose(5), pose(2)
    r_s, t_s, r_r, t_r = src[:3, :3], src[:3, 3], ref[:3, :3], ref[:3, 3]
    # P' = ((P R_s⁻¹ + T_s) − T_r) R_r, rows as points, R the pose's rotation block
    expected = ((p @ np.linalg.inv(r_s) + t_s) - t_r) @ r_r
    np.testing.assert_allclose(to_reference(p, src, ref), expected, atol=1e-9)
    np.testing.assert_allclose(to_reference(p, ref, ref), p, atol=1e-12)


def _car_scans(frames, rng):
    car = car_world()
    scans, poses = [], []
    for f in frames:
        inv = np.linalg.inv(pose(f))
        xyz = car @ inv[:3, :3].T + inv[:3, 3] + rng.normal(0, NOISE, size=car.shape)
        scans.append(np.c_[xyz, rng.uniform(0, 1, len(car))].astype(np.float32))
        poses.append(pose(f))
    return scans, poses


def test_parked_car_coincides_in_reference_frame():
    rng = np.random.default_rng(0)
    frames = [3, 4, 5, 6]
    scans, poses = _car_scans(frames, rng)
    vol = build_volume(scans, poses, frames)
    ref_points = vol.points[vol.source_frame == 6, :3]
    for f in frames[:-1]:
        aligned = vol.points[vol.source_frame == f, :3]
        err = np.linalg.norm(aligned - ref_points, axis=1)
        assert err.max() < 8 * NOISE  # the same physical points, within sensor noise
        raw = scans[frames.index(f)][:, :3]
        assert np.linalg.norm(raw - ref_points, axis=1).min() > 1.0  # unaligned they are metres apart


def test_split_volume_restores_scans_exactly():
    rng = np.random.default_rng(1)
    frames = [0, 1, 2]
    scans, poses = _car_scans(frames, rng)
    scans[1] = scans[1][:123]  # scans of different sizes
    labels = [rng.integers(0, 2**20, len(s)).astype(np.uint32) for s in scans]
    vol = build_volume(scans, poses, frames, labels)
    assert vol.points.shape == (sum(len(s) for s in scans), 4) and vol.points.dtype == np.float32
    perm = rng.permutation(len(vol.points))  # results may come back in any order
    lab = split_volume(vol.labels[perm], vol.source_frame[perm], vol.source_index[perm])
    rem = split_volume(vol.points[perm, 3], vol.source_frame[perm], vol.source_index[perm])
    xyz = split_volume(vol.points[perm, :3], vol.source_frame[perm], vol.source_index[perm])
    for i, f in enumerate(frames):
        assert np.array_equal(lab[f], labels[i])
        assert np.array_equal(rem[f], scans[i][:, 3])
        back = to_reference(xyz[f], poses[-1], poses[i])  # the inverse transform
        np.testing.assert_allclose(back, scans[i][:, :3], atol=2e-5)
    with pytest.raises(ValueError, match="not a permutation"):
        split_volume(vol.labels, vol.source_frame, np.zeros_like(vol.source_index))

"""Small SemanticKITTI-layout logs for store/flow tests, with a parked car placed by hand.

The world holds a ground patch (raw id 40, road) and a parked car (raw id 10, instance 1): a fixed
set of world points seen in every frame, so the same physical point can be compared across scans
after alignment. The sensor drives along x with a slow yaw; every frame sees the car's points
(in the same order) plus a random subset of ground points, with Gaussian sensor noise.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dsnet_core.io import kitti
from dsnet_core.io.semantickitti import write_frame, write_sequence_meta

TR = np.array([[0, -1, 0, 0.1], [0, 0, -1, -0.05], [1, 0, 0, -0.3], [0, 0, 0, 1]], dtype=np.float64)
NOISE = 0.005  # m, per coordinate
CAR_CENTRE = np.array([12.0, 4.0, -0.9])


def pose(i: int) -> np.ndarray:
    """float64 (4, 4) LiDAR-frame pose of frame i: 1.5 m/frame along x, 0.04 rad/frame yaw."""
    m = np.eye(4)
    c, s = np.cos(0.04 * i), np.sin(0.04 * i)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:3, 3] = [1.5 * i, 0.1 * i, 0.02 * i]
    return m


def car_world(n: int = 300, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return CAR_CENTRE + rng.uniform(-1, 1, size=(n, 3)) * [2.0, 0.9, 0.7]


def make_log(
    root: Path,
    sequences: tuple[str, ...] = ("00",),
    n_frames: int = 8,
    n_ground: int = 1500,
    n_car: int = 300,
    seed: int = 0,
) -> Path:
    """Write the log under ``root`` (``root/sequences/SS``). Point counts vary per frame."""
    car = car_world(n_car)
    for s_i, seq in enumerate(sequences):
        rng = np.random.default_rng(seed + 100 * s_i)
        seq_dir = Path(root) / "sequences" / seq
        poses = np.stack([pose(i) for i in range(n_frames)])
        for i in range(n_frames):
            n_g = int(n_ground + rng.integers(-200, 200))
            ground = np.c_[rng.uniform(-30, 40, size=(n_g, 2)), np.full(n_g, -1.7)]
            world = np.concatenate([ground, car])
            inv = np.linalg.inv(poses[i])
            xyz = world @ inv[:3, :3].T + inv[:3, 3] + rng.normal(0, NOISE, size=world.shape)
            scan = np.c_[xyz, rng.uniform(0, 1, len(world))].astype(np.float32)
            sem = np.r_[np.full(n_g, 40), np.full(len(car), 10)]
            inst = np.r_[np.zeros(n_g, int), np.ones(len(car), int)]
            write_frame(seq_dir, f"{i:06d}", scan, kitti.join_label(sem, inst))
        write_sequence_meta(seq_dir, poses, TR, np.arange(n_frames) * 0.1)
    return Path(root)

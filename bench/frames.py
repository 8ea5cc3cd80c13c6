"""A LiDAR-like synthetic frame for benchmarks (no labels): a 64-beam scan of a ground plane,
walls and boxes, ~120k points, ~30k occupied cylinder cells."""

from __future__ import annotations

import numpy as np


def lidar_like_frame(n_beams: int = 64, n_azimuth: int = 1900, seed: int = 0) -> np.ndarray:
    """float32 ``(N, 4)`` x, y, z, remission."""
    rng = np.random.default_rng(seed)
    elev = np.deg2rad(np.linspace(-24.8, 2.0, n_beams))
    azim = np.linspace(-np.pi, np.pi, n_azimuth, endpoint=False)
    el, az = np.meshgrid(elev, azim, indexing="ij")
    # ground at z = -1.66; walls at a range that varies with azimuth; random obstacles
    wall = 12 + 25 * (0.5 + 0.5 * np.sin(3 * az))
    t_ground = np.where(el < 0, -1.66 / np.sin(np.minimum(el, -1e-3)), np.inf)
    t = np.minimum(t_ground, wall / np.cos(el))
    obstacle = (np.sin(40 * az) > 0.9) & (el > -0.2)
    t = np.where(obstacle, np.minimum(t, 6 + 20 * (0.5 + 0.5 * np.cos(7 * az))), t)
    keep = (t < 80) & (rng.random(az.shape) < 0.985)
    x = t * np.cos(el) * np.cos(az)
    y = t * np.cos(el) * np.sin(az)
    z = t * np.sin(el)
    pts = np.stack([x[keep], y[keep], z[keep], rng.random(keep.sum())], axis=1)
    pts[:, :3] += rng.normal(0, 0.01, (len(pts), 3))
    return pts.astype(np.float32)

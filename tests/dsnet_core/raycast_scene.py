"""A tiny ray-cast street for odometry tests: ground plane + axis-aligned boxes, 32 beams.

Used until a test needs the full synthetic generator; it is deterministic for a seed.
"""

from __future__ import annotations

import numpy as np

SENSOR_HEIGHT = 1.73


def ground_height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Gently rolling ground, metres (slopes below ~10 %). A perfectly flat ground seen by a
    level sensor gives identical ground rings in every scan, onto which ICP locks at zero motion."""
    return (
        0.25 * np.sin(0.21 * x + 0.3)
        + 0.15 * np.sin(0.17 * y + 1.1)
        + 0.04 * np.sin(0.9 * x) * np.sin(0.8 * y)
    )


def _rot(axis: int, a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def trajectory(
    n_frames: int, speed: float = 1.0, yaw_rate: float = 0.02, jitter_deg: float = 0.1, seed: int = 0
) -> np.ndarray:
    """``(F, 4, 4)`` sensor → world poses along a curve (frame 0 at the origin, heading +x).

    The sensor rides :func:`ground_height` + 1.73 m; roll and pitch jitter (σ = ``jitter_deg``)
    stand for the vehicle's body motion.
    """
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (n_frames, 1, 1))
    x = y = 0.0
    for f in range(n_frames):
        yaw = yaw_rate * f
        roll, pitch = np.radians(rng.normal(0, jitter_deg, 2)) if f else (0.0, 0.0)
        poses[f, :3, :3] = _rot(2, yaw) @ _rot(1, pitch) @ _rot(0, roll)
        poses[f, :3, 3] = x, y, SENSOR_HEIGHT + ground_height(np.array(x), np.array(y))
        x, y = x + speed * np.cos(yaw), y + speed * np.sin(yaw)
    return poses


def street(poses: np.ndarray, seed: int = 0) -> tuple[np.ndarray, int]:
    """Boxes ``(B, 2, 3)`` (min, max corners, world metres) along the path; and the index of
    one parked car."""
    rng = np.random.default_rng(seed)
    boxes = []
    centres = poses[:, :3, 3]
    heading = poses[:, :3, 0]
    left = np.stack([-heading[:, 1], heading[:, 0], np.zeros(len(poses))], 1)
    for f in range(-20, len(poses) + 30, 5):
        i = int(np.clip(f, 0, len(poses) - 1))
        base = centres[i] + heading[i] * (f - i)
        for side in (-1, 1):
            c = base + side * left[i] * rng.uniform(8, 12)
            half = np.array([rng.uniform(1.5, 3), rng.uniform(1.5, 3), 0])
            boxes.append([c - half, c + half + [0, 0, rng.uniform(4, 10)]])
            if rng.random() < 0.6:  # a pole or a tree trunk
                p = base + side * left[i] * rng.uniform(5.5, 6.5) + heading[i] * rng.uniform(0, 3)
                boxes.append([p - [0.15, 0.15, 0], p + np.array([0.15, 0.15, 4])])
            for _ in range(3):  # clutter: bollards, bins, bushes
                p = base + side * left[i] * rng.uniform(3, 7) + heading[i] * rng.uniform(0, 5)
                half = rng.uniform(0.1, 0.5, 3) * [1, 1, 0] + [0, 0, rng.uniform(0.3, 1.5)]
                boxes.append([p - half * [1, 1, 0], p + half])
            if rng.random() < 0.4:  # a parked car
                p = base + side * left[i] * 4 + heading[i] * rng.uniform(0, 3)
                boxes.append([p - [2.0, 0.9, 0], p + np.array([2.0, 0.9, 1.5])])
    for b in boxes:
        b[0][2], b[1][2] = -1.0, max(b[1][2], 0.5)
    # a parked car beside the road, 12 m ahead of the first frame
    car_c = centres[0] + heading[0] * 12 + left[0] * 4
    boxes.append([car_c - [2.1, 0.9, 0], car_c + np.array([2.1, 0.9, 1.5])])
    return np.asarray(boxes, dtype=np.float64), len(boxes) - 1


def rays(n_beams: int = 32, n_azimuth: int = 600) -> np.ndarray:
    """``(R, 3)`` unit ray directions in the sensor frame (+2° to −24.9° elevation)."""
    el = np.radians(np.linspace(2.0, -24.9, n_beams))
    az = np.linspace(-np.pi, np.pi, n_azimuth, endpoint=False)
    e, a = np.meshgrid(el, az, indexing="ij")
    return np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)


def scan(pose: np.ndarray, boxes: np.ndarray, rng: np.random.Generator, max_range: float = 50.0):
    """Cast one scan. Returns ``(N, 3)`` points in the sensor frame and ``(N,)`` box index
    (-1 = ground); nearest hit wins, range noise σ = 2 cm."""
    d = rays() @ pose[:3, :3].T
    o = pose[:3, 3]
    near = np.flatnonzero(
        np.linalg.norm(np.maximum(np.maximum(boxes[:, 0] - o, o - boxes[:, 1]), 0), axis=1) < max_range
    )
    boxes = boxes[near]
    inv = 1.0 / np.where(np.abs(d) < 1e-9, 1e-9, d)  # slab test, one axis at a time
    tmin = np.full((len(d), len(boxes)), -np.inf, np.float32)
    tmax = np.full((len(d), len(boxes)), np.inf, np.float32)
    for ax in range(3):
        t1 = ((boxes[:, 0, ax] - o[ax])[None, :] * inv[:, ax, None]).astype(np.float32)
        t2 = ((boxes[:, 1, ax] - o[ax])[None, :] * inv[:, ax, None]).astype(np.float32)
        np.maximum(tmin, np.minimum(t1, t2), out=tmin)
        np.minimum(tmax, np.maximum(t1, t2), out=tmax)
    hit = (tmax >= tmin) & (tmax > 0)
    tbox = np.where(hit, np.maximum(tmin, 0), np.inf).astype(np.float64)
    which = tbox.argmin(1)
    best = tbox[np.arange(len(d)), which]
    tg = _ground_hit(o, d, max_range)
    ground = tg < best
    t = np.where(ground, tg, best)
    ok = t < max_range
    t = t[ok] + rng.normal(0, 0.02, ok.sum())
    world = o + d[ok] * t[:, None]
    sensor = (world - o) @ pose[:3, :3]
    return sensor, np.where(ground[ok], -1, near[which[ok]])


def _above(o: np.ndarray, d: np.ndarray, t: np.ndarray) -> np.ndarray:
    p = o + d * t[:, None]
    return p[:, 2] > ground_height(p[:, 0], p[:, 1])


def _ground_hit(o: np.ndarray, d: np.ndarray, max_range: float) -> np.ndarray:
    """First ground crossing along each ray: march in 2 m steps, then bisect; inf if none."""
    hit = np.full(len(d), np.inf)
    todo = np.flatnonzero(d[:, 2] < 0.05)  # rays climbing faster than the ground never hit it
    for step in np.arange(2.0, max_range + 2.0, 2.0):
        newly = ~_above(o, d[todo], np.full(len(todo), step))
        hit[todo[newly]] = step
        todo = todo[~newly]
    ok = np.isfinite(hit)
    a, b = hit[ok] - 2.0, hit[ok]
    for _ in range(16):
        m = 0.5 * (a + b)
        up = _above(o, d[ok], m)
        a, b = np.where(up, m, a), np.where(up, b, m)
    hit[ok] = 0.5 * (a + b)
    return hit


def box_distance(points: np.ndarray, box: np.ndarray) -> np.ndarray:
    """Distance of ``(N, 3)`` points to the surface of an axis-aligned ``box`` (2, 3)."""
    outside = np.linalg.norm(np.maximum(np.maximum(box[0] - points, points - box[1]), 0), axis=1)
    inside = np.minimum(points - box[0], box[1] - points).min(1)
    return np.where(outside > 0, outside, np.maximum(inside, 0))

"""MOST's training targets from modal (point-level) ground truth (paper Sec. III).

- modal centre ``c``: the mean of an instance's visible points in one scan;
- shrink-wrapped extent ``r_t = max{|p − c|}`` per axis (half-sizes of the tight axis-aligned box
  about ``c``, metres), refined by **MAX**: ``r = max_t r_t`` over every scan of the sequence in
  which the instance is seen (instance ids over time come from the ground truth);
- velocity: the centred difference of modal centres ``(μ^{t+1} − μ^{t−1}) / (t_{t+1} − t_{t−1})``
  in the world frame (poses remove ego motion), one-sided at the ends of a track, then rotated into
  the scan's sensor frame; metres per second, (x, y) only.

Instances are keyed by ``train id << 32 | instance id`` (the training samples' keys).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FrameObjects:
    """The modal objects of one scan.

    Attributes:
        keys: int64 ``(M,)`` instance keys, ascending.
        classes: int64 ``(M,)`` train ids.
        centres: float64 ``(M, 3)`` modal centres, metres, sensor frame.
        extents: float64 ``(M, 3)`` shrink-wrapped half-extents ``r_t``, metres.
        counts: int64 ``(M,)`` points.
    """

    keys: np.ndarray
    classes: np.ndarray
    centres: np.ndarray
    extents: np.ndarray
    counts: np.ndarray

    def __len__(self) -> int:
        return int(self.keys.size)


@dataclass(frozen=True)
class ObjectTargets:
    """Targets of one scan's objects: modal centres with MAX extents and velocities.

    Attributes:
        keys, classes, centres: as :class:`FrameObjects`.
        extents: float64 ``(M, 3)`` MAX extents (metres).
        velocity: float64 ``(M, 2)`` metres per second in the sensor frame (0 where unknown).
        has_velocity: bool ``(M,)`` the instance is seen in a neighbouring scan.
    """

    keys: np.ndarray
    classes: np.ndarray
    centres: np.ndarray
    extents: np.ndarray
    velocity: np.ndarray
    has_velocity: np.ndarray

    def __len__(self) -> int:
        return int(self.keys.size)


def frame_objects(xyz: np.ndarray, keys: np.ndarray, min_points: int = 1) -> FrameObjects:
    """Modal centres and shrink-wrapped extents of one scan's instances.

    Args:
        xyz: float ``(N, 3)`` points, metres, sensor frame.
        keys: int64 ``(N,)`` instance keys (``train id << 32 | id``), 0 = no instance.
        min_points: instances with fewer points are left out.
    """
    sel = keys > 0
    uk, inv = np.unique(keys[sel], return_inverse=True)
    pts = np.asarray(xyz, np.float64)[sel]
    counts = np.bincount(inv, minlength=uk.size)
    centres = np.stack([np.bincount(inv, pts[:, d], minlength=uk.size) for d in range(3)], 1)
    centres = centres / np.maximum(counts, 1)[:, None]
    extents = np.zeros((uk.size, 3))
    np.maximum.at(extents, inv, np.abs(pts - centres[inv]))
    keep = counts >= min_points
    return FrameObjects(
        uk[keep].astype(np.int64),
        (uk[keep] >> 32).astype(np.int64),
        centres[keep],
        extents[keep],
        counts[keep],
    )


def max_extents(frames: Sequence[FrameObjects]) -> dict[int, np.ndarray]:
    """MAX: per instance key, the per-axis maximum of its shrink-wrapped extents over ``frames``."""
    out: dict[int, np.ndarray] = {}
    for fo in frames:
        for key, r in zip(fo.keys.tolist(), fo.extents, strict=True):
            out[key] = np.maximum(out[key], r) if key in out else r.copy()
    return out


def _world(fo: FrameObjects, pose: np.ndarray) -> dict[int, np.ndarray]:
    w = fo.centres @ pose[:3, :3].T + pose[:3, 3]
    return dict(zip(fo.keys.tolist(), w, strict=True))


def sequence_targets(
    frames: Sequence[FrameObjects], poses: np.ndarray | None = None, times: Sequence[float] | None = None
) -> list[ObjectTargets]:
    """Per-scan targets of a sequence: MAX extents over the sequence and centred-difference velocities.

    Args:
        frames: the objects of every scan, in time order.
        poses: float64 ``(F, 4, 4)`` LiDAR-frame poses (sensor → world), or None (velocities are
            then relative to the sensor).
        times: seconds per scan, or None (0.1 s per scan, the 10 Hz spin).
    """
    n = len(frames)
    poses = np.broadcast_to(np.eye(4), (n, 4, 4)) if poses is None else np.asarray(poses, np.float64)
    t = np.arange(n) * 0.1 if times is None else np.asarray(times, np.float64)
    ext = max_extents(frames)
    world = [_world(fo, poses[f]) for f, fo in enumerate(frames)]
    out = []
    for f, fo in enumerate(frames):
        vel = np.zeros((len(fo), 2))
        has = np.zeros(len(fo), bool)
        for m, key in enumerate(fo.keys.tolist()):
            a = f - 1 if f > 0 and key in world[f - 1] else f
            b = f + 1 if f + 1 < n and key in world[f + 1] else f
            if a == b or t[b] <= t[a]:
                continue
            v_world = (world[b][key] - world[a][key]) / (t[b] - t[a])
            vel[m] = (poses[f][:3, :3].T @ v_world)[:2]
            has[m] = True
        extents = np.stack([ext[k] for k in fo.keys.tolist()]) if len(fo) else np.zeros((0, 3))
        out.append(ObjectTargets(fo.keys, fo.classes, fo.centres, extents, vel, has))
    return out


def transform_targets(
    targets: ObjectTargets, linear: np.ndarray, shift: np.ndarray, z_scale: float
) -> ObjectTargets:
    """The targets of a scan after the augmentation ``xy' = A·xy + shift_xy``, ``z' = s·z + shift_z``.

    Centres (means) and velocities map exactly; extents become those of the axis-aligned box that
    holds the transformed box: ``r'_xy = |A|·r_xy`` (elementwise absolute value), ``r'_z = s·r_z``.

    Args:
        linear: float ``(2, 2)`` A (rotation, flips, scale). shift: float ``(3,)`` metres.
        z_scale: s.
    """
    c = targets.centres.copy()
    c[:, :2] = c[:, :2] @ linear.T + shift[:2]
    c[:, 2] = c[:, 2] * z_scale + shift[2]
    r = targets.extents.copy()
    r[:, :2] = r[:, :2] @ np.abs(linear).T
    r[:, 2] = r[:, 2] * abs(z_scale)
    return ObjectTargets(
        targets.keys, targets.classes, c, r, targets.velocity @ linear.T, targets.has_velocity
    )

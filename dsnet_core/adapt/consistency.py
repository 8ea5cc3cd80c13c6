"""Whether a refined label is consistent over its voxel or its track.

Refinement gives every voxel of the static world one consensus class and every track one class;
how clear that consensus was is what makes a label trustworthy. Both votes count the teacher's
*per-frame* labels (before refinement):

- **voxel** (points without an instance): the share of all per-frame labels that fell in the
  point's world voxel (``voxel`` metres, over the whole sequence) and agree with the point's
  refined class;
- **track** (points of an instance): the track is seen in at least ``min_track_frames`` frames
  and at least ``min_share`` of its points were labelled with its refined class frame by frame.

Counts are integers, so the result does not depend on the order frames are added in. Without
poses there is no world frame: every point without an instance counts as consistent and only the
confidence threshold selects it.
"""

from __future__ import annotations

import numpy as np

from dsnet_core.adapt.selection import SelectionParams

BITS = 18
"""Bits per axis of a voxel key: ±2^17 voxels (±65 km at 0.5 m) around the world origin (the first
pose); farther points share the edge voxels. Three axes and a class id (< 2^8) fit in 63 bits."""
OFFSET = 1 << (BITS - 1)


def voxel_keys(xyz_world: np.ndarray, voxel: float) -> np.ndarray:
    """``(N,) int64`` keys of the world voxels of ``(N, 3)`` points (metres; :data:`BITS` per axis)."""
    cell = np.floor(np.asarray(xyz_world, np.float64) / voxel).astype(np.int64) + OFFSET
    cell = np.clip(cell, 0, (1 << BITS) - 1)
    return (cell[:, 0] << (2 * BITS)) | (cell[:, 1] << BITS) | cell[:, 2]


def to_world(xyz: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """``(N, 3)`` sensor-frame points through a ``(4, 4)`` sensor → world pose, float64.

    Element-wise products and sums (no BLAS), so the result is the same on every CPU."""
    xyz, pose = np.asarray(xyz, np.float64), np.asarray(pose, np.float64)
    x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    return np.stack([x * pose[i, 0] + y * pose[i, 1] + z * pose[i, 2] + pose[i, 3] for i in range(3)], 1)


class VoxelVotes:
    """Per (world voxel, class): per-frame labels of one sequence.

    Args:
        num_classes: C.
        voxel: voxel edge, metres.
        reduce_every: frames between reductions of the collected (key, count) pairs (memory).
    """

    def __init__(self, num_classes: int, voxel: float, reduce_every: int = 16) -> None:
        if num_classes > 256:
            raise ValueError(f"voxel votes take at most 256 classes, got {num_classes}")
        self.c, self.voxel, self.reduce_every = num_classes, voxel, reduce_every
        self._parts: list[tuple[np.ndarray, np.ndarray]] = []
        self._pairs = self._counts = self._voxels = self._totals = None

    def add(self, xyz_world: np.ndarray, sem: np.ndarray) -> None:
        """One frame's points (world frame) and their per-frame train ids (0 is not counted)."""
        keep = np.asarray(sem) > 0
        pairs = voxel_keys(xyz_world[keep], self.voxel) * self.c + np.asarray(sem, np.int64)[keep]
        self._parts.append(np.unique(pairs, return_counts=True))
        if len(self._parts) >= self.reduce_every:
            self._parts = [self._reduce()]

    def _reduce(self) -> tuple[np.ndarray, np.ndarray]:
        if not self._parts:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        keys = np.concatenate([k for k, _ in self._parts])
        counts = np.concatenate([n for _, n in self._parts])
        uniq, inv = np.unique(keys, return_inverse=True)
        return uniq, np.bincount(inv, weights=counts).astype(np.int64)

    def finish(self) -> None:
        """Fix the counts (call after the last :meth:`add`)."""
        self._pairs, self._counts = self._reduce()
        self._parts = []
        vox = self._pairs // self.c
        self._voxels, start = np.unique(vox, return_index=True)
        self._totals = np.add.reduceat(self._counts, start) if len(start) else np.zeros(0, np.int64)

    def share(self, xyz_world: np.ndarray, sem: np.ndarray) -> np.ndarray:
        """``(N,) float64`` the share of each point's voxel's votes that are for its class ``sem``
        (0 where the voxel has none)."""
        if self._pairs is None:
            raise RuntimeError("VoxelVotes.share before finish()")
        keys = voxel_keys(xyz_world, self.voxel)
        pair = keys * self.c + np.asarray(sem, np.int64)
        return _lookup(self._pairs, self._counts, pair) / np.maximum(
            _lookup(self._voxels, self._totals, keys), 1
        )


def _lookup(keys: np.ndarray, values: np.ndarray, query: np.ndarray) -> np.ndarray:
    if keys.size == 0:
        return np.zeros(query.shape, np.float64)
    pos = np.minimum(np.searchsorted(keys, query), keys.size - 1)
    return np.where(keys[pos] == query, values[pos], 0).astype(np.float64)


class TrackVotes:
    """Per track of one sequence: frames seen, points, and points whose per-frame class agrees with
    the refined one."""

    def __init__(self) -> None:
        self._ids: list[np.ndarray] = []
        self._rows: list[np.ndarray] = []

    def add(self, inst: np.ndarray, refined_sem: np.ndarray, frame_sem: np.ndarray) -> None:
        """One frame: refined ids and classes, and the per-frame classes of the same points."""
        tracked = np.asarray(inst) > 0
        if not tracked.any():
            return
        ids, inv = np.unique(np.asarray(inst, np.int64)[tracked], return_inverse=True)
        agree = (np.asarray(refined_sem) == np.asarray(frame_sem))[tracked]
        rows = np.stack([np.ones(ids.size, np.int64), np.bincount(inv), np.bincount(inv, weights=agree)], 1)
        self._ids.append(ids)
        self._rows.append(rows.astype(np.int64))

    def consistent(self, params: SelectionParams) -> tuple[np.ndarray, np.ndarray]:
        """``(ids, ok)``: sorted track ids ``(K,) int64`` and whether each is consistent ``(K,) bool``."""
        if not self._ids:
            return np.zeros(0, np.int64), np.zeros(0, bool)
        uniq, inv = np.unique(np.concatenate(self._ids), return_inverse=True)
        rows = np.zeros((uniq.size, 3), np.int64)
        np.add.at(rows, inv, np.concatenate(self._rows))
        frames, points, agree = rows.T
        ok = (frames >= params.min_track_frames) & (agree >= params.min_share * points - 1e-9)
        return uniq, ok


def frame_consistency(
    sem: np.ndarray,
    inst: np.ndarray,
    xyz_world: np.ndarray | None,
    votes: VoxelVotes | None,
    tracks: tuple[np.ndarray, np.ndarray],
    params: SelectionParams,
) -> np.ndarray:
    """``(N,) bool``: points without an instance whose voxel's share for their refined class is at
    least ``min_share`` (all of them without poses: ``xyz_world`` or ``votes`` None), and points of
    consistent tracks.

    Args:
        sem, inst: ``(N,) int64`` refined train ids and track ids.
        xyz_world: ``(N, 3)`` points in the world frame, or None.
        votes: the sequence's finished :class:`VoxelVotes`, or None.
        tracks: :meth:`TrackVotes.consistent` of the sequence.
    """
    inst = np.asarray(inst, np.int64)
    out = np.zeros(inst.shape, bool)
    free = inst == 0
    if xyz_world is None or votes is None:
        out[free] = True
    elif free.any():
        out[free] = votes.share(xyz_world[free], np.asarray(sem)[free]) >= params.min_share - 1e-9
    ids, ok = tracks
    if (~free).any() and ids.size:
        q = inst[~free]
        pos = np.minimum(np.searchsorted(ids, q), ids.size - 1)
        out[~free] = (ids[pos] == q) & ok[pos]
    return out

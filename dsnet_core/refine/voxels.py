"""Static-world votes in world voxels: one frame's votes, and the consensus of a window of frames.

A frame's votes are, per voxel its voters fall in, the ``top_k`` classes of their summed integer
votes (:mod:`dsnet_core.refine.frame`). A window's consensus in a voxel sums the votes of the
window's frames: the winning class, its share, the frames that voted there and the total. The
sums are integers, so the consensus of a frame depends only on the frames of its window, never
on the order or the batches they were read in.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from dsnet_core.refine.frame import FULL_VOTE
from dsnet_core.refine.kernels import accumulate, group_votes, top_k

_BITS = 21
_HALF = 1 << (_BITS - 1)


@dataclass(frozen=True)
class VoxelGrid:
    """Cubic voxels of edge ``size`` metres with a corner at ``origin`` (world frame)."""

    size: float
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def keys(self, world: np.ndarray) -> np.ndarray:
        """``(N,) int64`` key of the voxel of each point ``(N, 3)`` (metres). Indices are clipped to
        ±2^20 voxels from the origin (315 km at 0.3 m)."""
        world = np.asarray(world, np.float64)
        return self.keys_of(world[:, 0], world[:, 1], world[:, 2])

    def keys_of(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """:meth:`keys` of points given as three ``(N,)`` float64 coordinate arrays (metres)."""
        out = None
        for a, col in enumerate((x, y, z)):
            idx = (np.asarray(col, np.float64) - np.float64(self.origin[a])) / self.size
            idx = np.clip(np.floor(idx, out=idx), -_HALF + 1, _HALF - 1, out=idx).astype(np.int64) + _HALF
            out = idx if out is None else (out << _BITS) | idx
        return out


@dataclass(frozen=True)
class FrameVotes:
    """One frame's static votes.

    Attributes:
        index: the frame.
        keys: ``(U,) int64`` voxels with votes, sorted.
        cls: ``(U, k) int16`` their top classes (-1: none).
        val: ``(U, k) int64`` the summed votes of those classes.
    """

    index: int
    keys: np.ndarray
    cls: np.ndarray
    val: np.ndarray

    @property
    def nbytes(self) -> int:
        return int(self.keys.nbytes + self.cls.nbytes + self.val.nbytes)


def frame_votes(
    index: int,
    keys: np.ndarray,
    sem: np.ndarray,
    probs: np.ndarray | None,
    weight: np.ndarray,
    n_classes: int,
    k: int,
) -> FrameVotes:
    """The votes of one frame's voters.

    Args:
        index: the frame.
        keys: ``(V,) int64`` voxel of each voter.
        sem: ``(V,) int64`` each voter's class (its one-hot vote without probabilities).
        probs: ``(V, C) uint8`` their quantised probabilities, or None.
        weight: ``(V,) int64`` range × confidence weight (1..255²).
        n_classes: C.
        k: classes kept per voxel.
    """
    uniq, inv = np.unique(keys, return_inverse=True)
    return grouped_votes(index, uniq, inv.reshape(-1), sem, probs, weight, n_classes, k)


def grouped_votes(
    index: int,
    uniq: np.ndarray,
    inv: np.ndarray,
    sem: np.ndarray,
    probs: np.ndarray | None,
    weight: np.ndarray,
    n_classes: int,
    k: int,
) -> FrameVotes:
    """:func:`frame_votes` of voters already grouped by voxel: ``uniq`` ``(U,) int64`` their sorted
    voxel keys and ``inv`` ``(V,) int64`` each voter's position in ``uniq``."""
    sums = group_votes(inv, uniq.size, sem, probs, weight, n_classes)
    cls, val = top_k(sums, k)
    return FrameVotes(index, uniq, cls, val)


class SortedKeys:
    """The voxel keys of some points of a frame, sorted once, from which the ``np.unique(keys[rows],
    return_inverse=True)`` of any subset of them follows in linear time (the same arrays).

    Args:
        keys: ``(P,) int64``.
    """

    def __init__(self, keys: np.ndarray) -> None:
        self.n = keys.size
        self.order = np.argsort(keys)
        self.sorted = keys[self.order]

    def groups(self, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(uniq (U,) int64, inverse (M,) int64)`` of ``keys[mask]`` (``mask`` ``(P,) bool``), as
        ``np.unique(keys[mask], return_inverse=True)`` returns them."""
        sel = mask[self.order]
        keys = self.sorted[sel]
        if keys.size == 0:
            return keys, np.zeros(0, np.int64)
        first = np.empty(keys.size, bool)
        first[0] = True
        np.not_equal(keys[1:], keys[:-1], out=first[1:])
        full = np.empty(self.n, np.int64)
        full[self.order[sel]] = np.cumsum(first) - 1
        return keys[first], full[mask]


@dataclass(frozen=True)
class Consensus:
    """A window's verdict in some voxels (arrays ``(T,)``).

    Attributes:
        cls: winning class (ties to the lower id; -1 without votes).
        share: its share of the voxel's votes.
        frames: frames of the window that voted in the voxel.
        votes: the voxel's total votes, in full-weight points.
    """

    cls: np.ndarray
    share: np.ndarray
    frames: np.ndarray
    votes: np.ndarray

    def supported(self, min_frames: int, min_share: float, min_votes: float) -> np.ndarray:
        """``(T,) bool``: a consensus seen by enough frames, with enough votes and share."""
        return (
            (self.cls >= 0)
            & (self.frames >= min_frames)
            & (self.share >= min_share)
            & (self.votes >= min_votes)
        )


def window_consensus(target: np.ndarray, window: Iterable[FrameVotes], n_classes: int) -> Consensus:
    """The consensus of the frames ``window`` in the voxels ``target`` (``(T,) int64`` sorted unique)."""
    acc = np.zeros((target.size, n_classes), np.int64)
    frames = np.zeros(target.size, np.int64)
    for fv in window:
        accumulate(target, fv.keys, fv.cls, fv.val, acc, frames)
    total = acc.sum(axis=1)
    cls = np.argmax(acc, axis=1).astype(np.int64)
    best = acc[np.arange(target.size), cls]
    cls[total <= 0] = -1
    share = np.where(total > 0, best / np.maximum(total, 1), 0.0)
    return Consensus(cls, share, frames, total / FULL_VOTE)

"""Integer vote sums (numba loops): per group of points, per voxel's top classes, and over the
frames of a window. Integer arithmetic makes every sum exact, whatever the order of its terms."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def _sum_soft(group, q, w, out):  # pragma: no cover - compiled
    for p in range(group.shape[0]):
        g = group[p]
        wp = w[p]
        for c in range(q.shape[1]):
            out[g, c] += np.int64(q[p, c]) * wp


@numba.njit(cache=True)
def _sum_hard(group, sem, w, scale, out):  # pragma: no cover - compiled
    for p in range(group.shape[0]):
        out[group[p], sem[p]] += scale * w[p]


def group_votes(
    group: np.ndarray,
    n_groups: int,
    sem: np.ndarray,
    probs: np.ndarray | None,
    weight: np.ndarray,
    n_classes: int,
) -> np.ndarray:
    """Summed votes per group.

    Args:
        group: ``(N,) int64`` group of each point, 0..n_groups-1.
        n_groups: number of groups.
        sem: ``(N,) int64`` hard class of each point (used without ``probs``: one-hot × 255).
        probs: ``(N, C) uint8`` quantised probabilities, or None.
        weight: ``(N,) int64`` range × confidence weight of each point.
        n_classes: C.

    Returns:
        ``(n_groups, C) int64``.
    """
    out = np.zeros((n_groups, n_classes), np.int64)
    if group.size == 0:
        return out
    group = np.ascontiguousarray(group, np.int64)
    weight = np.ascontiguousarray(weight, np.int64)
    if probs is None:
        _sum_hard(group, np.ascontiguousarray(sem, np.int64), weight, np.int64(255), out)
    else:
        _sum_soft(group, np.ascontiguousarray(probs, np.uint8), weight, out)
    return out


@numba.njit(cache=True)
def _top_k(sums, k, cls, val):  # pragma: no cover - compiled
    n, c = sums.shape
    for i in range(n):
        for j in range(k):
            best = -1
            bv = np.int64(0)
            for a in range(c):
                v = sums[i, a]
                if v <= bv:
                    continue
                taken = False
                for jj in range(j):
                    if cls[i, jj] == a:
                        taken = True
                if not taken:
                    best, bv = a, v
            if best < 0:
                break
            cls[i, j] = best
            val[i, j] = bv


def top_k(sums: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` largest positive entries of each row of ``sums`` ``(U, C) int64`` (ties to the
    lower class): classes ``(U, k) int16`` (-1 where fewer) and values ``(U, k) int64`` (0 there)."""
    cls = np.full((sums.shape[0], k), -1, np.int16)
    val = np.zeros((sums.shape[0], k), np.int64)
    if sums.shape[0]:
        _top_k(np.ascontiguousarray(sums, np.int64), k, cls, val)
    return cls, val


@numba.njit(cache=True)
def _accumulate(target, keys, cls, val, acc, frames):  # pragma: no cover - compiled
    i = 0
    j = 0
    while i < target.shape[0] and j < keys.shape[0]:
        a = target[i]
        b = keys[j]
        if a < b:
            i += 1
        elif b < a:
            j += 1
        else:
            frames[i] += 1
            for k in range(cls.shape[1]):
                if cls[j, k] >= 0:
                    acc[i, cls[j, k]] += val[j, k]
            i += 1
            j += 1


def accumulate(
    target: np.ndarray,
    keys: np.ndarray,
    cls: np.ndarray,
    val: np.ndarray,
    acc: np.ndarray,
    frames: np.ndarray,
) -> None:
    """Add one frame's voxel votes to the voxels ``target`` (both key arrays sorted, unique).

    Args:
        target: ``(T,) int64`` voxel keys whose votes are wanted.
        keys: ``(U,) int64`` the frame's voted voxels; ``cls``, ``val``: their ``(U, k)`` top classes.
        acc: ``(T, C) int64`` running sums, updated in place.
        frames: ``(T,) int64`` frames that voted in each target voxel, updated in place.
    """
    if target.size and keys.size:
        _accumulate(target, keys, cls, val, acc, frames)


@numba.njit(cache=True)
def _group_box(group, x, y, lo, hi):  # pragma: no cover - compiled
    for p in range(group.shape[0]):
        g = group[p]
        # ties (+0.0 and -0.0) take the new value, as np.minimum.at / np.maximum.at do
        if x[p] <= lo[g, 0]:
            lo[g, 0] = x[p]
        if x[p] >= hi[g, 0]:
            hi[g, 0] = x[p]
        if y[p] <= lo[g, 1]:
            lo[g, 1] = y[p]
        if y[p] >= hi[g, 1]:
            hi[g, 1] = y[p]


def group_box(
    group: np.ndarray, n_groups: int, x: np.ndarray, y: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per group the smallest and largest ``x`` and ``y`` (``(n_groups, 2) float64`` each; inf and
    -inf for an empty group), as ``np.minimum.at`` / ``np.maximum.at`` give them, in one pass.

    Args:
        group: ``(N,) int64`` group of each point, 0..n_groups-1.
        x, y: ``(N,) float64`` finite coordinates.
    """
    lo = np.full((n_groups, 2), np.inf)
    hi = np.full((n_groups, 2), -np.inf)
    if group.size:
        _group_box(np.ascontiguousarray(group, np.int64), np.ascontiguousarray(x, np.float64),
                   np.ascontiguousarray(y, np.float64), lo, hi)  # fmt: skip
    return lo, hi

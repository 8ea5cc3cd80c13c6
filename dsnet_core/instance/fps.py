"""Deterministic farthest point sampling (FPS) of shifting seeds.

The result equals the naive algorithm exactly (start at index 0; each step picks the point
whose squared distance, in float64, to the already chosen set is largest; ties go to the lowest
index). Speed comes from a k-d partition of the points into leaves with bounding boxes: a new
sample can only lower the distances in leaves whose box is closer to it than the leaf's current
largest distance, so most leaves are skipped once the samples are dense.
"""

from __future__ import annotations

import numba
import numpy as np

from dsnet_core.instance.kdtree import leaves

_LEAF_SIZE = 128
_GROUP = 16  # leaves per group


def farthest_point_sampling(points: np.ndarray, n: int) -> np.ndarray:
    """Pick ``min(n, M)`` points by farthest point sampling, starting at index 0.

    Args:
        points: float32 (M, 3) positions in metres (any real dtype is accepted).
        n: number of samples wanted.

    Returns:
        int64 (min(n, M),) indices into ``points`` in selection order. When ``n >= M`` every
        point is returned in its original order (``arange(M)``), as the reference does.
    """
    return sample_with_nearest(points, n)[0]


def sample_with_nearest(points: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`farthest_point_sampling`, and for every point its nearest sample.

    The sampling keeps each point's squared distance to the chosen set; recording which sample
    lowered it last gives the nearest sample for free (float64 distances; among equidistant
    samples the earliest chosen).

    Returns:
        (samples int64 (S,), nearest int64 (M,): position in ``samples`` of each point's nearest).
    """
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (M, 3), got {points.shape}")
    m = pts.shape[0]
    if n >= m:
        return np.arange(m, dtype=np.int64), np.arange(m, dtype=np.int64)
    if n <= 0:
        return np.zeros(0, dtype=np.int64), np.full(m, -1, dtype=np.int64)
    if not np.isfinite(pts).all():
        raise ValueError("points hold NaN or inf")
    order, leaf_start = leaves(pts, _LEAF_SIZE)
    samples, near_sorted = _fps_leaves(pts[order], order.astype(np.int64), leaf_start, n)
    nearest = np.empty(m, dtype=np.int64)
    nearest[order] = near_sorted
    return samples, nearest


@numba.njit(cache=True)
def _box_lb(lo: np.ndarray, hi: np.ndarray, b: int, p: np.ndarray, cur: int) -> float:
    """Squared distance from point ``p[cur]`` to box ``b``: a lower bound for every point inside."""
    lb = 0.0
    for k in range(3):
        c = p[cur, k]
        if c < lo[b, k]:
            lb += (lo[b, k] - c) * (lo[b, k] - c)
        elif c > hi[b, k]:
            lb += (c - hi[b, k]) * (c - hi[b, k])
    return lb


@numba.njit(cache=True)
def _fps_leaves(p: np.ndarray, orig: np.ndarray, start: np.ndarray, n: int) -> np.ndarray:
    n_leaves = start.shape[0] - 1
    m = p.shape[0]
    lo = np.empty((n_leaves, 3))
    hi = np.empty((n_leaves, 3))
    for leaf in range(n_leaves):
        for k in range(3):
            lo[leaf, k] = np.inf
            hi[leaf, k] = -np.inf
        for i in range(start[leaf], start[leaf + 1]):
            for k in range(3):
                lo[leaf, k] = min(lo[leaf, k], p[i, k])
                hi[leaf, k] = max(hi[leaf, k], p[i, k])
    dist = np.full(m, np.inf)
    near = np.zeros(m, dtype=np.int64)  # sample (selection position) that set dist
    leaf_max = np.full(n_leaves, np.inf)
    leaf_arg = np.empty(n_leaves, dtype=np.int64)  # position (sorted order) of the leaf's farthest point
    for leaf in range(n_leaves):
        leaf_arg[leaf] = start[leaf]
        best = orig[start[leaf]]
        for i in range(start[leaf], start[leaf + 1]):
            if orig[i] < best:
                best = orig[i]
                leaf_arg[leaf] = i
    out = np.empty(n, dtype=np.int64)
    # the first sample is original index 0
    cur = 0
    for i in range(m):
        if orig[i] == 0:
            cur = i
    # groups of consecutive (hence nearby) leaves: one box test can skip a whole group
    n_groups = (n_leaves + _GROUP - 1) // _GROUP
    glo = np.empty((n_groups, 3))
    ghi = np.empty((n_groups, 3))
    gmax = np.full(n_groups, np.inf)
    garg = np.empty(n_groups, dtype=np.int64)
    for g in range(n_groups):
        for k in range(3):
            glo[g, k] = np.inf
            ghi[g, k] = -np.inf
        garg[g] = leaf_arg[g * _GROUP]
        for leaf in range(g * _GROUP, min((g + 1) * _GROUP, n_leaves)):
            for k in range(3):
                glo[g, k] = min(glo[g, k], lo[leaf, k])
                ghi[g, k] = max(ghi[g, k], hi[leaf, k])
    for s in range(n):
        out[s] = orig[cur]
        cx, cy, cz = p[cur, 0], p[cur, 1], p[cur, 2]
        for g in range(n_groups):
            if _box_lb(glo, ghi, g, p, cur) * (1.0 - 1e-9) >= gmax[g]:
                continue
            for leaf in range(g * _GROUP, min((g + 1) * _GROUP, n_leaves)):
                # squared distance from the new sample to the leaf's box: a lower bound for its points
                if _box_lb(lo, hi, leaf, p, cur) * (1.0 - 1e-9) >= leaf_max[leaf]:
                    continue
                best_v = -1.0
                best_i = -1
                for i in range(start[leaf], start[leaf + 1]):
                    dx = p[i, 0] - cx
                    dy = p[i, 1] - cy
                    dz = p[i, 2] - cz
                    d = dx * dx + dy * dy + dz * dz
                    if d < dist[i]:
                        dist[i] = d
                        near[i] = s
                    v = dist[i]
                    if v > best_v or (v == best_v and orig[i] < orig[best_i]):
                        best_v = v
                        best_i = i
                leaf_max[leaf] = best_v
                leaf_arg[leaf] = best_i
            best_v = -1.0
            best_i = -1
            for leaf in range(g * _GROUP, min((g + 1) * _GROUP, n_leaves)):
                v = leaf_max[leaf]
                i = leaf_arg[leaf]
                if v > best_v or (v == best_v and orig[i] < orig[best_i]):
                    best_v = v
                    best_i = i
            gmax[g] = best_v
            garg[g] = best_i
        best_v = -1.0
        cur = -1
        for g in range(n_groups):
            v = gmax[g]
            i = garg[g]
            if v > best_v or (v == best_v and orig[i] < orig[cur]):
                best_v = v
                cur = i
    return out, near

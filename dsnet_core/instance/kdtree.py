"""Median-split k-d trees over 3D points (numba), shared by FPS and the radius sums.

The split of a node puts the lower half of its points along the widest axis of their bounding box
in the first child: a quickselect (expected linear time) on the index array, not a sort.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def _select(order, pts, axis, lo, hi, k):
    """Reorder ``order[lo:hi]`` so that ``order[k]`` holds the point of rank ``k - lo`` along
    ``axis``, points before it no larger and points after it no smaller (Hoare quickselect)."""
    while hi - lo > 1:
        mid = (lo + hi) // 2
        a, b, c = pts[order[lo], axis], pts[order[mid], axis], pts[order[hi - 1], axis]
        pivot = max(min(a, b), min(max(a, b), c))  # median of three
        i, j = lo, hi - 1
        while i <= j:
            while pts[order[i], axis] < pivot:
                i += 1
            while pts[order[j], axis] > pivot:
                j -= 1
            if i <= j:
                order[i], order[j] = order[j], order[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j + 1
        elif k >= i:
            lo = i
        else:
            return


@numba.njit(cache=True)
def build_kdtree(pts, leaf_size):
    """Median-split k-d tree of ``pts`` (M, 3) float.

    Node ``i`` covers ``order[start[i]:end[i]]``; leaves have ``left = -1``; the two children of a
    node are created together, after it (right = left + 1), the lower half first. A node whose
    points all coincide stays a leaf whatever its size.

    Returns:
        (order int64 (M,), start, end, left int64 (nodes,)).
    """
    m = pts.shape[0]
    cap = 2 * (m // max(leaf_size // 2, 1) + 1) + 1
    order = np.arange(m)
    start = np.empty(cap, dtype=np.int64)
    end = np.empty(cap, dtype=np.int64)
    left = np.full(cap, -1, dtype=np.int64)
    start[0], end[0] = 0, m
    n_nodes = 1
    stack = np.empty(128, dtype=np.int64)
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        node = stack[top]
        lo_i, hi_i = start[node], end[node]
        if hi_i - lo_i <= leaf_size:
            continue
        best_axis, best_ext = 0, -1.0
        for d in range(3):
            mn, mx = np.inf, -np.inf
            for s in range(lo_i, hi_i):
                v = np.float64(pts[order[s], d])
                mn = min(mn, v)
                mx = max(mx, v)
            if mx - mn > best_ext:
                best_ext, best_axis = mx - mn, d
        if best_ext <= 0.0:
            continue  # identical points stay one leaf
        mid = lo_i + (hi_i - lo_i) // 2
        _select(order, pts, best_axis, lo_i, hi_i, mid)
        left[node] = n_nodes
        start[n_nodes], end[n_nodes] = lo_i, mid
        start[n_nodes + 1], end[n_nodes + 1] = mid, hi_i
        stack[top] = n_nodes + 1  # the lower half is popped first: leaves come out left to right
        stack[top + 1] = n_nodes
        top += 2
        n_nodes += 2
    return order, start[:n_nodes].copy(), end[:n_nodes].copy(), left[:n_nodes].copy()


def leaves(pts: np.ndarray, leaf_size: int) -> tuple[np.ndarray, np.ndarray]:
    """Permutation grouping ``pts`` into k-d leaves of at most ``leaf_size`` points (coincident
    points may share a larger leaf).

    Returns:
        (order int64 (M,), leaf_start int64 (L + 1,)): leaf ``l`` holds ``order[start[l]:start[l+1]]``.
    """
    order, start, _, left = build_kdtree(pts, leaf_size)
    firsts = np.sort(start[left < 0])
    return order, np.append(firsts, pts.shape[0]).astype(np.int64)

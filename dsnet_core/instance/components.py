"""Connected components of the fixed-radius graph (BFS clustering) without listing the edges.

Points closer than ``radius`` (boundary included) are linked; the components are the clusters.
A grid of edge ``radius/√3`` makes every cell a clique, so cells are united whole; two cells of
the 5×5×5 stencil are united as soon as one linking pair is found between them. Dense regressed
centres (millions of edges) therefore cost about one check per pair of occupied cells.
"""

from __future__ import annotations

import numba
import numpy as np


def radius_components(x: np.ndarray, radius: float) -> np.ndarray:
    """Component label of every point of the radius graph.

    Args:
        x: (N, 3) float32/float64 positions in metres.
        radius: link distance in metres.

    Returns:
        int64 (N,) labels 0..C−1, numbered by first appearance.
    """
    n = x.shape[0]
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    if not np.isfinite(x).all():
        raise ValueError("positions hold NaN or inf")
    xf = np.ascontiguousarray(x, dtype=np.float64)
    h = radius / np.sqrt(3.0) * (1.0 - 1e-9)
    cells = np.floor((xf - xf.min(axis=0)) / h).astype(np.int64) + 2
    dims = cells.max(axis=0) + 3
    if float(np.prod(dims.astype(np.float64))) >= 2.0**62:
        raise ValueError(f"positions span too large a box for radius {radius} m")
    keys = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
    ukeys, cell_of = np.unique(keys, return_inverse=True)
    order = np.argsort(cell_of, kind="stable")
    starts = np.searchsorted(cell_of[order], np.arange(ukeys.size + 1))
    root = _unite_cells(xf[order], ukeys, starts, radius * radius, dims)
    _, labels = np.unique(root[cell_of], return_inverse=True)
    # renumber by first appearance for a stable, input-ordered labelling
    _, first = np.unique(labels, return_index=True)
    rank = np.empty_like(first)
    rank[np.argsort(first)] = np.arange(first.size)
    return rank[labels].astype(np.int64)


@numba.njit(cache=True)
def _find(parent, i):
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@numba.njit(cache=True)
def _unite_cells(p, ukeys, starts, r2, dims):
    n_cells = ukeys.shape[0]
    parent = np.arange(n_cells)
    sx = dims[1] * dims[2]
    sy = dims[2]
    for c in range(n_cells):
        for ox in range(-2, 3):
            for oy in range(-2, 3):
                for oz in range(-2, 3):
                    off = ox * sx + oy * sy + oz
                    if off <= 0:
                        continue  # each unordered cell pair once
                    key = ukeys[c] + off
                    pos = np.searchsorted(ukeys, key)
                    if pos >= n_cells or ukeys[pos] != key:
                        continue
                    a, b = _find(parent, c), _find(parent, pos)
                    if a == b:
                        continue
                    linked = False
                    for i in range(starts[c], starts[c + 1]):
                        for j in range(starts[pos], starts[pos + 1]):
                            dx = p[i, 0] - p[j, 0]
                            dy = p[i, 1] - p[j, 1]
                            dz = p[i, 2] - p[j, 2]
                            if dx * dx + dy * dy + dz * dz <= r2:
                                linked = True
                                break
                        if linked:
                            break
                    if linked:
                        parent[max(a, b)] = min(a, b)
    root = np.empty(n_cells, dtype=np.int64)
    for c in range(n_cells):
        root[c] = _find(parent, c)
    return root


def dbscan(x: np.ndarray, eps: float, min_samples: int) -> np.ndarray:
    """DBSCAN without neighbour lists: core points have ≥ ``min_samples`` points (themselves
    included) within ``eps``; clusters are the radius components of the core points; a border
    point joins the cluster of its nearest core point within ``eps`` (scikit-learn gives a border
    point reachable from two clusters to the one it expands first); the rest is noise.

    Args:
        x: (N, 3) positions in metres.
        eps: neighbourhood radius in metres (boundary included).
        min_samples: neighbourhood size that makes a core point.

    Returns:
        int64 (N,) labels 0..C−1 by first appearance of their core points, −1 for noise.
    """
    from scipy.spatial import cKDTree

    from dsnet_core.instance.radius import radius_sums

    n = x.shape[0]
    labels = np.full(n, -1, dtype=np.int64)
    if n == 0:
        return labels
    xf = np.ascontiguousarray(x, dtype=np.float64)
    counts = radius_sums(xf, xf, np.array([eps]), np.ones((1, n, 1)))[0, :, 0]
    core = counts >= min_samples
    if not core.any():
        return labels
    labels[core] = radius_components(xf[core], eps)
    border = np.flatnonzero(~core)
    if border.size:
        dist, nn = cKDTree(xf[core]).query(xf[border], k=1, distance_upper_bound=eps * (1 + 1e-9))
        ok = np.isfinite(dist)
        labels[border[ok]] = labels[core][nn[ok]]
    return labels

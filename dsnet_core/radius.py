"""Fixed-radius neighbour sums on a uniform cell grid (CPU, numba).

``radius_sums(queries, points, radii, values)[j, a] = Σ_b values[j, b]`` over the points ``b``
with ``‖queries[a] − points[b]‖² ≤ radii[j]²``. Squared distances are exact differences,
``dx·dx + dy·dy + dz·dz`` in the dtype of the inputs (the same expression as the dense kernel,
so both draw the same boundaries); sums accumulate in float64. No pair list is materialised:
each query visits the 27 grid cells (edge = largest radius) around it.
"""

from __future__ import annotations

import numba
import numpy as np

_MAX_CELL_KEY = 2**62


def radius_sums(queries: np.ndarray, points: np.ndarray, radii: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Sum ``values`` over the points within each radius of each query.

    Args:
        queries: (Q, 3) float32 or float64 positions in metres.
        points: (P, 3) positions, same dtype as ``queries``.
        radii: (K,) radii in metres, ascending.
        values: (K, P, C) float64; ``values[j]`` is summed for radius ``radii[j]``.

    Returns:
        float64 (K, Q, C) sums.
    """
    if queries.dtype != points.dtype:
        raise ValueError(f"queries ({queries.dtype}) and points ({points.dtype}) must share a dtype")
    radii = np.asarray(radii, dtype=np.float64)
    if radii.ndim != 1 or radii.size == 0 or np.any(np.diff(radii) < 0) or radii[0] <= 0:
        raise ValueError(f"radii must be positive and ascending, got {radii}")
    k, n_p, c = values.shape
    if k != radii.size or n_p != points.shape[0]:
        raise ValueError(f"values {values.shape} do not match radii {radii.shape} and points {points.shape}")
    out = np.zeros((k, queries.shape[0], c))
    if queries.shape[0] == 0 or n_p == 0:
        return out
    if not (np.isfinite(queries).all() and np.isfinite(points).all()):
        raise ValueError("positions hold NaN or inf")
    # a hair wider than the largest radius so that float32 rounding of a distance that passes the
    # test can never put the pair two cells apart
    cell = float(radii[-1]) * (1.0 + 1e-5)
    lo = np.minimum(queries.min(axis=0), points.min(axis=0)).astype(np.float64)
    hi = np.maximum(queries.max(axis=0), points.max(axis=0)).astype(np.float64)
    dims = (np.floor((hi - lo) / cell).astype(np.int64) + 3).astype(np.int64)
    if float(dims[0]) * float(dims[1]) * float(dims[2]) >= _MAX_CELL_KEY:
        raise ValueError(f"positions span too large a box ({hi - lo} m) for radius {cell} m")
    r2 = (radii * radii).astype(queries.dtype)
    _radius_sums(
        np.ascontiguousarray(queries),
        np.ascontiguousarray(points),
        r2,
        np.ascontiguousarray(values, dtype=np.float64),
        lo,
        cell,
        dims,
        out,
    )
    return out


@numba.njit(cache=True)
def _cell_keys(x: np.ndarray, lo: np.ndarray, cell: float, dims: np.ndarray) -> np.ndarray:
    keys = np.empty(x.shape[0], dtype=np.int64)
    for i in range(x.shape[0]):
        ix = np.int64(np.floor((x[i, 0] - lo[0]) / cell)) + 1
        iy = np.int64(np.floor((x[i, 1] - lo[1]) / cell)) + 1
        iz = np.int64(np.floor((x[i, 2] - lo[2]) / cell)) + 1
        keys[i] = (ix * dims[1] + iy) * dims[2] + iz
    return keys


@numba.njit(cache=True)
def _radius_sums(q, p, r2, values, lo, cell, dims, out):
    k = r2.shape[0]
    c = values.shape[2]
    pkeys = _cell_keys(p, lo, cell, dims)
    order = np.argsort(pkeys, kind="mergesort")
    skeys = pkeys[order]
    ps = p[order]
    # unique occupied cells and their ranges in the sorted order
    n_cells = 1
    for i in range(1, skeys.shape[0]):
        if skeys[i] != skeys[i - 1]:
            n_cells += 1
    ukeys = np.empty(n_cells, dtype=np.int64)
    ustart = np.empty(n_cells + 1, dtype=np.int64)
    ukeys[0] = skeys[0]
    ustart[0] = 0
    u = 0
    for i in range(1, skeys.shape[0]):
        if skeys[i] != skeys[i - 1]:
            u += 1
            ukeys[u] = skeys[i]
            ustart[u] = i
    ustart[n_cells] = skeys.shape[0]
    qkeys = _cell_keys(q, lo, cell, dims)
    stride_x = dims[1] * dims[2]
    stride_y = dims[2]
    for a in range(q.shape[0]):
        qx, qy, qz = q[a, 0], q[a, 1], q[a, 2]
        for ox in range(-1, 2):
            for oy in range(-1, 2):
                for oz in range(-1, 2):
                    key = qkeys[a] + ox * stride_x + oy * stride_y + oz
                    pos = np.searchsorted(ukeys, key)
                    if pos >= n_cells or ukeys[pos] != key:
                        continue
                    for s in range(ustart[pos], ustart[pos + 1]):
                        dx = ps[s, 0] - qx
                        dy = ps[s, 1] - qy
                        dz = ps[s, 2] - qz
                        d2 = dx * dx + dy * dy + dz * dz
                        if d2 > r2[k - 1]:
                            continue
                        b = order[s]
                        j = k - 1
                        while j >= 0 and d2 <= r2[j]:
                            for ch in range(c):
                                out[j, a, ch] += values[j, b, ch]
                            j -= 1
    return out

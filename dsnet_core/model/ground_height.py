"""Height above the local ground: a robust per-cloud ground fit for the ``height`` input channel.

The fit (all in float64 numpy, deterministic: order statistics, medians and bilinear weights):

1. Square cells of :data:`CELL` metres over ±:data:`HALF_EXTENT` metres around the sensor (points
   beyond fall into the border cells).
2. Each cell's ground candidate is a low order statistic of its points' z: the point at rank
   ``floor(PERCENTILE · (n − 1))`` of the cell's n points sorted by z (a real point's z: no
   interpolation, robust to a few returns below the ground).
3. A :data:`FILTER` × :data:`FILTER` median filter over the candidates (empty cells ignored)
   replaces cells whose lowest returns are an object's (a car roof, a canopy) by their
   neighbourhood's ground.
4. Empty cells (occluded, beyond the returns) take the median of their filled 3 × 3 neighbours,
   :data:`FILL_STEPS` times; cells still empty (far from every return) take the median ground.
5. Each point's ground is the bilinear interpolation of the cell-centre grounds at its x, y; its
   height is ``z − ground``, clipped to [:data:`MIN_HEIGHT`, :data:`MAX_HEIGHT`].

Accuracy: exact on flat ground; on a slope s the low order statistic of a cell lies about
``0.45 · s · CELL`` below the cell's mean (≈ 2 cm at 2 %), and the last cells at the edge of the
returns extrapolate flat (a few cm on a slope).

The refine stage's ground prior (Patchwork++, an optional extra) labels points ground or not but
gives no surface to measure a height from, and is not part of the base install; this fit is.
"""

from __future__ import annotations

import warnings

import numpy as np

CELL = 2.0
"""Cell side, metres."""
HALF_EXTENT = 100.0
"""The grid covers [-HALF_EXTENT, HALF_EXTENT]² metres around the cloud's origin."""
PERCENTILE = 0.05
"""The order statistic of a cell's z taken as its ground candidate."""
FILTER = 5
"""Side of the median filter over the candidates, cells."""
FILL_STEPS = 4
"""Hole-filling passes (each reaches one cell further); a point's interpolation reads only the four
cells around it, filled in the first pass."""
MIN_HEIGHT, MAX_HEIGHT = -5.0, 10.0
"""The channel's clip range, metres."""


def _window_median(grid: np.ndarray, size: int) -> np.ndarray:
    """NaN-ignoring median over each cell's ``size × size`` neighbourhood (NaN where it is empty)."""
    r = size // 2
    n0, n1 = grid.shape
    pad = np.full((n0 + 2 * r, n1 + 2 * r), np.nan)
    pad[r : r + n0, r : r + n1] = grid
    stack = np.stack([pad[i : i + n0, j : j + n1] for i in range(size) for j in range(size)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN neighbourhoods stay NaN
        return np.nanmedian(stack, axis=0)


def ground_grid(xyz: np.ndarray) -> np.ndarray:
    """The fitted ground height of every cell centre.

    Args:
        xyz: float ``(N, 3)`` metres, N ≥ 1.

    Returns:
        float64 ``(n, n)`` ground z per cell (``n = 2 · HALF_EXTENT / CELL``); cell ``(i, j)`` is
        centred on ``(-HALF_EXTENT + (i + 0.5) · CELL, -HALF_EXTENT + (j + 0.5) · CELL)``.
    """
    n = round(2 * HALF_EXTENT / CELL)
    p = np.asarray(xyz, np.float64)
    ix = np.clip(np.floor((p[:, 0] + HALF_EXTENT) / CELL), 0, n - 1).astype(np.int64)
    iy = np.clip(np.floor((p[:, 1] + HALF_EXTENT) / CELL), 0, n - 1).astype(np.int64)
    cell = ix * n + iy
    order = np.lexsort((p[:, 2], cell))
    counts = np.bincount(cell, minlength=n * n)
    start = np.cumsum(counts) - counts
    filled = np.flatnonzero(counts)
    pick = start[filled] + np.floor(PERCENTILE * (counts[filled] - 1)).astype(np.int64)
    cand = np.full(n * n, np.nan)
    cand[filled] = p[order[pick], 2]
    grid = _window_median(cand.reshape(n, n), FILTER)
    grid[np.isnan(cand.reshape(n, n))] = np.nan  # the filter smooths filled cells; holes fill next
    for _ in range(FILL_STEPS):
        holes = np.isnan(grid)
        if not holes.any():
            break
        near = _window_median(grid, 3)
        grid[holes] = near[holes]
    rest = np.isnan(grid)  # far from every return: no point's interpolation reaches them
    if rest.any():
        grid[rest] = np.median(grid[~rest]) if (~rest).any() else 0.0
    return grid


def height_above_ground(xyz: np.ndarray) -> np.ndarray:
    """Per-point height above the fitted ground (module docstring).

    Args:
        xyz: float ``(N, 3)`` metres (a scan in its sensor frame, or an aligned volume).

    Returns:
        float64 ``(N,)`` metres, in [MIN_HEIGHT, MAX_HEIGHT]; empty for an empty cloud.
    """
    p = np.asarray(xyz, np.float64)
    if p.shape[0] == 0:
        return np.zeros(0)
    grid = ground_grid(p)
    n = grid.shape[0]
    # continuous cell coordinates relative to the cell centres, clamped to the grid
    u = np.clip((p[:, 0] + HALF_EXTENT) / CELL - 0.5, 0.0, n - 1.0)
    v = np.clip((p[:, 1] + HALF_EXTENT) / CELL - 0.5, 0.0, n - 1.0)
    i0 = np.minimum(np.floor(u).astype(np.int64), n - 2)
    j0 = np.minimum(np.floor(v).astype(np.int64), n - 2)
    fu, fv = u - i0, v - j0
    g = (
        grid[i0, j0] * (1 - fu) * (1 - fv)
        + grid[i0 + 1, j0] * fu * (1 - fv)
        + grid[i0, j0 + 1] * (1 - fu) * fv
        + grid[i0 + 1, j0 + 1] * fu * fv
    )
    return np.clip(p[:, 2] - g, MIN_HEIGHT, MAX_HEIGHT)

"""Which points of a scan lie outside a model's cylindrical grid (numpy only, no torch).

The network never drops a point: :func:`dsnet_core.model.cylinder.cylinder_features` clamps a
point's (ρ, φ, z) into ``[min_bound, max_bound]`` before taking its cell, so a point beyond the
grid is labelled from the edge cell it is clamped into (its raw ρ, φ, z features keep the true
values). Ingest counts such points per scan so a log from another sensor (a 70 m nuScenes
return, a roof mount higher than the grid's z range) shows how much of it the model sees only
at the grid's edge.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def outside_grid(points: np.ndarray, min_bound: Sequence[float], max_bound: Sequence[float]) -> np.ndarray:
    """``(N,) bool``: True where a point's (ρ, φ, z) lies outside ``[min_bound, max_bound]`` on any axis.

    Computed in float32 exactly as the model computes the polar coordinates (``ρ = sqrt(x² + y²)``,
    ``φ = atan2(y, x)``), so the points counted are the points the model clamps (with the grid's
    default ``ours`` convention; the ``reference`` convention compares in float64 and also clamps
    a point whose float32 φ is float32(π), which lands in the same edge cell either way).

    Args:
        points: ``(N, ≥3)`` x, y, z in metres (the sensor frame).
        min_bound: (ρ metres, φ radians, z metres) lower bounds of the grid.
        max_bound: the upper bounds.
    """
    xyz = np.asarray(points)[:, :3].astype(np.float32, copy=False)
    x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    lo = np.asarray(min_bound, dtype=np.float32)
    hi = np.asarray(max_bound, dtype=np.float32)
    rho = np.sqrt(x * x + y * y)
    phi = np.arctan2(y, x)
    out = (rho < lo[0]) | (rho > hi[0]) | (z < lo[2]) | (z > hi[2])
    return out | (phi < lo[1]) | (phi > hi[1])

"""BEV detection targets (CenterPoint-style, paper eq. 2) on the Cartesian grid.

For each object a 2D Gaussian is drawn into its class's heatmap, centred on the cell that holds
the projected modal centre (value exactly 1 there) with standard deviation
``σ = max(‖r_xy‖ / 3, min_sigma)`` where ``r_xy`` is the projected (MAX) modal extent — the
paper's "projected modal extent as the variance", scaled so the Gaussian falls to ~1 % at the
object's projected radius. Overlapping Gaussians of one class keep the maximum. The regression
targets live at the centre cells: the sub-cell offset of the centre (x, y), its height z, its
extents and its velocity.

Heatmap cells are indexed ``[class, ix, iy]`` with ``ix = ⌊(x + half_extent) / cell⌋``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dsnet_core.most.config import BevGrid
from dsnet_core.most.targets import ObjectTargets


@dataclass(frozen=True)
class BevTargets:
    """Targets of one scan.

    Attributes:
        heatmap: float32 ``(K, S, S)`` class-wise centre heatmaps, S = grid size.
        index: int64 ``(M,)`` flat centre cell ``ix * S + iy`` of each kept object.
        cls: int64 ``(M,)`` heatmap channel (position of the class in ``things``).
        offset: float32 ``(M, 2)`` centre minus its cell's centre, metres.
        height: float32 ``(M,)`` centre z, metres.
        extent: float32 ``(M, 3)`` half-extents, metres.
        velocity: float32 ``(M, 2)`` m/s; vel_mask: bool ``(M,)``.
        keys: int64 ``(M,)`` instance keys of the kept objects.
    """

    heatmap: np.ndarray
    index: np.ndarray
    cls: np.ndarray
    offset: np.ndarray
    height: np.ndarray
    extent: np.ndarray
    velocity: np.ndarray
    vel_mask: np.ndarray
    keys: np.ndarray


def cell_of(xy: np.ndarray, grid: BevGrid) -> np.ndarray:
    """int64 ``(M, 2)`` cells (ix, iy) of points ``(M, 2)`` (may lie outside ``0..S-1``)."""
    return np.floor((np.asarray(xy, np.float64) + grid.half_extent) / grid.cell).astype(np.int64)


def cell_centre(cells: np.ndarray, grid: BevGrid) -> np.ndarray:
    """float64 ``(M, 2)`` metric centres of cells ``(M, 2)``."""
    return (np.asarray(cells, np.float64) + 0.5) * grid.cell - grid.half_extent


def gaussian_sigma(extents: np.ndarray, grid: BevGrid, min_sigma: float = 0.8) -> np.ndarray:
    """float64 ``(M,)`` Gaussian standard deviations in cells from half-extents ``(M, 3)``.

    Args:
        min_sigma: floor in cells (small objects still get a blob CenterPoint-style).
    """
    return np.maximum(np.linalg.norm(np.asarray(extents)[:, :2], axis=1) / 3.0 / grid.cell, min_sigma)


def draw_gaussian(heat: np.ndarray, cx: int, cy: int, sigma: float) -> None:
    """Max-merge ``exp(−d²/2σ²)`` (d in cells from (cx, cy)) into ``heat`` ``(S, S)`` within 3σ."""
    rad = int(np.ceil(3 * sigma))
    s = heat.shape[0]
    x0, x1 = max(cx - rad, 0), min(cx + rad + 1, s)
    y0, y1 = max(cy - rad, 0), min(cy + rad + 1, s)
    if x0 >= x1 or y0 >= y1:
        return
    dx = np.arange(x0, x1) - cx
    dy = np.arange(y0, y1) - cy
    g = np.exp(-(dx[:, None] ** 2 + dy[None, :] ** 2) / (2 * sigma * sigma))
    np.maximum(heat[x0:x1, y0:y1], g, out=heat[x0:x1, y0:y1])


def bev_targets(
    objects: ObjectTargets, grid: BevGrid, things: tuple[int, ...], min_sigma: float = 0.8
) -> BevTargets:
    """Heatmaps and centre-cell regression targets of one scan's objects.

    Objects whose centre falls outside the grid, or whose class is not in ``things``, are left out.
    """
    s, k = grid.size, len(things)
    heat = np.zeros((k, s, s), np.float32)
    chan = {t: i for i, t in enumerate(things)}
    cells = cell_of(objects.centres[:, :2], grid) if len(objects) else np.zeros((0, 2), np.int64)
    inside = ((cells >= 0) & (cells < s)).all(1) & np.isin(objects.classes, list(things))
    sig = gaussian_sigma(objects.extents, grid, min_sigma) if len(objects) else np.zeros(0)
    keep = np.flatnonzero(inside)
    for m in keep.tolist():
        draw_gaussian(heat[chan[int(objects.classes[m])]], int(cells[m, 0]), int(cells[m, 1]), float(sig[m]))
    c = cells[keep]
    return BevTargets(
        heatmap=heat,
        index=(c[:, 0] * s + c[:, 1]).astype(np.int64),
        cls=np.array([chan[int(t)] for t in objects.classes[keep]], np.int64),
        offset=(objects.centres[keep, :2] - cell_centre(c, grid)).astype(np.float32),
        height=objects.centres[keep, 2].astype(np.float32),
        extent=objects.extents[keep].astype(np.float32),
        velocity=objects.velocity[keep].astype(np.float32),
        vel_mask=objects.has_velocity[keep].copy(),
        keys=objects.keys[keep].copy(),
    )

"""Cylindrical voxelisation (Cylinder3D): points → (ρ, φ, z) cells, the 9 per-point features and
the point↔voxel index maps. Grid size, bounds and cell convention are configuration; nothing is
densified.

Two cell conventions (:data:`CONVENTIONS`):

- ``"ours"`` (default): cell = (max − min) / n, so the n cells tile [min, max]; features in float32.
- ``"reference"``: the DS-Net / Cylinder3D data loaders' cell = (max − min) / (n − 1) (the last cell
  only receives points clamped onto ``max``); cells and centres computed in float64 from the
  float32 polar coordinates, the relative coordinates rounded to float32, as those loaders do.
  A network trained by the reference code sees every voxel at these positions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from dsnet_core.model.grid import CONVENTIONS, CylinderGrid

__all__ = ["CONVENTIONS", "CylinderGrid", "Voxelized", "cylinder_features"]


@dataclass
class Voxelized:
    """The voxelisation of a batch of point clouds.

    Attributes:
        features: float32 ``(N, 9)`` per point: (ρ, φ, z) relative to the cell centre, (ρ, φ, z),
            (x, y), remission.
        point_cells: int64 ``(N, 3)`` the cell of each point (clamped).
        coords: int64 ``(M, 4)`` unique voxels (batch, iρ, iφ, iz), sorted by key.
        point_to_voxel: int64 ``(N,)`` index into ``coords`` of each point.
        batch_size: number of clouds.
    """

    features: torch.Tensor
    point_cells: torch.Tensor
    coords: torch.Tensor
    point_to_voxel: torch.Tensor
    batch_size: int


def cylinder_features(points: torch.Tensor, grid: CylinderGrid) -> tuple[torch.Tensor, torch.Tensor]:
    """Cells and the 9 input features of one cloud (and any extra channels it carries).

    Args:
        points: float ``(N, 4 + E)`` x, y, z (metres), remission, then E extra input channels
            (:func:`dsnet_core.model.inputs.build_inputs`; E = 0 for a reader's cloud).
        grid: the grid.

    Returns:
        cells: int64 ``(N, 3)`` clamped cell indices; features: float32 ``(N, 9 + E)``, the extra
        channels last.
    """
    pts = points.to(torch.float32)
    x, y, z, r = pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 3]
    pol = torch.stack([torch.sqrt(x * x + y * y), torch.atan2(y, x), z], dim=1)
    if grid.convention == "reference":
        return _reference_cells(pts, grid)
    lo = torch.tensor(grid.min_bound, dtype=torch.float32, device=pts.device)
    hi = torch.tensor(grid.max_bound, dtype=torch.float32, device=pts.device)
    step = torch.tensor(grid.interval, dtype=torch.float32, device=pts.device)
    size = torch.tensor(grid.size, dtype=torch.int64, device=pts.device)
    cells = torch.floor((torch.minimum(torch.maximum(pol, lo), hi) - lo) / step).to(torch.int64)
    cells = torch.minimum(torch.clamp_min(cells, 0), size - 1)
    centre = (cells.to(torch.float32) + 0.5) * step + lo
    feats = torch.cat([pol - centre, pol, pts[:, :2], r[:, None], pts[:, 4:]], dim=1)
    return cells, feats


def _reference_cells(pts: torch.Tensor, grid: CylinderGrid) -> tuple[torch.Tensor, torch.Tensor]:
    """The reference loaders' arithmetic: float32 polar coordinates from numpy's expressions (torch's
    float32 ``sqrt(x*x + y*y)`` and ``atan2`` differ from numpy's by an ulp now and then), cells and
    centres in float64 with cell (max − min) / (n − 1), relative coordinates rounded to float32."""
    xyz = pts[:, :3].detach().cpu().numpy()
    x, y = xyz[:, 0], xyz[:, 1]
    pol_np = np.stack((np.sqrt(x**2 + y**2), np.arctan2(y, x), xyz[:, 2]), axis=1)
    pol = torch.from_numpy(pol_np).to(pts.device)
    f64 = dict(dtype=torch.float64, device=pts.device)
    lo, hi = torch.tensor(grid.min_bound, **f64), torch.tensor(grid.max_bound, **f64)
    step = torch.tensor(grid.interval, **f64)
    pol64 = pol.to(torch.float64)
    cells = torch.floor((torch.minimum(torch.maximum(pol64, lo), hi) - lo) / step).to(torch.int64)
    size = torch.tensor(grid.size, dtype=torch.int64, device=pts.device)
    cells = torch.minimum(torch.clamp_min(cells, 0), size - 1)
    centre = (cells.to(torch.float32) + 0.5).to(torch.float64) * step + lo
    rel = (pol64 - centre).to(torch.float32)
    return cells, torch.cat([rel, pol, pts[:, :2], pts[:, 3:]], dim=1)


def voxelize(clouds: list[torch.Tensor], grid: CylinderGrid) -> Voxelized:
    """Voxelise a batch of clouds onto the cylindrical grid.

    Args:
        clouds: list of float ``(N_b, 4)`` tensors (x, y, z, remission), all on one device.
        grid: the grid.

    Returns:
        The :class:`Voxelized` batch; points are concatenated in the order of ``clouds``.
    """
    cells_l, feats_l = [], []
    for pts in clouds:
        cells, feats = cylinder_features(pts, grid)
        cells_l.append(cells)
        feats_l.append(feats)
    return voxelize_cells(cells_l, feats_l, grid)


def voxelize_cells(cells_l: list[torch.Tensor], feats_l: list[torch.Tensor], grid: CylinderGrid) -> Voxelized:
    """Voxelise clouds whose cells and point features are already computed (batch index = list
    position; the equivariant lifting passes each rotated copy as its own batch entry).

    Args:
        cells_l: int64 ``(N_b, 3)`` cell indices per cloud; feats_l: float ``(N_b, F)`` features.
        grid: the grid (its size gives the voxel keys).
    """
    batch_l = [
        torch.full((c.shape[0],), b, dtype=torch.int64, device=c.device) for b, c in enumerate(cells_l)
    ]
    cells = torch.cat(cells_l)
    batch = torch.cat(batch_l)
    s0, s1, s2 = grid.size
    keys = ((batch * s0 + cells[:, 0]) * s1 + cells[:, 1]) * s2 + cells[:, 2]
    ukeys, inverse = torch.unique(keys, sorted=True, return_inverse=True)
    coords = torch.stack(
        [ukeys // (s0 * s1 * s2), (ukeys // (s1 * s2)) % s0, (ukeys // s2) % s1, ukeys % s2], dim=1
    )
    return Voxelized(
        features=torch.cat(feats_l),
        point_cells=cells,
        coords=coords,
        point_to_voxel=inverse,
        batch_size=len(cells_l),
    )

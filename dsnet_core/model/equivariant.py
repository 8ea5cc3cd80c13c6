"""Eq-4D-StOP's rotation equivariance on the cylindrical grid: lifting to the cyclic group C_n.

Yaw rotations are discretised to the n anchors ``R_j`` (angle ``2π·j/n``). The lifted feature map
is the backbone applied, with shared weights, to the n copies of the cloud rotated by ``R_j⁻¹``
(the regular representation, Eq-4D-StOP eq. 3). On this grid a rotation by ``2π/n`` moves every
point by exactly ``A/n`` azimuth cells when n divides the number A of azimuth cells and the cells
tile the full circle (cell size ``2π/A``), so each copy is built by an integer shift of the
azimuth index — the same voxels, in another place — rather than by re-binning rotated
coordinates: rotating the input by ``R_k`` then permutes the copies (copy j of the rotated cloud
is copy ``j − k`` of the original), whatever the backbone does at the azimuth seam.

Outputs:
- invariant targets (semantic logits) by invariant pooling over the copies (mean or max, eq. 7);
- the equivariant offset field by rotational coordinate selection: each copy scores its anchor
  (eq. 9), the best-scoring copy's offset, predicted in that copy's frame, is rotated back by
  its ``R_j``; the instance features handed on are the selected copy's (invariant).
Training: cross-entropy on the anchor nearest to the ground-truth offset's direction and the
offset loss in that anchor's frame (:func:`equivariant_offset_loss`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from dsnet_core.errors import ConfigError
from dsnet_core.model.cylinder import CylinderGrid, Voxelized, voxelize_cells

_TOL = 1e-9
OWN_CONVENTIONS = ("ours", "dsnet", "project", "default")  # CylinderGrid.convention "ours"
"""Names under which a grid config may record this project's cell convention, (max − min)/n."""


def check_equivariant_grid(grid: CylinderGrid, n: int) -> None:
    """Refuse a grid on which a yaw of ``2π/n`` is not an exact shift of the azimuth cells.

    Raises:
        ConfigError: naming what fails (the cell convention, the azimuth bounds, or n ∤ A).
    """
    if n == 1:
        return
    convention = getattr(grid, "convention", None)
    a = grid.size[1]
    lo, hi = grid.min_bound[1], grid.max_bound[1]
    if abs(grid.interval[1] * a - 2 * math.pi) > _TOL or (convention not in (None, *OWN_CONVENTIONS)):
        raise ConfigError(
            f"--equivariant {n} needs azimuth cells that tile the circle (cell size 2π/A, this "
            f"project's (max − min)/n convention); the grid's convention "
            f"{convention or 'unknown'} gives cells of {grid.interval[1]:.6g} rad for A = {a}, "
            "so a rotation is not a shift of the cells (an imported reference grid cannot be lifted)"
        )
    if abs(lo + math.pi) > _TOL or abs(hi - math.pi) > _TOL:
        raise ConfigError(f"--equivariant {n} needs the azimuth bounds [-π, π], the grid has [{lo}, {hi}]")
    if a % n:
        divisors = [d for d in range(2, a + 1) if a % d == 0][:12]
        raise ConfigError(
            f"--equivariant {n}: n must divide the grid's {a} azimuth cells for a yaw of 360°/n "
            f"to be an exact cell shift (possible n: {', '.join(map(str, divisors))}, ...)"
        )


@dataclass
class Lifted:
    """The n rotated copies of a batch, voxelised together.

    Attributes:
        vox: the voxelisation of ``n·B`` clouds, copy-major (batch entry ``j·B + b`` is copy j of
            cloud b), so copy 0's voxels come first; its points are ``n·N`` rows, copy-major.
        xyz: float32 ``(n·N, 3)`` each copy's point coordinates in its own frame (metres).
        n: the group order.
    """

    vox: Voxelized
    xyz: torch.Tensor
    n: int


def anchor_angles(n: int, device: torch.device | str = "cpu") -> torch.Tensor:
    """float64 ``(n,)`` anchor yaws ``2π·j/n`` (radians)."""
    return torch.arange(n, dtype=torch.float64, device=device) * (2 * math.pi / n)


def rotate_xy(v: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Rotate float ``(N, ≥2)`` rows by per-row (or scalar) ``angle`` radians about z (float64
    arithmetic, input dtype out); columns after the first two are kept."""
    a = angle.to(torch.float64)
    c, s = torch.cos(a), torch.sin(a)
    x, y = v[:, 0].to(torch.float64), v[:, 1].to(torch.float64)
    out = v.clone()
    out[:, 0] = (c * x - s * y).to(v.dtype)
    out[:, 1] = (s * x + c * y).to(v.dtype)
    return out


def lift(clouds: list[torch.Tensor], grid: CylinderGrid, n: int) -> Lifted:
    """Voxelise the n copies ``R_j⁻¹·cloud`` by shifting the azimuth index of copy 0's cells.

    The 9 point features of every copy are computed in float64 and rounded once: copy j keeps
    copy 0's offsets from the cell centre, ρ, z and remission; its azimuth is its shifted cell's
    centre plus that offset, and its x, y are the input's rotated by ``-2π·j/n``. A cloud given in
    float64 and rotated in float64 by ``2π·k/n`` therefore yields the same copies as the original,
    permuted, up to one float32 rounding. Call :func:`check_equivariant_grid` first.

    Args:
        clouds: float ``(N_b, 4 + E)`` per cloud (x, y, z metres, remission, E extra input
            channels, invariant under yaw and kept as they are), float32 or float64.
    """
    a = grid.size[1]
    f64 = torch.float64
    cells_l, feats_l, xyz_l = [], [], []
    base = [_polar64(c, grid) for c in clouds]
    for j in range(n):
        angle = torch.tensor(-2 * math.pi * j / n, dtype=f64)
        for cells, rel, pol, pts in base:
            cj = cells.clone()
            cj[:, 1] = torch.remainder(cells[:, 1] - j * (a // n), a)
            phi = (cj[:, 1].to(f64) + 0.5) * grid.interval[1] + grid.min_bound[1] + rel[:, 1]
            xy = rotate_xy(pts[:, :2], angle)
            feats = torch.cat([rel, pol[:, :1], phi[:, None], pol[:, 2:3], xy, pts[:, 3:]], dim=1)
            cells_l.append(cj)
            feats_l.append(feats.to(torch.float32))
            xyz_l.append(torch.cat([xy, pts[:, 2:3]], dim=1).to(torch.float32))
    return Lifted(voxelize_cells(cells_l, feats_l, grid), torch.cat(xyz_l), n)


def _polar64(cloud: torch.Tensor, grid: CylinderGrid):
    """:func:`~dsnet_core.model.cylinder.cylinder_features`' cells and polar parts in float64:
    cells int64 ``(N, 3)``, offsets from the cell centre ``(N, 3)``, (ρ, φ, z) ``(N, 3)`` and
    the points ``(N, 4 + E)``."""
    pts = cloud.to(torch.float64)
    x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
    pol = torch.stack([torch.sqrt(x * x + y * y), torch.atan2(y, x), z], dim=1)
    lo = torch.tensor(grid.min_bound, dtype=torch.float64, device=pts.device)
    hi = torch.tensor(grid.max_bound, dtype=torch.float64, device=pts.device)
    step = torch.tensor(grid.interval, dtype=torch.float64, device=pts.device)
    size = torch.tensor(grid.size, dtype=torch.int64, device=pts.device)
    cells = torch.floor((torch.minimum(torch.maximum(pol, lo), hi) - lo) / step).to(torch.int64)
    cells = torch.minimum(torch.clamp_min(cells, 0), size - 1)
    rel = pol - ((cells.to(torch.float64) + 0.5) * step + lo)
    return cells, rel, pol, pts


def pool(values: torch.Tensor, how: str) -> torch.Tensor:
    """Invariant pooling over the copies: ``(n, N, C)`` → ``(N, C)`` by "mean" or "max"."""
    return values.mean(dim=0) if how == "mean" else values.amax(dim=0)


def select_anchor(
    scores: torch.Tensor, offsets: torch.Tensor, features: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rotational coordinate selection.

    Args:
        scores: float ``(N, n)`` anchor scores; offsets: float ``(N, n, 3)`` each copy's offset in
            its own frame (metres); features: float ``(N, n, D)``.

    Returns:
        offsets float ``(N, 3)`` in the input frame, features ``(N, D)`` of the selected copy,
        and the selected anchor int64 ``(N,)``.
    """
    n = scores.shape[1]
    sel = scores.argmax(dim=1)
    rows = torch.arange(scores.shape[0], device=scores.device)
    local = offsets[rows, sel]
    angles = anchor_angles(n, scores.device)[sel]
    return rotate_xy(local, angles), features[rows, sel], sel


def nearest_anchor(vectors: torch.Tensor, n: int) -> torch.Tensor:
    """int64 ``(N,)`` the anchor nearest to each vector's yaw ``atan2(v_y, v_x)``."""
    theta = torch.atan2(vectors[:, 1].to(torch.float64), vectors[:, 0].to(torch.float64))
    return torch.remainder(torch.round(theta / (2 * math.pi / n)).to(torch.int64), n)


def equivariant_offset_loss(
    scores: torch.Tensor,
    offsets: torch.Tensor,
    xyz: torch.Tensor,
    centres: torch.Tensor,
    valid: torch.Tensor,
    score_weight: float = 1.0,
) -> torch.Tensor:
    """Eq-4D-StOP's loss for the offset field: cross-entropy (eq. 9) on the anchor nearest to the
    target offset's direction, plus DS-Net's L1 offset loss of that anchor's copy, in its frame.

    Args:
        scores: float ``(N, n)``; offsets: float ``(N, n, 3)`` per copy, in the copy's frame;
        xyz, centres: float ``(N, 3)`` input-frame points and instance centres; valid: bool ``(N,)``
        thing points; score_weight: weight of the cross-entropy term.
    """
    if not bool(valid.any()):
        return offsets.sum() * 0.0 + scores.sum() * 0.0
    n = scores.shape[1]
    target = (centres - xyz)[valid]
    anchor = nearest_anchor(target, n)
    local_target = rotate_xy(target, -anchor_angles(n, target.device)[anchor])
    rows = torch.arange(anchor.numel(), device=anchor.device)
    pred = offsets[valid][rows, anchor]
    l1 = (pred - local_target).abs().sum(dim=1).mean()
    return l1 + score_weight * F.cross_entropy(scores[valid], anchor)

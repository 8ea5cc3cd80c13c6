"""The modal detection branch: flatten a U-Net level along height, resample the polar map onto a
Cartesian BEV grid, 2D convolutions, centre heatmaps and regression maps.

Why Cartesian (``docs/most.md`` has the full argument): the backbone's cells are polar, so a
polar heatmap's cells grow with range (4° is 0.7 m at 10 m and 3.5 m at 50 m). CenterPoint's
recipe — isotropic Gaussians sized in metres, a fixed NMS window, centre offsets, extents and
velocities regressed in metres — assumes cells of one metric size; on polar cells every one of
them would become range-dependent and anisotropic. Resampling the flattened polar features once
(bilinear, wrapping in φ) onto a Cartesian grid costs one ``grid_sample`` and keeps the rest of
the branch exactly CenterPoint's.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from dsnet_core.model.cylinder import CylinderGrid
from dsnet_core.model.sparse_conv import SparseTensor
from dsnet_core.most.config import BevGrid

REGRESS = {"offset": slice(0, 2), "height": slice(2, 3), "extent": slice(3, 6), "velocity": slice(6, 8)}
N_REGRESS = 8


def level_shape(size: tuple[int, int, int], level: int) -> tuple[int, int, int]:
    """Spatial shape of U-Net level ``level`` (the strides of :class:`AsymmetricUNet`'s down blocks)."""
    strides = [(2, 2, 2), (2, 2, 2), (2, 2, 1), (2, 2, 1)][:level]
    shape = list(size)
    for st in strides:
        shape = [(n - 1) // s + 1 if s > 1 else n for n, s in zip(shape, st, strict=True)]
    return tuple(shape)


def level_stride(level: int) -> tuple[int, int]:
    """Cumulative (ρ, φ) stride of a level: coarse cell ``o`` is centred on fine cell ``o · stride``."""
    return (2**level, 2**level)


def flatten_height(x: SparseTensor) -> torch.Tensor:
    """Dense ``(B, C · Z, Nρ, Nφ)`` polar BEV map: the level's sparse features with height folded
    into channels (empty cells are 0)."""
    b, (nr, nphi, nz), c = x.batch_size, x.shape, x.features.shape[1]
    dense = x.features.new_zeros((b, nr, nphi, nz, c))
    co = x.coords
    dense[co[:, 0], co[:, 1], co[:, 2], co[:, 3]] = x.features
    return dense.permute(0, 4, 3, 1, 2).reshape(b, c * nz, nr, nphi)


def polar_sampling_grid(cyl: CylinderGrid, level: int, bev: BevGrid) -> torch.Tensor:
    """``grid_sample`` coordinates ``(1, S, S, 2)`` of every Cartesian cell centre in the polar map of
    ``level`` after one column of circular padding on each side of φ (``align_corners=True``)."""
    nr, nphi, _ = level_shape(cyl.size, level)
    sr, sphi = level_stride(level)
    centres = (torch.arange(bev.size, dtype=torch.float64) + 0.5) * bev.cell - bev.half_extent
    x, y = torch.meshgrid(centres, centres, indexing="ij")
    rho, phi = torch.sqrt(x * x + y * y), torch.atan2(y, x)
    (r0, p0, _), (dr, dp, _) = cyl.min_bound, cyl.interval
    u = ((rho - r0) / dr - 0.5) / sr
    v = ((phi - p0) / dp - 0.5) / sphi + 1.0
    gu = 2.0 * u / max(nr - 1, 1) - 1.0
    gv = 2.0 * v / (nphi + 1) - 1.0
    return torch.stack([gv, gu], dim=-1)[None].to(torch.float32)


def polar_to_cartesian(polar: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """Resample ``(B, C, Nρ, Nφ)`` onto the Cartesian grid: ``(B, C, S, S)`` indexed [ix, iy]."""
    padded = torch.cat([polar[..., -1:], polar, polar[..., :1]], dim=-1)
    g = grid.expand(polar.shape[0], -1, -1, -1)
    return F.grid_sample(padded, g, mode="bilinear", padding_mode="border", align_corners=True)


def sample_bev(features: torch.Tensor, xy: torch.Tensor, bev: BevGrid) -> torch.Tensor:
    """Bilinear BEV features ``(P, C)`` at metric positions ``xy`` ``(P, 2)`` of one map ``(C, S, S)``."""
    idx = (xy.to(features.dtype) + bev.half_extent) / bev.cell - 0.5
    g = 2.0 * idx / max(bev.size - 1, 1) - 1.0
    grid = torch.stack([g[:, 1], g[:, 0]], dim=-1)[None, None]
    out = F.grid_sample(features[None], grid, mode="bilinear", padding_mode="border", align_corners=True)
    return out[0, :, 0, :].t()


@dataclass
class BevOutput:
    """Outputs of the detection branch.

    Attributes:
        features: float ``(B, C, S, S)`` the BEV feature map ``F^bev``.
        heatmap: float ``(B, K, S, S)`` centre heatmap logits (sigmoid → confidence).
        regress: float ``(B, 8, S, S)``: offset x, y (m), height (m), extent x, y, z (m),
            velocity x, y (m/s); see :data:`REGRESS`.
    """

    features: torch.Tensor
    heatmap: torch.Tensor
    regress: torch.Tensor


def _conv_bn(cin: int, cout: int, k: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, k, padding=k // 2, bias=False), nn.BatchNorm2d(cout), nn.ReLU())


class BevHead(nn.Module):
    """1×1 reduction of the flattened polar map, resampling to Cartesian, two 3×3 conv-BN-ReLU
    layers (the paper's detection branch), then 1×1 heads for heatmaps and regression maps.

    Args:
        in_channels: C · Z of the flattened level. channels: width of ``F^bev``. num_things: K.
        sampling_grid: from :func:`polar_sampling_grid`.
    """

    def __init__(self, in_channels: int, channels: int, num_things: int, sampling_grid: torch.Tensor) -> None:
        super().__init__()
        self.reduce = _conv_bn(in_channels, channels, 1)
        self.convs = nn.Sequential(_conv_bn(channels, channels, 3), _conv_bn(channels, channels, 3))
        self.heatmap = nn.Conv2d(channels, num_things, 1)
        self.regress = nn.Conv2d(channels, N_REGRESS, 1)
        nn.init.constant_(self.heatmap.bias, -2.19)  # CenterPoint: initial confidence 0.1
        self.register_buffer("sampling_grid", sampling_grid, persistent=False)

    def forward(self, polar: torch.Tensor) -> BevOutput:
        feats = self.convs(polar_to_cartesian(self.reduce(polar), self.sampling_grid))
        return BevOutput(feats, self.heatmap(feats), self.regress(feats))

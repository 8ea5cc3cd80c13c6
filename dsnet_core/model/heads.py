"""Point MLP, semantic head and instance (offset) head of DS-Net."""

from __future__ import annotations

import torch
from torch import nn

from dsnet_core.model.backbone import ConvBNAct
from dsnet_core.model.sparse_conv import SparseTensor, SubMConv3d


class PointEncoder(nn.Module):
    """Per-point MLP (BN on input, Linear-BN-ReLU layers, final Linear), max-pooled per voxel,
    then Linear-ReLU compression.

    Args:
        in_dim: per-point features (9).
        widths: hidden widths then the pooled width, e.g. (64, 128, 256, 64).
        out_dim: compressed voxel width (16).
    """

    def __init__(self, in_dim: int, widths: tuple[int, ...], out_dim: int) -> None:
        super().__init__()
        layers: list[nn.Module] = [nn.BatchNorm1d(in_dim)]
        prev = in_dim
        for w in widths[:-1]:
            layers += [nn.Linear(prev, w), nn.BatchNorm1d(w), nn.ReLU()]
            prev = w
        layers.append(nn.Linear(prev, widths[-1]))
        self.mlp = nn.Sequential(*layers)
        self.compress = nn.Sequential(nn.Linear(widths[-1], out_dim), nn.ReLU())

    def forward(self, feats: torch.Tensor, point_to_voxel: torch.Tensor, n_voxels: int) -> torch.Tensor:
        """``(N, 9)`` point features → ``(M, out_dim)`` voxel features (max over each voxel's points)."""
        pt = self.mlp(feats)
        idx = point_to_voxel[:, None].expand(-1, pt.shape[1])
        pooled = pt.new_zeros((n_voxels, pt.shape[1])).scatter_reduce(0, idx, pt, "amax", include_self=False)
        return self.compress(pooled)


class SemanticHead(nn.Module):
    """One 3×3×3 submanifold conv (with bias) to per-voxel class logits."""

    def __init__(self, in_channels: int, num_classes: int) -> None:
        super().__init__()
        self.conv = SubMConv3d(in_channels, num_classes, 3, bias=True)

    def forward(self, x: SparseTensor) -> torch.Tensor:
        """``(M, num_classes)`` logits."""
        return self.conv(x).features


class InstanceHead(nn.Module):
    """Sparse convs C→C→C/2→D (3×3×3, BN, LeakyReLU), per point concat xyz, MLP (D+3)→D→3.

    With the paper's width: 128→128→64→32 and 35→32→3.
    """

    def __init__(self, in_channels: int, ins_dim: int = 32) -> None:
        super().__init__()
        c = in_channels
        self.convs = nn.ModuleList(
            [
                ConvBNAct(c, c, 3, bn_first=True),
                ConvBNAct(c, c // 2, 3, bn_first=True),
                ConvBNAct(c // 2, ins_dim, 3, bn_first=True),
            ]
        )
        self.offset = nn.Sequential(
            nn.Linear(ins_dim + 3, ins_dim), nn.BatchNorm1d(ins_dim), nn.ReLU(), nn.Linear(ins_dim, 3)
        )

    def forward(
        self, x: SparseTensor, point_to_voxel: torch.Tensor, xyz: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Returns offsets float ``(N, 3)`` (metres) and per-point features ``(N, ins_dim)``."""
        for conv in self.convs:
            x = conv(x)
        feat = x.features.index_select(0, point_to_voxel)
        return self.offset(torch.cat([feat, xyz], dim=1)), feat

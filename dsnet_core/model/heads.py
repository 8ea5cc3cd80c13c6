"""Point MLP, semantic head and instance (offset) head of DS-Net."""

from __future__ import annotations

import torch
from torch import nn

from dsnet_core.model.backbone import ConvBNAct
from dsnet_core.model.eval_path import bn_affine, needs_module_path
from dsnet_core.model.sparse_conv import SparseTensor, SubMConv3d

POINT_CHUNK = 2048  # points per chunk of the eval-mode MLPs (their activations stay in cache)


def fold_mlp(mlp: nn.Sequential) -> list[tuple[torch.Tensor, torch.Tensor, bool]]:
    """An eval-mode ``[BN], (Linear, [BN], [ReLU])…`` stack as ``(W^T, b, relu)`` per Linear, every
    batch norm folded into its Linear (a BN before the first Linear into its inputs' side).

    Returns:
        per Linear: weight float ``(in, out)`` (transposed, contiguous), bias ``(out,)``, and whether
        a ReLU follows.
    """
    mods, pre, out = list(mlp), None, []
    for i, m in enumerate(mods):
        if isinstance(m, nn.BatchNorm1d) and (i == 0 or not isinstance(mods[i - 1], nn.Linear)):
            pre = bn_affine(m)
        elif isinstance(m, nn.Linear):
            w, b = m.weight, m.bias if m.bias is not None else m.weight.new_zeros(m.out_features)
            if pre is not None:
                b, w, pre = b + w @ pre[1], w * pre[0][None, :], None
            nxt = mods[i + 1] if i + 1 < len(mods) else None
            if isinstance(nxt, nn.BatchNorm1d):
                scale, shift = bn_affine(nxt)
                w, b = w * scale[:, None], b * scale + shift
                nxt = mods[i + 2] if i + 2 < len(mods) else None
            out.append((w.t().contiguous(), b, isinstance(nxt, nn.ReLU)))
        elif not isinstance(m, (nn.BatchNorm1d, nn.ReLU)):
            raise TypeError(f"fold_mlp: unexpected layer {m}")
    return out


def run_folded(layers: list[tuple[torch.Tensor, torch.Tensor, bool]], x: torch.Tensor) -> torch.Tensor:
    """``(N, in)`` → ``(N, out)`` through :func:`fold_mlp`'s layers, ``POINT_CHUNK`` rows at a time
    (no autograd: for inference)."""
    out = x.new_empty((x.shape[0], layers[-1][0].shape[1]))
    for s in range(0, x.shape[0], POINT_CHUNK):
        h = x[s : s + POINT_CHUNK]
        for j, (w, b, relu) in enumerate(layers):
            h = (
                torch.addmm(b, h, w, out=out[s : s + POINT_CHUNK])
                if j == len(layers) - 1
                else torch.addmm(b, h, w)
            )
            if relu:
                h.relu_()
    return out


class PointEncoder(nn.Module):
    """Per-point MLP (BN on input, Linear-BN-ReLU layers, final Linear), max-pooled per voxel,
    then Linear-ReLU compression.

    In eval mode without autograd the MLP runs with its batch norms folded into the Linears, in
    cache-sized chunks of points (the same function, 3–4× faster on CPU; equal to float rounding).

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
        pt = self.mlp(feats) if needs_module_path(self, feats) else run_folded(fold_mlp(self.mlp), feats)
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
        if needs_module_path(self.offset, feat):
            return self.offset(torch.cat([feat, xyz], dim=1)), feat
        (w1, b1, _), (w2, b2, _) = fold_mlp(self.offset)  # w1: feature rows, then 3 xyz rows
        d = feat.shape[1]
        offsets = feat.new_empty((feat.shape[0], 3))
        for s in range(0, feat.shape[0], POINT_CHUNK):
            e = s + POINT_CHUNK
            h = torch.addmm(b1, feat[s:e], w1[:d]).addmm_(xyz[s:e], w1[d:]).relu_()
            torch.addmm(b2, h, w2, out=offsets[s:e])
        return offsets, feat

"""The Cylinder3D asymmetric residual sparse U-Net (base width ``w``; the paper uses 32).

Layout (channels): context block C_in→w; down blocks w→2w→4w→8w→16w (strides 2,2,2 / 2,2,2 /
2,2,1 / 2,2,1); up blocks 16w→16w→8w→4w→2w back onto the skip sites; the dimension-decomposition
refinement (three rank-1 kernels, sigmoid gates, multiplied with its input) concatenated with its
input gives 4w channels per active voxel.

``shared_rulebooks`` reproduces the networks trained by the reference code under spconv 1.x. There,
submanifold layers that share an ``indice_key`` reuse the rulebook (neighbour table) built by the
first of them, whatever their own kernel shape, and the kernel is read tap by tap in its flat
(row-major) order. Every layer of a block therefore acts with the first layer's kernel: the context
block with 1×3×3, each down block with 3×1×3, the three convolutions after each up-sampling with
1×3×3 (the 3×3×3 one uses only its first 9 taps, the kx = 0 plane), the refinement with 3×1×1.
The strided, inverse and 3×3×3 ``trans`` layers have keys of their own and are unaffected.
"""

from __future__ import annotations

import torch
from torch import nn

from dsnet_core.model.eval_path import bn_affine, needs_module_path
from dsnet_core.model.sparse_conv import SparseConv3d, SparseInverseConv3d, SparseTensor, SubMConv3d

K133, K313, K333 = (1, 3, 3), (3, 1, 3), (3, 3, 3)


class ConvBNAct(nn.Module):
    """Submanifold conv → activation → batch norm (the reference order), or conv → BN → act."""

    def __init__(self, cin: int, cout: int, kernel, act: nn.Module | None = None, bn_first: bool = False):
        super().__init__()
        self.conv = SubMConv3d(cin, cout, kernel)
        self.bn = nn.BatchNorm1d(cout)
        self.act = act if act is not None else nn.LeakyReLU()
        self.bn_first = bn_first

    def forward(self, x: SparseTensor) -> SparseTensor:
        f = self.conv(x).features
        if needs_module_path(self, f):
            f = self.act(self.bn(f)) if self.bn_first else self.bn(self.act(f))
            return x.with_features(f)
        # inference: the batch norm as one multiply-add in place on the fresh convolution output
        # (BatchNorm1d on few channels is 2-4x slower than this)
        scale, shift = bn_affine(self.bn)
        if self.bn_first:
            f = self._act_(torch.addcmul(shift, f, scale, out=f))
        else:
            f = self._act_(f)
            torch.addcmul(shift, f, scale, out=f)
        return x.with_features(f)

    def _act_(self, f: torch.Tensor) -> torch.Tensor:
        if isinstance(self.act, nn.LeakyReLU):
            return torch.nn.functional.leaky_relu_(f, self.act.negative_slope)
        return self.act(f)


class ResContextBlock(nn.Module):
    """Two asymmetric branches (1×3×3 then 3×1×3, and 3×1×3 then 1×3×3), summed."""

    def __init__(self, cin: int, cout: int, first=K133, second=K313) -> None:
        super().__init__()
        self.a1, self.a2 = ConvBNAct(cin, cout, first), ConvBNAct(cout, cout, second)
        self.b1, self.b2 = ConvBNAct(cin, cout, second), ConvBNAct(cout, cout, first)

    def forward(self, x: SparseTensor) -> SparseTensor:
        a = self.a2(self.a1(x)).features
        b = self.b2(self.b1(x))
        return b.with_features(b.features + a)


class DownBlock(nn.Module):
    """Asymmetric residual block then a strided 3×3×3 sparse conv; returns (coarse, skip)."""

    def __init__(
        self, cin: int, cout: int, stride: tuple[int, int, int], key: str, shared: bool = False
    ) -> None:
        super().__init__()
        self.res = ResContextBlock(cin, cout, first=K313, second=K313 if shared else K133)
        self.pool = SparseConv3d(cout, cout, 3, stride=stride, padding=1, indice_key=key)

    def forward(self, x: SparseTensor) -> tuple[SparseTensor, SparseTensor]:
        skip = self.res(x)
        return self.pool(skip), skip


class UpBlock(nn.Module):
    """3×3×3 conv, inverse conv onto the skip sites, add the skip, then 1×3×3, 3×1×3, 3×3×3."""

    def __init__(self, cin: int, cout: int, key: str, shared: bool = False) -> None:
        super().__init__()
        self.trans = ConvBNAct(cin, cout, K333)
        self.up = SparseInverseConv3d(cout, cout, 3, indice_key=key)
        kernels = (K133, K133, K133) if shared else (K133, K313, K333)
        self.c1, self.c2, self.c3 = (ConvBNAct(cout, cout, k) for k in kernels)

    def forward(self, x: SparseTensor, skip: SparseTensor) -> SparseTensor:
        up = self.up(self.trans(x))
        up = up.with_features(up.features + skip.features)
        return self.c3(self.c2(self.c1(up)))


class ReconBlock(nn.Module):
    """Dimension-decomposition refinement: σ(BN(3×1×1)) + σ(BN(1×3×1)) + σ(BN(1×1×3)), times the input."""

    def __init__(self, channels: int, shared: bool = False) -> None:
        super().__init__()
        kernels = ((3, 1, 1),) * 3 if shared else ((3, 1, 1), (1, 3, 1), (1, 1, 3))
        self.branches = nn.ModuleList(
            ConvBNAct(channels, channels, k, act=nn.Sigmoid(), bn_first=True) for k in kernels
        )

    def forward(self, x: SparseTensor) -> SparseTensor:
        gate = sum(b(x).features for b in self.branches)
        return x.with_features(gate * x.features)


class AsymmetricUNet(nn.Module):
    """The cylinder backbone: ``(M, C_in)`` voxel features → ``(M, 4w)`` on the same sites.

    Args:
        in_channels: voxel input channels (16 after the point MLP's compression).
        width: base width ``w``.
        shared_rulebooks: act like the reference under spconv 1.x (see the module docstring).
    """

    def __init__(self, in_channels: int = 16, width: int = 32, shared_rulebooks: bool = False) -> None:
        super().__init__()
        w, shared = width, shared_rulebooks
        self.out_channels = 4 * w
        self.context = ResContextBlock(in_channels, w, second=K133 if shared else K313)
        down = (
            (w, 2 * w, (2, 2, 2)),
            (2 * w, 4 * w, (2, 2, 2)),
            (4 * w, 8 * w, (2, 2, 1)),
            (8 * w, 16 * w, (2, 2, 1)),
        )
        self.down = nn.ModuleList(
            DownBlock(cin, cout, stride, f"down{i + 2}", shared) for i, (cin, cout, stride) in enumerate(down)
        )
        up = (
            (16 * w, 16 * w, "down5"),
            (16 * w, 8 * w, "down4"),
            (8 * w, 4 * w, "down3"),
            (4 * w, 2 * w, "down2"),
        )
        self.up = nn.ModuleList(UpBlock(cin, cout, key, shared) for cin, cout, key in up)
        self.recon = ReconBlock(2 * w, shared)

    def forward(self, x: SparseTensor) -> SparseTensor:
        x = self.context(x)
        skips = []
        for block in self.down:
            x, skip = block(x)
            skips.append(skip)
        for block, skip in zip(self.up, reversed(skips), strict=True):
            x = block(x, skip)
        refined = self.recon(x)
        return x.with_features(torch.cat([refined.features, x.features], dim=1))

"""Sparse 3D convolution in plain torch: gather → matmul → scatter per kernel tap.

Three layers, as in spconv: :class:`SubMConv3d` (outputs = inputs), :class:`SparseConv3d`
(strided, to a coarser grid) and :class:`SparseInverseConv3d` (back to the finer sites of a
named strided layer). Rulebooks are cached on the tensor's shared :class:`TableCache`, so every
layer at one resolution with one kernel shape reuses one table. The custom backward keeps only
the input features and the weights (no gathered copies). Weights are ``(K, C_in, C_out)`` with
taps in the row-major order of dense ``conv3d`` kernels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import torch
from torch import nn

from dsnet_core.model.sparse_index import Rulebook, strided_rulebook, submanifold_rulebook

Triple = tuple[int, int, int]


def _triple(v: int | tuple[int, ...]) -> Triple:
    return (v, v, v) if isinstance(v, int) else tuple(int(x) for x in v)


@dataclass
class TableCache:
    """Rulebooks shared by the layers of one forward pass.

    ``subm`` is keyed by (level, kernel); ``down`` by the strided layer's ``indice_key`` and holds
    (rulebook, fine tensor geometry) so that the matching inverse layer returns to the fine sites.
    """

    subm: dict = field(default_factory=dict)
    down: dict = field(default_factory=dict)


@dataclass
class SparseTensor:
    """Features on active sites of a sparse grid.

    Attributes:
        features: float ``(M, C)``.
        coords: int64 ``(M, 4)`` (batch, i, j, k), sorted by key (see ``sparse_index.coord_keys``).
        shape: spatial shape of the grid.
        batch_size: number of samples.
        level: identifies the resolution (the cumulative stride); tables are cached per level.
        cache: shared rulebook cache.
    """

    features: torch.Tensor
    coords: torch.Tensor
    shape: Triple
    batch_size: int
    level: Triple = (1, 1, 1)
    cache: TableCache = field(default_factory=TableCache)

    def with_features(self, features: torch.Tensor) -> SparseTensor:
        """The same sites with new features ``(M, C')``."""
        return replace(self, features=features)


class _SparseConvFn(torch.autograd.Function):
    """out[o] = Σ_k Σ_{(i, o) ∈ pairs_k} x[i] · W[k]; saves only ``x`` and ``W`` for backward."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, weight: torch.Tensor, book: Rulebook) -> torch.Tensor:
        ctx.save_for_backward(x, weight)
        ctx.book = book
        out = x.new_zeros((book.n_out, weight.shape[2]))
        for k, (i, o) in enumerate(book.pairs):
            if i.numel() == 0:
                continue
            if book.identity[k]:
                out.add_(x @ weight[k])
            else:
                out.index_add_(0, o, x.index_select(0, i) @ weight[k])
        return out

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):
        x, weight = ctx.saved_tensors
        book: Rulebook = ctx.book
        grad_out = grad_out.contiguous()
        gx = torch.zeros_like(x) if ctx.needs_input_grad[0] else None
        gw = torch.zeros_like(weight) if ctx.needs_input_grad[1] else None
        for k, (i, o) in enumerate(book.pairs):
            if i.numel() == 0:
                continue
            if book.identity[k]:
                g, xi = grad_out, x
            else:
                g, xi = grad_out.index_select(0, o), x.index_select(0, i)
            if gw is not None:
                gw[k] = xi.t() @ g
            if gx is not None:
                if book.identity[k]:
                    gx.add_(g @ weight[k].t())
                else:
                    gx.index_add_(0, i, g @ weight[k].t())
        return gx, gw, None


def sparse_conv(x: torch.Tensor, weight: torch.Tensor, book: Rulebook) -> torch.Tensor:
    """Apply a rulebook: features ``(n_in, C_in)``, weight ``(K, C_in, C_out)`` → ``(n_out, C_out)``."""
    return _SparseConvFn.apply(x, weight, book)


class _SparseConvBase(nn.Module):
    def __init__(self, in_channels: int, out_channels: int, kernel_size, bias: bool) -> None:
        super().__init__()
        self.in_channels, self.out_channels = in_channels, out_channels
        self.kernel_size = _triple(kernel_size)
        k = math.prod(self.kernel_size)
        self.weight = nn.Parameter(torch.empty(k, in_channels, out_channels))
        self.bias = nn.Parameter(torch.zeros(out_channels)) if bias else None
        bound = 1.0 / math.sqrt(in_channels * k)
        nn.init.uniform_(self.weight, -bound, bound)

    def _apply_book(self, x: torch.Tensor, book: Rulebook) -> torch.Tensor:
        out = sparse_conv(x, self.weight, book)
        return out + self.bias if self.bias is not None else out

    def extra_repr(self) -> str:
        return f"{self.in_channels}, {self.out_channels}, kernel_size={self.kernel_size}"


class SubMConv3d(_SparseConvBase):
    """Submanifold convolution: stride 1, padding ``k // 2``, outputs on the input sites."""

    def __init__(self, in_channels: int, out_channels: int, kernel_size=3, bias: bool = False) -> None:
        super().__init__(in_channels, out_channels, kernel_size, bias)
        if any(k % 2 == 0 for k in self.kernel_size):
            raise ValueError(f"submanifold kernels must be odd, got {self.kernel_size}")

    def forward(self, x: SparseTensor) -> SparseTensor:
        key = (x.level, self.kernel_size)
        book = x.cache.subm.get(key)
        if book is None:
            book = submanifold_rulebook(x.coords, x.shape, self.kernel_size)
            x.cache.subm[key] = book
        return x.with_features(self._apply_book(x.features, book))


class SparseConv3d(_SparseConvBase):
    """Strided sparse convolution to a coarser grid; registers its table under ``indice_key``."""

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        kernel_size=3,
        stride=2,
        padding=1,
        bias: bool = False,
        indice_key: str = "down",
    ) -> None:
        super().__init__(in_channels, out_channels, kernel_size, bias)
        self.stride, self.padding, self.indice_key = _triple(stride), _triple(padding), indice_key

    def forward(self, x: SparseTensor) -> SparseTensor:
        book, coords, shape = strided_rulebook(x.coords, x.shape, self.kernel_size, self.stride, self.padding)
        x.cache.down[self.indice_key] = (book, x.coords, x.shape, x.level)
        level = tuple(lv * s for lv, s in zip(x.level, self.stride, strict=True))
        return SparseTensor(self._apply_book(x.features, book), coords, shape, x.batch_size, level, x.cache)


class SparseInverseConv3d(_SparseConvBase):
    """Transposed convolution back onto the fine sites of the strided layer named ``indice_key``."""

    def __init__(
        self, in_channels: int, out_channels: int, kernel_size=3, bias: bool = False, indice_key: str = "down"
    ) -> None:
        super().__init__(in_channels, out_channels, kernel_size, bias)
        self.indice_key = indice_key

    def forward(self, x: SparseTensor) -> SparseTensor:
        if self.indice_key not in x.cache.down:
            raise KeyError(f"no strided layer '{self.indice_key}' ran before this inverse convolution")
        book, coords, shape, level = x.cache.down[self.indice_key]
        out = self._apply_book(x.features, book.transposed())
        return SparseTensor(out, coords, shape, x.batch_size, level, x.cache)

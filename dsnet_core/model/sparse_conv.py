"""Sparse 3D convolution in plain torch: gather → matmul → scatter per kernel tap.

Three layers, as in spconv: :class:`SubMConv3d` (outputs = inputs), :class:`SparseConv3d`
(strided, to a coarser grid) and :class:`SparseInverseConv3d` (back to the finer sites of a
named strided layer). Kernel maps are cached on the tensor's shared :class:`TableCache`: one
neighbour search per resolution serves every submanifold kernel there, and a strided layer's map
serves its inverse. The custom backward keeps only
the input features and the weights (no gathered copies). Weights are ``(K, C_in, C_out)`` with
taps in the row-major order of dense ``conv3d`` kernels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import torch
from torch import nn

from dsnet_core.model.sparse_index import NeighbourMap, Rulebook, strided_rulebook

Triple = tuple[int, int, int]


def _triple(v: int | tuple[int, ...]) -> Triple:
    return (v, v, v) if isinstance(v, int) else tuple(int(x) for x in v)


@dataclass
class TableCache:
    """Kernel maps shared by the layers of one forward pass (and reused by its backward).

    ``maps`` holds one :class:`NeighbourMap` per level (the 3×3×3 box, or larger if a layer asks),
    from which ``subm`` derives each (level, kernel) rulebook without another search; ``down`` is
    keyed by the strided layer's ``indice_key`` and holds (rulebook, fine tensor geometry) so that
    the matching inverse layer returns to the fine sites.
    """

    maps: dict = field(default_factory=dict)
    subm: dict = field(default_factory=dict)
    down: dict = field(default_factory=dict)

    def submanifold(self, x: SparseTensor, kernel: Triple) -> Rulebook:
        """The rulebook of a submanifold ``kernel`` on ``x``'s sites (built at most once)."""
        key = (x.level, kernel)
        book = self.subm.get(key)
        if book is None:
            need = tuple(max(1, k // 2) for k in kernel)
            nmap = self.maps.get(x.level)
            if nmap is None or any(r < n for r, n in zip(nmap.radius, need, strict=True)):
                if nmap is not None:
                    need = tuple(max(r, n) for r, n in zip(nmap.radius, need, strict=True))
                nmap = self.maps[x.level] = NeighbourMap.build(x.coords, x.shape, need, x.batch_size)
            book = self.subm[key] = nmap.rulebook(kernel)
        return book


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
    """out[o] = Σ_k Σ_{(i, o) ∈ pairs_k} x[i] · W[k]; saves only ``x`` and ``W`` for backward.

    One gather → GEMM → scatter-add per non-empty tap segment, bounds read from host ints (no
    device synchronisation); the submanifold centre tap is one dense GEMM that initialises the output.
    """

    @staticmethod
    def forward(ctx, x: torch.Tensor, weight: torch.Tensor, book: Rulebook) -> torch.Tensor:
        ctx.save_for_backward(x, weight)
        ctx.book = book
        if book.identity is not None:
            out = torch.mm(x, weight[book.identity])
        else:
            out = x.new_zeros((book.n_out, weight.shape[2]))
        ins, outs = book.in_idx, book.out_idx
        for tap, s, e in book.segments:
            out.index_add_(0, outs[s:e], torch.mm(x.index_select(0, ins[s:e]), weight[tap]))
        return out

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):
        x, weight = ctx.saved_tensors
        book: Rulebook = ctx.book
        g = grad_out.contiguous()
        need_x, need_w = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        gx = gw = None
        if need_w:
            gw = torch.zeros_like(weight)
            if book.identity is not None:
                torch.mm(x.t(), g, out=gw[book.identity])
        if need_x:
            gx = torch.mm(g, weight[book.identity].t()) if book.identity is not None else torch.zeros_like(x)
        ins, outs = book.in_idx, book.out_idx
        for tap, s, e in book.segments:
            i = ins[s:e]
            go = g.index_select(0, outs[s:e])
            if need_w:
                torch.mm(x.index_select(0, i).t(), go, out=gw[tap])
            if need_x:
                gx.index_add_(0, i, torch.mm(go, weight[tap].t()))
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
        return x.with_features(self._apply_book(x.features, x.cache.submanifold(x, self.kernel_size)))


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
        book, coords, shape = strided_rulebook(
            x.coords, x.shape, self.kernel_size, self.stride, self.padding, x.batch_size
        )
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

"""Kernel maps (rulebooks) of sparse convolution: which input site meets which output site
through which kernel tap.

A :class:`PairTable` holds one map's (input, output) pairs in two flat int32 tensors, one
contiguous segment per kernel offset ("column"). A :class:`Rulebook` is a view of a table for one
kernel: which columns it uses, with which weight taps, grouped so that equal-sized segments that
sit side by side run as one batched GEMM. Both directions of the gather–GEMM–reduce need a
compressed-row order of the pairs (by output for the forward, by input for the gradient of the
input); the table builds them once per set of columns (a counting sort, no sort) and caches
them, so every layer with that kernel, its inverse and the
backward reuse them.

Segment bounds are host ints read once when a map is built, so applying a rulebook never
synchronises with the device. Maps of CPU tensors are built by the numba loops of
:mod:`dsnet_core.model.sparse_maps_cpu` (the same tables, pair for pair, 2-3x faster); the torch
builders here serve CUDA tensors and grids too large for a dense index table.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
import torch

from dsnet_core.model import sparse_maps_cpu
from dsnet_core.model.sparse_index import (
    DENSE_TABLE_MAX_CELLS,
    DenseIndex,
    compact_keys,
    coord_keys,
    kernel_offsets,
    keys_to_coords,
    output_shape,
    scratch_table,
)

IDX = torch.int32  # pair and CSR indices (maps larger than 2^31 pairs are refused)
CPU_KERNELS = True  # build maps of CPU tensors with the numba loops of sparse_maps_cpu (tests turn it off)


def _numba(t: torch.Tensor) -> bool:
    return CPU_KERNELS and t.device.type == "cpu"


@dataclass
class PairTable:
    """The flat pairs of one kernel map.

    Attributes:
        in_idx, out_idx: int32 ``(P,)``; column ``c`` owns rows ``[starts[c], starts[c] + counts[c])``.
        starts, counts: host ints per column. Within a column every input and every output occurs
            at most once (a site meets a given offset once).
        n_in, n_out: numbers of input and output sites.
        mirror: per column, the column that holds the same pairs swapped in the same order (the
            offset ``-d`` of a submanifold map), or None.
    """

    in_idx: torch.Tensor
    out_idx: torch.Tensor
    starts: list[int]
    counts: list[int]
    n_in: int
    n_out: int
    mirror: list[int] | None = None
    _csr: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if self.in_idx.numel() >= 2**31:
            raise ValueError(f"kernel map with {self.in_idx.numel()} pairs exceeds int32 indices")

    def csr(self, side: str, cols: tuple[int, ...]) -> tuple[torch.Tensor, torch.Tensor]:
        """Rows of the pairs in ``cols`` grouped by their ``side`` ("in"/"out") site: (rows int32
        ``(Q,)``, offsets int32 ``(n_side,)``) as ``embedding_bag`` takes them (empty groups allowed).

        A counting sort that walks the segments in turn: a site occurs at most once per segment, so
        each segment's pairs take the next free slot of their site without conflicts (O(P), no sort).
        Cached per (side, cols): every layer with that kernel, its inverse and the backward share it.
        """
        key = (side, cols)
        got = self._csr.get(key)
        if got is not None:
            return got
        if side == "in" and self.mirror is not None:  # by input = the mirror columns by output
            rows, offsets = self.csr("out", tuple(sorted(self.mirror[c] for c in cols)))
            got = self._csr[key] = (self._partner().index_select(0, rows.long()), offsets)
            return got
        idx, n = (self.in_idx, self.n_in) if side == "in" else (self.out_idx, self.n_out)
        segs = [(self.starts[c], self.starts[c] + self.counts[c]) for c in cols if self.counts[c]]
        dev = idx.device
        fill = torch.zeros(n, dtype=torch.int64, device=dev)
        if not segs:
            got = self._csr[key] = (idx.new_zeros(0), fill.to(IDX))
            return got
        if _numba(idx):
            lo, hi = (np.array(v, dtype=np.int64) for v in zip(*segs, strict=True))
            rows, offsets = sparse_maps_cpu.csr_rows(idx.numpy(), lo, hi, n)
            got = self._csr[key] = (torch.from_numpy(rows), torch.from_numpy(offsets))
            return got
        sel = torch.cat([idx[s:e] for s, e in segs]).long()
        if n > 1:
            fill[1:] = torch.cumsum(torch.bincount(sel, minlength=n), 0)[:-1]
        offsets = fill.to(IDX)
        rows = torch.empty(sel.numel(), dtype=IDX, device=dev)
        pos = 0
        for s, e in segs:
            site = sel[pos : pos + e - s]
            pos += e - s
            slot = fill.index_select(0, site)
            rows.index_copy_(0, slot, torch.arange(s, e, dtype=IDX, device=dev))
            fill.index_copy_(0, site, slot + 1)
        got = self._csr[key] = (rows, offsets)
        return got

    def _partner(self) -> torch.Tensor:
        """int32 ``(P,)``: the row of the same pair, swapped, in the mirror column."""
        p = self._csr.get("partner")
        if p is None:
            dev = self.in_idx.device
            shift = torch.tensor(
                [self.starts[self.mirror[c]] - self.starts[c] for c in range(len(self.counts))]
            )
            order = sorted(range(len(self.counts)), key=lambda c: self.starts[c])
            sizes = torch.tensor([self.counts[c] for c in order])
            step = torch.repeat_interleave(shift[order], sizes).to(dev)
            p = self._csr["partner"] = (torch.arange(self.in_idx.numel(), device=dev) + step).to(IDX)
        return p


@dataclass
class Group:
    """Adjacent segments of equal size run as one (batched) GEMM.

    Attributes:
        start, end: rows ``[start, end)`` of the table; ``len(taps)`` segments of ``size`` rows.
        taps: weight taps of the segments, in row order; ``tap_index`` the same as a device tensor.
    """

    start: int
    end: int
    size: int
    taps: tuple[int, ...]
    tap_index: torch.Tensor


@dataclass
class Rulebook:
    """One convolution's view of a :class:`PairTable` (possibly transposed: inputs ↔ outputs).

    Attributes:
        table: the pairs.
        groups: the GEMM groups (non-empty segments only).
        cols: table columns this kernel uses.
        identity: weight tap that maps every site onto itself (submanifold centre), or None.
        transposed: True for the inverse convolution of the table's map.
    """

    table: PairTable
    groups: list[Group]
    cols: tuple[int, ...]
    identity: int | None
    transposed: bool = False

    @property
    def in_idx(self) -> torch.Tensor:
        return self.table.out_idx if self.transposed else self.table.in_idx

    @property
    def out_idx(self) -> torch.Tensor:
        return self.table.in_idx if self.transposed else self.table.out_idx

    @property
    def n_in(self) -> int:
        return self.table.n_out if self.transposed else self.table.n_in

    @property
    def n_out(self) -> int:
        return self.table.n_in if self.transposed else self.table.n_out

    @property
    def n_rows(self) -> int:
        """Rows of the table a workspace must hold (the groups index into them)."""
        return self.table.in_idx.numel()

    def csr(self, side: str) -> tuple[torch.Tensor, torch.Tensor]:
        """Compressed rows by this convolution's "out" or "in" sites (see :meth:`PairTable.csr`)."""
        flip = {"in": "out", "out": "in"}
        return self.table.csr(flip[side] if self.transposed else side, self.cols)

    def transpose(self) -> Rulebook:
        """The rulebook of the inverse convolution (inputs and outputs swapped, same weights' taps)."""
        return Rulebook(self.table, self.groups, self.cols, self.identity, not self.transposed)

    def pairs(self, n_taps: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Per weight tap ``(in_idx, out_idx)`` int64 (the identity tap as two aranges); for tests
        and reference implementations."""
        empty = self.in_idx.new_zeros(0, dtype=torch.int64)
        out = [(empty, empty)] * n_taps
        for g in self.groups:
            for j, tap in enumerate(g.taps):
                s = g.start + j * g.size
                out[tap] = (self.in_idx[s : s + g.size].long(), self.out_idx[s : s + g.size].long())
        if self.identity is not None:
            ar = torch.arange(self.n_in, device=self.in_idx.device)
            out[self.identity] = (ar, ar)
        return out


def _group(start: int, size: int, taps: tuple[int, ...], device) -> Group:
    return Group(start, start + size * len(taps), size, taps, torch.tensor(taps, device=device))


@dataclass
class NeighbourMap:
    """All submanifold pairs of one resolution for the box kernel of radius ``radius``.

    Built once per resolution and shared by every submanifold layer whose kernel fits inside the box
    (1×3×3, 3×1×3, 3×1×1, … all select columns of the 3×3×3 map). Half the offsets are looked up;
    offset ``-d`` reuses offset ``d``'s pairs swapped (if ``p + d = q`` then ``q - d = p``) and sits
    right after it, with the same size, so the two run as one batched GEMM. Column ``c`` is the
    box offset ``c`` (row-major) with the centre left out.
    """

    radius: tuple[int, int, int]
    table: PairTable

    @classmethod
    def build(cls, coords: torch.Tensor, shape, radius, batch_size: int) -> NeighbourMap:
        """The map of ``coords`` (int64 ``(M, 4)`` sorted by key) in a ``shape`` grid."""
        dev, m = coords.device, coords.shape[0]
        offs = kernel_offsets(tuple(2 * r + 1 for r in radius), dev) - torch.tensor(radius, device=dev)
        n_box = offs.shape[0]
        half = n_box // 2
        box = tuple(s + 2 * r for s, r in zip(shape, radius, strict=True))
        n_cells = max(batch_size, 1) * box[0] * box[1] * box[2]
        if _numba(coords) and m and half and n_cells <= DENSE_TABLE_MAX_CELLS:
            keys = coord_keys(coords + torch.tensor([0, *radius]), box).contiguous()
            steps = (offs[:half] * torch.tensor([box[1] * box[2], box[2], 1])).sum(1)
            table = scratch_table(n_cells, dev).numpy()
            in_np, out_np, counts_np = sparse_maps_cpu.neighbour_pairs(keys.numpy(), m, steps.numpy(), table)
            in_idx, out_idx, counts_half = (
                torch.from_numpy(in_np),
                torch.from_numpy(out_np),
                counts_np.tolist(),
            )
            starts_half = list(itertools.accumulate([0, *counts_half[:-1]]))[:half]
        else:
            in_idx, out_idx, starts_half, counts_half = cls._pairs_torch(
                coords, shape, radius, batch_size, offs
            )
        starts, counts = [0] * (n_box - 1), [0] * (n_box - 1)
        for u in range(half):
            mirror = n_box - 2 - u  # column of offset -d (box index n_box-1-u, centre dropped)
            starts[u], counts[u] = 2 * starts_half[u], counts_half[u]
            starts[mirror], counts[mirror] = 2 * starts_half[u] + counts_half[u], counts_half[u]
        mirror = [n_box - 2 - c for c in range(n_box - 1)]
        return cls(tuple(radius), PairTable(in_idx, out_idx, starts, counts, m, m, mirror))

    @staticmethod
    def _pairs_torch(coords, shape, radius, batch_size, offs):
        """(in_idx, out_idx, starts_half, counts_half) of the first half of ``offs`` and their
        mirrors, with whole-array torch operations (any device)."""
        m, half = coords.shape[0], offs.shape[0] // 2
        with DenseIndex(coords, shape, radius, batch_size) as index:
            nbr = index.neighbours(offs[:half]).reshape(-1)  # (half * M,)
        flat = torch.nonzero(nbr >= 0).reshape(-1)
        site = (flat % max(m, 1)).to(IDX)
        other = nbr.index_select(0, flat).to(IDX)  # pair of offset d: in = other (site + d), out = site
        counts_half = torch.bincount(flat // max(m, 1), minlength=half).tolist() if half else []
        starts_half = list(itertools.accumulate([0, *counts_half[:-1]]))[:half]
        # rows: [d_0 pairs, -d_0 pairs, d_1 pairs, -d_1 pairs, ...]
        ends = [s + n for s, n in zip(starts_half, counts_half, strict=True)]
        spans = list(zip(starts_half, ends, strict=True))
        in_idx = torch.cat([t for s, e in spans for t in (other[s:e], site[s:e])] or [site[:0]])
        out_idx = torch.cat([t for s, e in spans for t in (site[s:e], other[s:e])] or [site[:0]])
        return in_idx, out_idx, starts_half, counts_half

    def rulebook(self, kernel: tuple[int, int, int]) -> Rulebook:
        """The rulebook of an odd ``kernel`` that fits in this map's box (weights in row-major order)."""
        r, dev = self.radius, self.table.in_idx.device
        box = tuple(2 * x + 1 for x in r)
        centre = (box[0] * box[1] * box[2]) // 2
        tap_of_col, identity = {}, None
        for t, (a, b, c) in enumerate(itertools.product(*(range(k) for k in kernel))):
            d = (a - kernel[0] // 2 + r[0], b - kernel[1] // 2 + r[1], c - kernel[2] // 2 + r[2])
            u = (d[0] * box[1] + d[1]) * box[2] + d[2]
            if u == centre:
                identity = t
            else:
                tap_of_col[u if u < centre else u - 1] = t
        groups = []
        n_cols = 2 * centre
        for u in range(centre):  # an odd box kernel holds offset d iff it holds -d
            if u in tap_of_col and self.table.counts[u]:
                mirror = n_cols - 1 - u
                taps = (tap_of_col[u], tap_of_col[mirror])
                groups.append(_group(self.table.starts[u], self.table.counts[u], taps, dev))
        return Rulebook(self.table, groups, tuple(sorted(tap_of_col)), identity)


def strided_rulebook(
    coords: torch.Tensor,
    shape: tuple[int, int, int],
    kernel: tuple[int, int, int],
    stride: tuple[int, int, int],
    padding: tuple[int, int, int],
    batch_size: int | None = None,
) -> tuple[Rulebook, torch.Tensor, tuple[int, int, int]]:
    """Rulebook of a regular (strided) sparse convolution: every output touched by an input is active.

    Dense ``conv3d`` computes ``out[o] = Σ_d W[d] · in[o·s + d − p]``; input ``q`` reaches output
    ``o = (q + p − d) / s`` where that is an integer inside the output shape. Per axis that is a
    ``(k, M)`` test; the taps combine by broadcasting. Column ``t`` is weight tap ``t``.

    Returns:
        rulebook, output coordinates int64 ``(M', 4)`` sorted by key, output spatial shape.
    """
    out_shape = output_shape(shape, kernel, stride, padding)
    dev, m = coords.device, coords.shape[0]
    if batch_size is None:
        batch_size = int(coords[:, 0].max()) + 1 if m else 1
    n_cells = batch_size * out_shape[0] * out_shape[1] * out_shape[2]
    k = kernel[0] * kernel[1] * kernel[2]
    if _numba(coords) and m and n_cells <= DENSE_TABLE_MAX_CELLS:
        arr = [np.array(v, dtype=np.int64) for v in (shape, kernel, stride, padding, out_shape)]
        table = scratch_table(n_cells, dev).numpy()
        q_np, o_np, counts_np, keys_np = sparse_maps_cpu.strided_pairs(
            coords.contiguous().numpy(), *arr, table
        )
        q, out_idx, counts = torch.from_numpy(q_np), torch.from_numpy(o_np), counts_np.tolist()
        out_keys = torch.from_numpy(keys_np)
    else:
        q, out_idx, counts, out_keys = _strided_pairs_torch(
            coords, kernel, stride, padding, out_shape, batch_size
        )
    starts = list(itertools.accumulate([0, *counts[:-1]]))
    table = PairTable(q.to(IDX), out_idx.to(IDX), starts, counts, m, out_keys.numel())
    groups = [_group(starts[t], n, (t,), dev) for t, n in enumerate(counts) if n]
    book = Rulebook(table, groups, tuple(range(k)), None)
    return book, keys_to_coords(out_keys, out_shape), out_shape


def _strided_pairs_torch(coords, kernel, stride, padding, out_shape, batch_size):
    """(inputs, output ranks, counts per tap, sorted output keys) of a strided map, with
    whole-array torch operations (any device)."""
    dev, m = coords.device, coords.shape[0]
    ct = coords.t().contiguous()  # (4, M): per-axis rows keep every (k, M) operand contiguous
    ok_axes, o_axes = [], []
    for a in range(3):
        num = ct[a + 1][None, :] + (padding[a] - torch.arange(kernel[a], device=dev))[:, None]  # (k_a, M)
        o = torch.div(num, stride[a], rounding_mode="floor")
        ok_axes.append((num == o * stride[a]) & (o >= 0) & (o < out_shape[a]))
        o_axes.append(o)
    k = kernel[0] * kernel[1] * kernel[2]
    valid = ok_axes[0][:, None, None, :] & ok_axes[1][None, :, None, :] & ok_axes[2][None, None, :, :]
    flat = torch.nonzero(valid.reshape(-1)).reshape(-1)  # (tap, input) row-major: by tap, inputs ascending
    tap, q = flat // max(m, 1), flat % max(m, 1)

    def axis(a: int, d: torch.Tensor) -> torch.Tensor:  # output coordinate along axis a of each pair
        return o_axes[a].reshape(-1).index_select(0, d * m + q)

    k1, k2 = kernel[1], kernel[2]
    okey = ct[0].index_select(0, q) * out_shape[0] + axis(0, tap // (k1 * k2))
    okey = (okey * out_shape[1] + axis(1, (tap // k2) % k1)) * out_shape[2] + axis(2, tap % k2)
    n_cells = batch_size * out_shape[0] * out_shape[1] * out_shape[2]
    out_keys, out_idx = compact_keys(okey, n_cells)
    return q, out_idx, torch.bincount(tap, minlength=k).tolist(), out_keys

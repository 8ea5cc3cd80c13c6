"""Coordinate hashing and kernel maps (rulebooks) for sparse convolution.

Active sites are int64 ``(M, 4)`` coordinates (batch, i, j, k) inside a spatial shape, sorted by
their row-major key. Neighbours are found through a dense index table over the (padded) box when
it is small enough (one gather per tap, no bounds checks: the padding cells hold -1), else with
``searchsorted`` on the sorted keys; both run on any torch device without host synchronisation
except for reading the pair counts once per map.

A rulebook stores every tap's (input, output) pairs in two flat index tensors, one segment per
tap, so a convolution walks host-side segment bounds and never synchronises. Index dtype is
int64 on CPU (``index_add_`` with int32 indices takes a slow path there, measured 6× slower) and
int32 on CUDA.
"""

from __future__ import annotations

import itertools
import threading
from dataclasses import dataclass

import torch

# dense tables up to this many cells (int32/64 entries); larger boxes fall back to searchsorted
DENSE_TABLE_MAX_CELLS = 1 << 26


def coord_keys(coords: torch.Tensor, shape: tuple[int, int, int]) -> torch.Tensor:
    """Row-major keys ``(M,) int64`` of ``(M, 4)`` coordinates in a ``shape`` box."""
    s0, s1, s2 = shape
    return ((coords[:, 0] * s0 + coords[:, 1]) * s1 + coords[:, 2]) * s2 + coords[:, 3]


def keys_to_coords(keys: torch.Tensor, shape: tuple[int, int, int]) -> torch.Tensor:
    """Inverse of :func:`coord_keys`: ``(M,) int64`` keys → ``(M, 4) int64`` coordinates."""
    s0, s1, s2 = shape
    return torch.stack(
        [keys // (s0 * s1 * s2), (keys // (s1 * s2)) % s0, (keys // s2) % s1, keys % s2], dim=1
    )


def sort_coords(coords: torch.Tensor, shape: tuple[int, int, int]) -> torch.Tensor:
    """Permutation ``(M,) int64`` that sorts coordinates by key (the order every table assumes)."""
    return torch.argsort(coord_keys(coords, shape))


def kernel_offsets(kernel: tuple[int, int, int], device: torch.device | str = "cpu") -> torch.Tensor:
    """Kernel taps ``(K, 3) int64`` in row-major (kx, ky, kz) order, as dense ``conv3d`` weights."""
    taps = list(itertools.product(*(range(k) for k in kernel)))
    return torch.tensor(taps, dtype=torch.int64, device=device).reshape(-1, 3)


def index_dtype(device: torch.device) -> torch.dtype:
    """Dtype of rulebook indices on ``device`` (int32 on CUDA, int64 on CPU; see module docstring)."""
    return torch.int32 if device.type == "cuda" else torch.int64


def lookup(sorted_keys: torch.Tensor, query: torch.Tensor) -> torch.Tensor:
    """Index of each ``query`` key in ``sorted_keys`` (``(Q,) int64``), -1 where absent."""
    if sorted_keys.numel() == 0 or query.numel() == 0:
        return torch.full_like(query, -1)
    pos = torch.searchsorted(sorted_keys, query).clamp_max(sorted_keys.numel() - 1)
    return torch.where(sorted_keys[pos] == query, pos, torch.full_like(pos, -1))


_SCRATCH = threading.local()


def _scratch_table(n_cells: int, device: torch.device) -> torch.Tensor:
    """A cached int64 table of ``n_cells`` entries, all -1 (callers reset what they write).

    One per thread and device, grown on demand: allocating and filling a fresh multi-megabyte table
    per level and forward costs more than the lookups themselves.
    """
    tables = getattr(_SCRATCH, "tables", None)
    if tables is None:
        tables = _SCRATCH.tables = {}
    t = tables.get(device)
    if t is None or t.numel() < n_cells:
        with torch.inference_mode(False):  # a normal tensor, usable inside and outside inference mode
            t = tables[device] = torch.full((max(n_cells, 1 << 16),), -1, dtype=torch.int64, device=device)
    return t[:n_cells]


class DenseIndex:
    """Index of active sites in a padded dense box: ``table[key] = site`` (context manager).

    Args:
        coords: int64 ``(M, 4)`` sites sorted by key.
        shape: spatial shape.
        pad: cells of padding per axis (the largest neighbour offset to be looked up).
        batch_size: number of samples (the box's first axis).

    ``dense`` is False when the box exceeds :data:`DENSE_TABLE_MAX_CELLS`; lookups then use
    ``searchsorted``. Offsets larger than ``pad`` are not allowed.
    """

    def __init__(self, coords: torch.Tensor, shape, pad, batch_size: int) -> None:
        self.coords, self.shape, self.pad = coords, tuple(shape), tuple(pad)
        self.box = tuple(s + 2 * p for s, p in zip(shape, pad, strict=True))
        dev = coords.device
        n_cells = max(batch_size, 1) * self.box[0] * self.box[1] * self.box[2]
        self.dense = n_cells <= DENSE_TABLE_MAX_CELLS
        if coords.shape[0] == 0:
            self.keys = coords.new_zeros(0)
            self.dense = False
        elif self.dense:
            shift = torch.tensor([0, *self.pad], dtype=torch.int64, device=dev)
            self.keys = coord_keys(coords + shift, self.box)
            self.table = _scratch_table(n_cells, dev)
            self.table[self.keys] = torch.arange(coords.shape[0], device=dev)
        else:
            self.keys = coord_keys(coords, self.shape)

    def __enter__(self) -> DenseIndex:
        return self

    def __exit__(self, *exc) -> None:
        if self.dense:
            self.table[self.keys] = -1  # restore the scratch table's invariant

    def key_step(self, offsets: torch.Tensor) -> torch.Tensor:
        """Key differences ``(T,) int64`` of spatial ``(T, 3)`` offsets in this box's key space."""
        box = self.box if self.dense else self.shape
        step = torch.tensor([box[1] * box[2], box[2], 1], dtype=torch.int64, device=offsets.device)
        return (offsets * step).sum(1)

    def neighbours(self, offsets: torch.Tensor) -> torch.Tensor:
        """Site index ``(T, M) int64`` at ``site + offset`` for each offset row, -1 where inactive."""
        m = self.coords.shape[0]
        if m == 0:
            return self.coords.new_full((offsets.shape[0], 0), -1)
        query = self.keys[None, :] + self.key_step(offsets)[:, None]
        if self.dense:
            return self.table[query]
        nb = self.coords[None, :, 1:] + offsets[:, None, :]
        inside = ((nb >= 0) & (nb < torch.tensor(self.shape, device=nb.device))).all(dim=2)
        idx = lookup(self.keys, query.reshape(-1)).reshape(query.shape)
        return torch.where(inside, idx, torch.full_like(idx, -1))


@dataclass
class Rulebook:
    """Gather/scatter pairs of one sparse convolution.

    Attributes:
        in_idx, out_idx: ``(P,)`` pair indices (dtype :func:`index_dtype`), one segment per tap.
        segments: ``(tap, start, end)`` host ints: weight ``tap`` maps ``in_idx[start:end]`` onto
            ``out_idx[start:end]``; only non-empty segments are listed.
        identity: the weight tap that maps every site onto itself (submanifold centre), or None.
        n_in: number of input sites; n_out: number of output sites.
    """

    in_idx: torch.Tensor
    out_idx: torch.Tensor
    segments: list[tuple[int, int, int]]
    identity: int | None
    n_in: int
    n_out: int

    def transposed(self) -> Rulebook:
        """The rulebook of the inverse convolution (inputs and outputs swapped)."""
        return Rulebook(self.out_idx, self.in_idx, self.segments, self.identity, self.n_out, self.n_in)

    def pairs(self, n_taps: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Per weight tap ``(in_idx, out_idx)`` int64 (the identity tap as two aranges)."""
        empty = self.in_idx.new_zeros(0, dtype=torch.int64)
        out = [(empty, empty)] * n_taps
        for tap, s, e in self.segments:
            out[tap] = (self.in_idx[s:e].long(), self.out_idx[s:e].long())
        if self.identity is not None:
            ar = torch.arange(self.n_in, device=self.in_idx.device)
            out[self.identity] = (ar, ar)
        return out


@dataclass
class NeighbourMap:
    """All submanifold pairs of one resolution for the box kernel of radius ``radius``.

    Built once per resolution and shared by every submanifold layer whose kernel fits inside the box
    (1×3×3, 3×1×3, 3×1×1, … all select taps of the 3×3×3 map). Half the offsets are looked up;
    offset ``-d`` reuses offset ``d``'s pairs swapped (if ``p + d = q`` then ``q - d = p``).

    Attributes:
        in_idx, out_idx: flat pairs; offset ``u`` of the box (row-major, centre excluded) owns
            ``[starts[u], starts[u] + counts[u])``.
    """

    radius: tuple[int, int, int]
    in_idx: torch.Tensor
    out_idx: torch.Tensor
    starts: list[int]
    counts: list[int]
    n: int

    @classmethod
    def build(cls, coords: torch.Tensor, shape, radius, batch_size: int) -> NeighbourMap:
        """The map of ``coords`` (int64 ``(M, 4)`` sorted by key) in a ``shape`` grid."""
        dev, m = coords.device, coords.shape[0]
        offs = kernel_offsets(tuple(2 * r + 1 for r in radius), dev) - torch.tensor(radius, device=dev)
        n_box = offs.shape[0]
        half = n_box // 2
        with DenseIndex(coords, shape, radius, batch_size) as index:
            nbr = index.neighbours(offs[:half])  # (half, M)
        rows, site = torch.nonzero(nbr >= 0, as_tuple=True)
        other = nbr[rows, site]
        counts_half = torch.bincount(rows, minlength=half).tolist() if half else []
        idt = index_dtype(dev)
        # first half: offset d (in = site + d, out = site); second half: the same pairs swapped,
        # in the same order, for the mirrored offset -d
        in_idx = torch.cat([other, site]).to(idt)
        out_idx = torch.cat([site, other]).to(idt)
        p_half = int(rows.numel())
        starts_half = list(itertools.accumulate([0, *counts_half[:-1]])) if half else []
        starts, counts = [0] * (n_box - 1), [0] * (n_box - 1)
        for u in range(half):
            starts[u], counts[u] = starts_half[u], counts_half[u]
            mirror = n_box - 2 - u  # index of offset n_box-1-u once the centre is dropped
            starts[mirror], counts[mirror] = p_half + starts_half[u], counts_half[u]
        return cls(tuple(radius), in_idx, out_idx, starts, counts, m)

    def rulebook(self, kernel: tuple[int, int, int]) -> Rulebook:
        """The rulebook of an odd ``kernel`` that fits in this map's box (weights in row-major order)."""
        r = self.radius
        box = tuple(2 * x + 1 for x in r)
        segments, identity = [], None
        for t, (a, b, c) in enumerate(itertools.product(*(range(k) for k in kernel))):
            d = (a - kernel[0] // 2 + r[0], b - kernel[1] // 2 + r[1], c - kernel[2] // 2 + r[2])
            u = (d[0] * box[1] + d[1]) * box[2] + d[2]
            centre = (box[0] * box[1] * box[2]) // 2
            if u == centre:
                identity = t
                continue
            u = u if u < centre else u - 1
            if self.counts[u]:
                segments.append((t, self.starts[u], self.starts[u] + self.counts[u]))
        return Rulebook(self.in_idx, self.out_idx, segments, identity, self.n, self.n)


def submanifold_rulebook(
    coords: torch.Tensor,
    shape: tuple[int, int, int],
    kernel: tuple[int, int, int],
    batch_size: int | None = None,
) -> Rulebook:
    """Rulebook of a stride-1 submanifold convolution with padding ``k // 2`` (outputs = inputs).

    Args:
        coords: int64 ``(M, 4)`` active sites sorted by key.
        shape: spatial shape.
        kernel: odd kernel size per axis.
        batch_size: number of samples (default: read from ``coords``, one host synchronisation).
    """
    if batch_size is None:
        batch_size = int(coords[:, 0].max()) + 1 if coords.shape[0] else 1
    radius = tuple(k // 2 for k in kernel)
    return NeighbourMap.build(coords, shape, radius, batch_size).rulebook(kernel)


def output_shape(
    shape: tuple[int, int, int], kernel: tuple[int, int, int], stride: tuple[int, int, int], padding
) -> tuple[int, int, int]:
    """Spatial shape after a strided convolution, as dense ``conv3d`` computes it."""
    return tuple((n + 2 * p - k) // s + 1 for n, k, s, p in zip(shape, kernel, stride, padding, strict=True))


def _compact(keys: torch.Tensor, n_cells: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Sorted unique ``keys`` (int64 in ``[0, n_cells)``) and each key's index among them.

    A dense mark, ``nonzero`` and a table lookup when the box is small enough (no sort), else
    ``torch.unique``.
    """
    if n_cells > DENSE_TABLE_MAX_CELLS or keys.numel() == 0:
        return torch.unique(keys, sorted=True, return_inverse=True)
    table = _scratch_table(n_cells, keys.device)
    table[keys] = 0
    out = torch.nonzero(table == 0).reshape(-1)
    table[out] = torch.arange(out.numel(), device=keys.device)
    idx = table[keys]
    table[out] = -1
    return out, idx


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
    ``(M, k)`` test; the taps combine by broadcasting.

    Returns:
        rulebook, output coordinates int64 ``(M', 4)`` sorted by key, output spatial shape.
    """
    out_shape = output_shape(shape, kernel, stride, padding)
    dev, m = coords.device, coords.shape[0]
    if batch_size is None:
        batch_size = int(coords[:, 0].max()) + 1 if m else 1
    ok_axes, o_axes = [], []
    for a in range(3):
        num = coords[:, a + 1, None] + padding[a] - torch.arange(kernel[a], device=dev)[None, :]
        o = torch.div(num, stride[a], rounding_mode="floor")
        ok_axes.append((num - o * stride[a] == 0) & (o >= 0) & (o < out_shape[a]))
        o_axes.append(o)
    o0, o1, o2 = o_axes
    s1, s2 = out_shape[1], out_shape[2]
    base = coords[:, 0, None, None, None] * out_shape[0]
    okey = ((base + o0[:, :, None, None]) * s1 + o1[:, None, :, None]) * s2 + o2[:, None, None, :]
    valid = ok_axes[0][:, :, None, None] & ok_axes[1][:, None, :, None] & ok_axes[2][:, None, None, :]
    k = kernel[0] * kernel[1] * kernel[2]
    okey, valid = okey.reshape(m, k), valid.reshape(m, k)
    tap, q = torch.nonzero(valid.t(), as_tuple=True)  # grouped by tap, inputs ascending
    pair_keys = okey[q, tap]
    n_cells = batch_size * out_shape[0] * s1 * s2
    out_keys, out_idx = _compact(pair_keys, n_cells)
    counts = torch.bincount(tap, minlength=k).tolist() if k else []
    idt = index_dtype(dev)
    segments, start = [], 0
    for t, n in enumerate(counts):
        if n:
            segments.append((t, start, start + n))
        start += n
    book = Rulebook(q.to(idt), out_idx.to(idt), segments, None, m, out_keys.numel())
    return book, keys_to_coords(out_keys, out_shape), out_shape

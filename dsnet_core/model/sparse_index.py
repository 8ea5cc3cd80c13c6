"""Coordinate hashing and site lookup for sparse convolution.

Active sites are int64 ``(M, 4)`` coordinates (batch, i, j, k) inside a spatial shape, sorted by
their row-major key. Neighbours are found through a dense index table over the (padded) box when
it is small enough (one gather per offset, no bounds checks: the padding cells hold -1), else with
``searchsorted`` on the sorted keys; both run on any torch device without host synchronisation.
"""

from __future__ import annotations

import itertools
import threading

import torch

# dense int32 tables up to this many cells (256 MB); larger boxes fall back to searchsorted
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


def kernel_offsets(kernel: tuple[int, int, int], device: torch.device | str = "cpu") -> torch.Tensor:
    """Kernel taps ``(K, 3) int64`` in row-major (kx, ky, kz) order, as dense ``conv3d`` weights."""
    taps = list(itertools.product(*(range(k) for k in kernel)))
    return torch.tensor(taps, dtype=torch.int64, device=device).reshape(-1, 3)


def lookup(sorted_keys: torch.Tensor, query: torch.Tensor) -> torch.Tensor:
    """Index of each ``query`` key in ``sorted_keys`` (``(Q,) int64``), -1 where absent."""
    if sorted_keys.numel() == 0 or query.numel() == 0:
        return torch.full_like(query, -1)
    pos = torch.searchsorted(sorted_keys, query).clamp_max(sorted_keys.numel() - 1)
    return torch.where(sorted_keys[pos] == query, pos, torch.full_like(pos, -1))


_SCRATCH = threading.local()


def scratch_table(n_cells: int, device: torch.device) -> torch.Tensor:
    """A cached int32 table of ``n_cells`` entries, all -1 (callers reset what they write).

    One per thread and device, grown on demand: allocating and filling a fresh multi-megabyte table
    per level and forward costs more than the lookups themselves.
    """
    tables = getattr(_SCRATCH, "tables", None)
    if tables is None:
        tables = _SCRATCH.tables = {}
    t = tables.get(device)
    if t is None or t.numel() < n_cells:
        with torch.inference_mode(False):  # a normal tensor, usable inside and outside inference mode
            t = tables[device] = torch.full((max(n_cells, 1 << 16),), -1, dtype=torch.int32, device=device)
    return t[:n_cells]


def release_scratch_tables() -> None:
    """Free this thread's cached index tables."""
    _SCRATCH.tables = {}


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
            self.table = scratch_table(n_cells, dev)
            self.table.index_copy_(0, self.keys, torch.arange(coords.shape[0], dtype=torch.int32, device=dev))
        else:
            self.keys = coord_keys(coords, self.shape)

    def __enter__(self) -> DenseIndex:
        return self

    def __exit__(self, *exc) -> None:
        if self.dense:
            self.table.index_fill_(0, self.keys, -1)  # restore the scratch table's invariant

    def key_step(self, offsets: torch.Tensor) -> torch.Tensor:
        """Key differences ``(T,) int64`` of spatial ``(T, 3)`` offsets in this box's key space."""
        box = self.box if self.dense else self.shape
        step = torch.tensor([box[1] * box[2], box[2], 1], dtype=torch.int64, device=offsets.device)
        return (offsets * step).sum(1)

    def neighbours(self, offsets: torch.Tensor) -> torch.Tensor:
        """Site index ``(T, M)`` (int32, or int64 without a dense table) at ``site + offset`` for
        each offset row, -1 where inactive."""
        m = self.coords.shape[0]
        if m == 0:
            return self.coords.new_full((offsets.shape[0], 0), -1)
        query = self.keys[None, :] + self.key_step(offsets)[:, None]
        if self.dense:
            return self.table.index_select(0, query.reshape(-1)).reshape(query.shape)
        nb = self.coords[None, :, 1:] + offsets[:, None, :]
        inside = ((nb >= 0) & (nb < torch.tensor(self.shape, device=nb.device))).all(dim=2)
        idx = lookup(self.keys, query.reshape(-1)).reshape(query.shape)
        return torch.where(inside, idx, torch.full_like(idx, -1))


def output_shape(
    shape: tuple[int, int, int], kernel: tuple[int, int, int], stride: tuple[int, int, int], padding
) -> tuple[int, int, int]:
    """Spatial shape after a strided convolution, as dense ``conv3d`` computes it."""
    return tuple((n + 2 * p - k) // s + 1 for n, k, s, p in zip(shape, kernel, stride, padding, strict=True))


def compact_keys(keys: torch.Tensor, n_cells: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Sorted unique ``keys`` (int64 in ``[0, n_cells)``) and each key's index among them.

    A dense mark, ``nonzero`` and a table lookup when the box is small enough (no sort), else
    ``torch.unique``.
    """
    if n_cells > DENSE_TABLE_MAX_CELLS or keys.numel() == 0:
        return torch.unique(keys, sorted=True, return_inverse=True)
    table = scratch_table(n_cells, keys.device)
    table.index_fill_(0, keys, 0)
    out = torch.nonzero(table == 0).reshape(-1)
    table.index_copy_(0, out, torch.arange(out.numel(), dtype=torch.int32, device=keys.device))
    idx = table.index_select(0, keys).long()
    table.index_fill_(0, out, -1)
    return out, idx

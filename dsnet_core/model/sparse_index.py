"""Coordinate hashing and neighbour (rule) tables for sparse convolution.

Active sites are int64 ``(M, 4)`` coordinates (batch, i, j, k) inside a spatial shape. A site's
key is its row-major index in the (batch, i, j, k) box; tables are built with ``searchsorted``
on sorted keys, so they run on any torch device.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import torch


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


def lookup(sorted_keys: torch.Tensor, query: torch.Tensor) -> torch.Tensor:
    """Index of each ``query`` key in ``sorted_keys`` (``(Q,) int64``), -1 where absent."""
    if sorted_keys.numel() == 0 or query.numel() == 0:
        return torch.full_like(query, -1)
    pos = torch.searchsorted(sorted_keys, query).clamp_max(sorted_keys.numel() - 1)
    return torch.where(sorted_keys[pos] == query, pos, torch.full_like(pos, -1))


@dataclass
class Rulebook:
    """Gather/scatter pairs of one sparse convolution, one entry per kernel tap.

    Attributes:
        pairs: per tap ``(in_idx, out_idx)``, int64 ``(P_k,)`` each.
        n_in: number of input sites; n_out: number of output sites.
        identity: per tap, True when the tap maps every site onto itself (submanifold centre).
    """

    pairs: list[tuple[torch.Tensor, torch.Tensor]]
    n_in: int
    n_out: int
    identity: list[bool]

    def transposed(self) -> Rulebook:
        """The rulebook of the inverse convolution (inputs and outputs swapped)."""
        return Rulebook([(o, i) for i, o in self.pairs], self.n_out, self.n_in, list(self.identity))


def _split_rows(found: torch.Tensor, values: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """Per row of a ``(T, M)`` mask: (values[row, hits], column indices of the hits)."""
    rows, cols = torch.nonzero(found, as_tuple=True)
    counts = torch.bincount(rows, minlength=found.shape[0]).tolist()
    return list(zip(values[rows, cols].split(counts), cols.split(counts), strict=True))


def submanifold_rulebook(
    coords: torch.Tensor, shape: tuple[int, int, int], kernel: tuple[int, int, int]
) -> Rulebook:
    """Rulebook of a stride-1 submanifold convolution with padding ``k // 2`` (outputs = inputs).

    All taps are looked up in one vectorised ``searchsorted``; tap ``-d`` reuses tap ``d``'s pairs
    swapped (if ``p + d = q`` then ``q - d = p``), so only half the taps are searched.

    Args:
        coords: int64 ``(M, 4)`` active sites sorted by key.
        shape: spatial shape.
        kernel: odd kernel size per axis.
    """
    m, dev = coords.shape[0], coords.device
    centre = torch.tensor([k // 2 for k in kernel], device=dev)
    offs = kernel_offsets(kernel, dev) - centre
    n_taps = offs.shape[0]
    half = n_taps // 2  # taps before the centre; tap n_taps-1-t is the mirror of tap t
    arange = torch.arange(m, dtype=torch.int64, device=dev)
    pairs: list = [None] * n_taps
    identity = [False] * n_taps
    pairs[half], identity[half] = (arange, arange), True
    if half and m:
        keys = coord_keys(coords, shape)
        d = offs[:half]
        stride = torch.tensor([shape[1] * shape[2], shape[2], 1], dtype=torch.int64, device=dev)
        nb = coords[None, :, 1:] + d[:, None, :]
        ok = ((nb >= 0) & (nb < torch.tensor(shape, device=dev))).all(dim=2)
        query = keys[None, :] + (d * stride).sum(1)[:, None]
        idx = lookup(keys, query.reshape(-1)).reshape(half, m)
        found = ok & (idx >= 0)
        for t, (nbr, site) in enumerate(_split_rows(found, idx)):
            pairs[t] = (nbr, site)
            pairs[n_taps - 1 - t] = (site, nbr)
    elif half:
        empty = arange[:0]
        for t in range(n_taps):
            if t != half:
                pairs[t] = (empty, empty)
    return Rulebook(pairs, m, m, identity)


def output_shape(
    shape: tuple[int, int, int], kernel: tuple[int, int, int], stride: tuple[int, int, int], padding
) -> tuple[int, int, int]:
    """Spatial shape after a strided convolution, as dense ``conv3d`` computes it."""
    return tuple((n + 2 * p - k) // s + 1 for n, k, s, p in zip(shape, kernel, stride, padding, strict=True))


def strided_rulebook(
    coords: torch.Tensor,
    shape: tuple[int, int, int],
    kernel: tuple[int, int, int],
    stride: tuple[int, int, int],
    padding: tuple[int, int, int],
) -> tuple[Rulebook, torch.Tensor, tuple[int, int, int]]:
    """Rulebook of a regular (strided) sparse convolution: every output touched by an input is active.

    Dense ``conv3d`` computes ``out[o] = Σ_d W[d] · in[o·s + d − p]``; input ``q`` reaches output
    ``o = (q + p − d) / s`` where that is an integer inside the output shape.

    Returns:
        rulebook, output coordinates int64 ``(M', 4)`` sorted by key, output spatial shape.
    """
    out_shape = output_shape(shape, kernel, stride, padding)
    dev = coords.device
    offs = kernel_offsets(kernel, dev)
    s = torch.tensor(stride, dtype=torch.int64, device=dev)
    p = torch.tensor(padding, dtype=torch.int64, device=dev)
    osize = torch.tensor(out_shape, dtype=torch.int64, device=dev)
    arange = torch.arange(coords.shape[0], dtype=torch.int64, device=dev)
    cand = []
    for d in offs:
        q = coords[:, 1:] + p - d
        ok = ((q % s) == 0).all(dim=1)
        o = torch.div(q, s, rounding_mode="floor")
        ok &= ((o >= 0) & (o < osize)).all(dim=1)
        cand.append((arange[ok], torch.cat([coords[ok, :1], o[ok]], dim=1)))
    all_keys = torch.cat([coord_keys(c, out_shape) for _, c in cand]) if cand else arange[:0]
    out_keys = torch.unique(all_keys, sorted=True)
    pairs = [(i, lookup(out_keys, coord_keys(c, out_shape))) for i, c in cand]
    book = Rulebook(pairs, coords.shape[0], out_keys.numel(), [False] * len(pairs))
    return book, keys_to_coords(out_keys, out_shape), out_shape

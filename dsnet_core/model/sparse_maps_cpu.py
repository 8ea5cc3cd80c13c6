"""CPU (numba) builders of the kernel maps in :mod:`dsnet_core.model.sparse_maps`.

The torch builders run on any device as a handful of whole-array operations; on one CPU thread
their int64 temporaries (tens of arrays the size of the pair list) cost more than the lookups
themselves. These loops produce the same tables, pair for pair and in the same order, in one or
two passes. Every function takes and returns numpy arrays; the dense index tables are the
callers' scratch tables (all -1 on entry, restored to -1 on return).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def neighbour_pairs(keys, m, steps, table):
    """Pairs of the first half of a box's offsets (see ``NeighbourMap.build``).

    Args:
        keys: int64 ``(M,)`` sites' keys in the padded box (ascending).
        m: number of sites.
        steps: int64 ``(H,)`` key difference of each half offset ``d_u``.
        table: int32 dense index of the padded box (-1 on entry and return).

    Returns:
        (in_idx int32 ``(2P,)``, out_idx int32 ``(2P,)``, counts int64 ``(H,)``): per offset ``u``
        its pairs (in = site + d_u, out = site; sites ascending), then the same pairs swapped.
    """
    for s in range(m):
        table[keys[s]] = s
    h = steps.shape[0]
    nbr = np.empty((h, m), dtype=np.int32)
    counts = np.zeros(h, dtype=np.int64)
    for u in range(h):
        for s in range(m):
            o = table[keys[s] + steps[u]]
            nbr[u, s] = o
            if o >= 0:
                counts[u] += 1
    for s in range(m):
        table[keys[s]] = -1
    total = 2 * counts.sum()
    in_idx = np.empty(total, dtype=np.int32)
    out_idx = np.empty(total, dtype=np.int32)
    pos = 0
    for u in range(h):
        a, b = pos, pos + counts[u]
        for s in range(m):
            o = nbr[u, s]
            if o >= 0:
                in_idx[a], out_idx[a] = o, s
                in_idx[b], out_idx[b] = s, o
                a += 1
                b += 1
        pos += 2 * counts[u]
    return in_idx, out_idx, counts


@numba.njit(cache=True)
def _axis_taps(size, k, s, p, out_size):
    """Per coordinate ``c`` along one axis (``0 <= c < size``): the ``n[c]`` taps ``d[c, :]``
    through which it reaches an output, and that output ``o[c, :]`` (``c + p - d = s · o``)."""
    n = np.zeros(size, dtype=np.int64)
    d_of = np.empty((size, k), dtype=np.int64)
    o_of = np.empty((size, k), dtype=np.int64)
    for c in range(size):
        for d in range(k):
            num = c + p - d
            o = num // s
            if num == o * s and o >= 0 and o < out_size:
                d_of[c, n[c]] = d
                o_of[c, n[c]] = o
                n[c] += 1
    return n, d_of, o_of


@numba.njit(cache=True)
def strided_pairs(coords, shape, kernel, stride, padding, out_shape, table):
    """Pairs of a strided convolution (see ``strided_rulebook``).

    Args:
        coords: int64 ``(M, 4)`` sites sorted by key.
        shape, kernel, stride, padding, out_shape: int64 ``(3,)``.
        table: int32 scratch of at least ``batch · prod(out_shape)`` cells (-1 on entry and return).

    Returns:
        (in_idx int32 ``(P,)``, out_idx int32 ``(P,)``, counts int64 ``(K,)``, out_keys int64
        ``(M',)`` ascending): pairs by tap (row-major), inputs ascending within a tap; ``out_idx``
        is the output's rank among ``out_keys``.
    """
    m = coords.shape[0]
    k1, k2 = kernel[1], kernel[2]
    n_taps = kernel[0] * k1 * k2
    n0, d0, o0 = _axis_taps(shape[0], kernel[0], stride[0], padding[0], out_shape[0])
    n1, d1, o1 = _axis_taps(shape[1], k1, stride[1], padding[1], out_shape[1])
    n2, d2, o2 = _axis_taps(shape[2], k2, stride[2], padding[2], out_shape[2])
    counts = np.zeros(n_taps, dtype=np.int64)
    marked = np.empty(max(m, 16), dtype=np.int64)
    n_marked = 0
    out_keys = marked[:0]
    starts = np.zeros(n_taps, dtype=np.int64)
    in_idx = np.empty(0, dtype=np.int32)
    out_idx = np.empty(0, dtype=np.int32)
    for fill in range(2):  # pass 0 counts the pairs per tap and collects the outputs; pass 1 fills
        if fill:
            out_keys = np.sort(marked[:n_marked])
            for r in range(n_marked):
                table[out_keys[r]] = r
            for t in range(1, n_taps):
                starts[t] = starts[t - 1] + counts[t - 1]
            in_idx = np.empty(starts[n_taps - 1] + counts[n_taps - 1], dtype=np.int32)
            out_idx = np.empty(in_idx.shape[0], dtype=np.int32)
        for q in range(m):  # inputs ascending within every tap
            c0, c1, c2 = coords[q, 1], coords[q, 2], coords[q, 3]
            if not (0 <= c0 < shape[0] and 0 <= c1 < shape[1] and 0 <= c2 < shape[2]):
                raise ValueError("a site lies outside the grid's shape")
            base = coords[q, 0] * out_shape[0]
            for i0 in range(n0[c0]):
                key0 = (base + o0[c0, i0]) * out_shape[1]
                for i1 in range(n1[c1]):
                    key1 = (key0 + o1[c1, i1]) * out_shape[2]
                    t1 = (d0[c0, i0] * k1 + d1[c1, i1]) * k2
                    for i2 in range(n2[c2]):
                        key = key1 + o2[c2, i2]
                        t = t1 + d2[c2, i2]
                        if fill:
                            p = starts[t]
                            in_idx[p] = q
                            out_idx[p] = table[key]
                            starts[t] = p + 1
                            continue
                        counts[t] += 1
                        if table[key] < 0:
                            table[key] = 0
                            if n_marked == marked.shape[0]:
                                grown = np.empty(2 * n_marked, dtype=np.int64)
                                grown[:n_marked] = marked
                                marked = grown
                            marked[n_marked] = key
                            n_marked += 1
    for r in range(n_marked):
        table[out_keys[r]] = -1
    return in_idx, out_idx, counts, out_keys


@numba.njit(cache=True)
def csr_rows(idx, seg_start, seg_end, n):
    """Rows of the pairs in the segments, grouped by their site in ``idx`` (a counting sort that
    walks the segments in turn), and each site's first position.

    Args:
        idx: int32 ``(P,)`` site of every pair row.
        seg_start, seg_end: int64 ``(S,)`` row ranges, walked in order.
        n: number of sites.

    Returns:
        (rows int32 ``(Q,)``, offsets int32 ``(n,)``).
    """
    fill = np.zeros(n + 1, dtype=np.int64)
    for g in range(seg_start.shape[0]):
        for r in range(seg_start[g], seg_end[g]):
            fill[idx[r] + 1] += 1
    for i in range(n):
        fill[i + 1] += fill[i]
    offsets = fill[:n].astype(np.int32)
    rows = np.empty(fill[n], dtype=np.int32)
    for g in range(seg_start.shape[0]):
        for r in range(seg_start[g], seg_end[g]):
            site = idx[r]
            rows[fill[site]] = r
            fill[site] += 1
    return rows, offsets

"""Fixed-radius neighbour sums over a k-d tree with subtree summaries (CPU, numba).

``radius_sums(queries, points, radii, values)[j, a] = Σ_b values[j, b]`` over the points ``b``
with ``‖queries[a] − points[b]‖² ≤ radii[j]²``. The pointwise test is exact differences,
``dx·dx + dy·dy + dz·dz`` in the dtype of the inputs (the expression of the dense kernel, so both
draw the same boundaries). A subtree whose box lies wholly inside a radius (with a 1e-6 relative
margin, so no point of it could fail the pointwise test) contributes its precomputed sum at once;
one wholly outside (same margin) is skipped; only the rest is visited point by point. Seeds that
have converged into tight clusters therefore cost about one visit per cluster, not one per pair.
Sums accumulate in float64. Values shared by every radius (a broadcast ``values``, as dynamic
shifting passes) are stored and summarised once, not once per radius (the same additions).
"""

from __future__ import annotations

import numba
import numpy as np

from dsnet_core.instance.kdtree import build_kdtree

_LEAF_SIZE = 8  # measured on shifting seeds: 8 beats 16 by 10-15% (dual-tree walk included)
_MARGIN = 1e-6


class RadiusIndex:
    """Points, radii and values prepared once for many :meth:`sums` queries.

    Args:
        points: (P, 3) float32 or float64 positions in metres.
        radii: (K,) radii in metres, ascending.
        values: (K, P, C) values; ``values[j]`` is summed for radius ``radii[j]``.
    """

    def __init__(self, points: np.ndarray, radii: np.ndarray, values: np.ndarray) -> None:
        radii = np.asarray(radii, dtype=np.float64)
        if radii.ndim != 1 or radii.size == 0 or np.any(np.diff(radii) < 0) or radii[0] <= 0:
            raise ValueError(f"radii must be positive and ascending, got {radii}")
        k, n_p, c = values.shape
        if k != radii.size or n_p != points.shape[0] or points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(
                f"values {values.shape} do not match radii {radii.shape} and points {points.shape}"
            )
        if not np.isfinite(points).all():
            raise ValueError("positions hold NaN or inf")
        self.dtype = points.dtype
        self.radii = radii
        self.shape = (k, c)
        self.empty = n_p == 0
        if self.empty:
            return
        pts = np.ascontiguousarray(points)
        self.order, self.start, self.end, self.left = build_kdtree(pts, _LEAF_SIZE)
        self.ps = pts[self.order]
        shared = k == 1 or values.strides[0] == 0  # every radius sums the same values
        self.vs = np.ascontiguousarray(
            np.transpose(values[:1] if shared else values, (1, 0, 2))[self.order], dtype=np.float64
        )  # (P, K, C), or (P, 1, C) for shared values
        self.lo, self.hi, self.node_sums = _summaries(self.ps, self.vs, self.start, self.end, self.left)

    def sums(self, queries: np.ndarray) -> np.ndarray:
        """float64 (K, Q, C): for each radius and query, the sum of the values of the points within."""
        if queries.dtype != self.dtype:
            raise ValueError(f"queries ({queries.dtype}) and points ({self.dtype}) must share a dtype")
        out = np.zeros((self.shape[0], queries.shape[0], self.shape[1]))
        if queries.shape[0] == 0 or self.empty:
            return out
        if not np.isfinite(queries).all():
            raise ValueError("positions hold NaN or inf")
        return self._sums(np.ascontiguousarray(queries), out)

    def sums_at_points(self) -> np.ndarray:
        """``sums(points)`` (equal up to the order of the float64 additions): the indexed points as
        queries, by a dual-tree walk over the one tree (:func:`_self_query`; measured 2.0–2.4×
        faster than one walk per query in the given order on shifting seeds)."""
        out = np.zeros((self.shape[0], 0 if self.empty else self.ps.shape[0], self.shape[1]))
        if self.empty:
            return out
        r2 = (self.radii * self.radii).astype(self.dtype)
        args = (self.ps, self.vs, r2, self.radii**2, self.lo, self.hi, self.node_sums)
        _self_query(*args, self.start, self.end, self.left, out)
        back = np.empty_like(out)
        back[:, self.order] = out
        return back

    def _sums(self, q: np.ndarray, out: np.ndarray) -> np.ndarray:
        r2 = (self.radii * self.radii).astype(self.dtype)
        _query(
            q,
            self.ps,
            self.vs,
            r2,
            self.radii**2,
            self.lo,
            self.hi,
            self.node_sums,
            self.start,
            self.end,
            self.left,
            out,
        )
        return out


def radius_sums(queries: np.ndarray, points: np.ndarray, radii: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Sum ``values`` over the points within each radius of each query.

    Args:
        queries: (Q, 3) float32 or float64 positions in metres.
        points: (P, 3) positions, same dtype as ``queries``.
        radii: (K,) radii in metres, ascending.
        values: (K, P, C) values; ``values[j]`` is summed for radius ``radii[j]``.

    Returns:
        float64 (K, Q, C) sums.
    """
    index = RadiusIndex(points, radii, values)
    return index.sums_at_points() if queries is points else index.sums(queries)


@numba.njit(cache=True)
def _summaries(ps, vs, start, end, left):
    n = start.shape[0]
    k, c = vs.shape[1], vs.shape[2]
    lo = np.empty((n, 3))
    hi = np.empty((n, 3))
    sums = np.zeros((n, k, c))
    for node in range(n - 1, -1, -1):  # children before parents
        if left[node] < 0:
            for d in range(3):
                lo[node, d] = np.inf
                hi[node, d] = -np.inf
            for s in range(start[node], end[node]):
                for d in range(3):
                    lo[node, d] = min(lo[node, d], ps[s, d])
                    hi[node, d] = max(hi[node, d], ps[s, d])
                sums[node] += vs[s]
        else:
            a, b = left[node], left[node] + 1
            for d in range(3):
                lo[node, d] = min(lo[a, d], lo[b, d])
                hi[node, d] = max(hi[a, d], hi[b, d])
            sums[node] = sums[a] + sums[b]
    return lo, hi, sums


@numba.njit(cache=True, inline="always")
def _open_radii(mind2, maxd2, r2_64, jlo, jhi):
    """Of the radii ``jlo..jhi`` (ascending, squared in ``r2_64``), for a pair of regions at squared
    distances ``mind2..maxd2``: ``(lo, hi)`` such that radii above ``hi`` hold every pair, radii
    below ``lo`` none, and ``lo..hi`` must be looked into (empty when ``lo > hi``). The 1e-6
    relative margins keep the verdicts true under the pointwise test's rounding."""
    hi = jhi
    while hi >= jlo and maxd2 <= r2_64[hi] * (1.0 - 1e-6):
        hi -= 1
    lo = jlo
    while lo <= hi and mind2 > r2_64[lo] * (1.0 + 1e-6):
        lo += 1
    return lo, hi


@numba.njit(cache=True, inline="always")
def _add_rows(acc, rows, j0, j1):
    """``acc[j0:j1] += rows[j0:j1]`` for 2-D arrays, without the temporary a slice sum makes
    (``rows`` of one row: that row for every ``j``)."""
    step = 1 if rows.shape[0] > 1 else 0
    for j in range(j0, j1):
        for ch in range(acc.shape[1]):
            acc[j, ch] += rows[j * step, ch]


@numba.njit(cache=True, inline="always")
def _leaf_sums(ps, vs, r2, s0, s1, qx, qy, qz, jlo, jhi, acc):
    """``acc[j] += vs[s, j]`` for the points ``s0 <= s < s1`` within radius ``j`` of ``(qx, qy, qz)``
    (``jlo <= j <= jhi``): the pointwise test, exact differences in the points' dtype."""
    c = vs.shape[2]
    step = 1 if vs.shape[1] > 1 else 0  # shared values: one column for every radius
    for s in range(s0, s1):
        dx = ps[s, 0] - qx
        dy = ps[s, 1] - qy
        dz = ps[s, 2] - qz
        d2 = dx * dx + dy * dy + dz * dz
        j = jhi
        while j >= jlo and d2 <= r2[j]:
            for ch in range(c):
                acc[j, ch] += vs[s, j * step, ch]
            j -= 1


@numba.njit(cache=True)
def _query(q, ps, vs, r2, r2_64, lo, hi, sums, start, end, left, out):
    k, c = r2.shape[0], vs.shape[2]
    stack_node = np.empty(256, dtype=np.int64)
    stack_jlo = np.empty(256, dtype=np.int64)
    stack_jhi = np.empty(256, dtype=np.int64)
    acc = np.empty((k, c))
    right_of = left + 1  # siblings are created together
    for a in range(q.shape[0]):
        qx, qy, qz = q[a, 0], q[a, 1], q[a, 2]
        acc[:] = 0.0
        top = 0
        stack_node[0], stack_jlo[0], stack_jhi[0] = 0, 0, k - 1
        top = 1
        while top > 0:
            top -= 1
            node, jlo, jhi = stack_node[top], stack_jlo[top], stack_jhi[top]
            mind2 = 0.0
            maxd2 = 0.0
            for d in range(3):
                x = np.float64(q[a, d])
                below = lo[node, d] - x
                above = x - hi[node, d]
                if below > 0:
                    mind2 += below * below
                elif above > 0:
                    mind2 += above * above
                far = max(abs(x - lo[node, d]), abs(x - hi[node, d]))
                maxd2 += far * far
            new_lo, new_hi = _open_radii(mind2, maxd2, r2_64, jlo, jhi)
            _add_rows(acc, sums[node], new_hi + 1, jhi + 1)
            if new_lo > new_hi:
                continue
            if left[node] < 0:
                _leaf_sums(ps, vs, r2, start[node], end[node], qx, qy, qz, new_lo, new_hi, acc)
            else:
                stack_node[top], stack_jlo[top], stack_jhi[top] = left[node], new_lo, new_hi
                stack_node[top + 1], stack_jlo[top + 1], stack_jhi[top + 1] = right_of[node], new_lo, new_hi
                top += 2
        for j in range(k):
            for ch in range(c):
                out[j, a, ch] = acc[j, ch]
    return out


@numba.njit(cache=True)
def _self_query(ps, vs, r2, r2_64, lo, hi, sums, start, end, left, out):
    """``out[j, a] = Σ_b vs[b, j]`` over the indexed points ``b`` within ``radii[j]`` of the indexed
    point ``a`` (tree order), by a dual-tree walk: a pair of nodes whose boxes lie wholly within a
    radius adds the data node's sum once to the query node (pushed down to its points at the end),
    a pair wholly beyond it is skipped, and only the rest is split down to point pairs."""
    n_nodes = start.shape[0]
    k, c = r2.shape[0], vs.shape[2]
    pending = np.zeros((n_nodes, k, c))
    acc = np.zeros((ps.shape[0], k, c))
    stack_q = np.empty(512, dtype=np.int64)
    stack_d = np.empty(512, dtype=np.int64)
    stack_jlo = np.empty(512, dtype=np.int64)
    stack_jhi = np.empty(512, dtype=np.int64)
    stack_q[0], stack_d[0], stack_jlo[0], stack_jhi[0] = 0, 0, 0, k - 1
    top = 1
    while top > 0:
        top -= 1
        qn, dn, jlo, jhi = stack_q[top], stack_d[top], stack_jlo[top], stack_jhi[top]
        mind2 = 0.0
        maxd2 = 0.0
        for d in range(3):
            gap = max(lo[dn, d] - hi[qn, d], lo[qn, d] - hi[dn, d], 0.0)
            mind2 += gap * gap
            far = max(hi[dn, d] - lo[qn, d], hi[qn, d] - lo[dn, d])
            maxd2 += far * far
        new_lo, new_hi = _open_radii(mind2, maxd2, r2_64, jlo, jhi)
        _add_rows(pending[qn], sums[dn], new_hi + 1, jhi + 1)
        if new_lo > new_hi:
            continue
        q_leaf, d_leaf = left[qn] < 0, left[dn] < 0
        if q_leaf and d_leaf:
            for a in range(start[qn], end[qn]):
                _leaf_sums(
                    ps, vs, r2, start[dn], end[dn], ps[a, 0], ps[a, 1], ps[a, 2], new_lo, new_hi, acc[a]
                )
            continue
        if top + 2 > stack_q.shape[0]:
            raise RuntimeError("dual-tree stack overflow")
        ext_q = max(hi[qn, 0] - lo[qn, 0], hi[qn, 1] - lo[qn, 1], hi[qn, 2] - lo[qn, 2])
        ext_d = max(hi[dn, 0] - lo[dn, 0], hi[dn, 1] - lo[dn, 1], hi[dn, 2] - lo[dn, 2])
        split_d = q_leaf or (not d_leaf and ext_d >= ext_q)
        for child in range(2):
            if split_d:
                stack_q[top], stack_d[top] = qn, left[dn] + child
            else:
                stack_q[top], stack_d[top] = left[qn] + child, dn
            stack_jlo[top], stack_jhi[top] = new_lo, new_hi
            top += 1
    for node in range(n_nodes):  # parents before children: push the pending sums down
        if left[node] >= 0:
            for child in range(left[node], left[node] + 2):
                pending[child] += pending[node]
        else:
            for a in range(start[node], end[node]):
                for j in range(k):
                    for ch in range(c):
                        out[j, a, ch] = acc[a, j, ch] + pending[node, j, ch]
    return out

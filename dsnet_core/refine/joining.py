"""Tracks repaired in both directions: a track that ends and one that starts at most ``G`` frames
later are the same object when each one's position, extrapolated across the gap with its own
velocity (forwards from the end of the first, backwards from the start of the second), lands near
the other's observed centre. Pairs are chosen one-to-one (an optimal assignment), only within a
class group; a chain of joined tracks keeps the id of its earliest track.

Tracks are named by their keys ``id | generation << 16`` (:mod:`dsnet_core.temporal.ids`): once a
temporal stage has reused ids, one id names several tracks at different times, and a join that
would stretch an id over frames where another track holds it is refused (:func:`keep_ids_apart`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from dsnet_core.refine.history import TrackSummary
from dsnet_core.refine.motion import fit_velocity
from dsnet_core.temporal.ids import key_generation, key_id


@dataclass(frozen=True)
class Join:
    """One repair: track ``later`` continues track ``earlier`` after ``gap`` frames unseen, with a
    mean extrapolation error of ``distance`` metres."""

    earlier: int
    later: int
    gap: int
    distance: float


def _end_state(s: TrackSummary, t: int, n: int, at_end: bool) -> tuple[float, np.ndarray, np.ndarray]:
    """(time, centre, velocity) of track ``t`` at its end (or start), velocity from ``n`` sightings."""
    r = s.rows(t)
    time, centre = s.time[r], s.centre[r]
    sl = slice(-n, None) if at_end else slice(0, n)
    k = -1 if at_end else 0
    return float(time[k]), centre[k], fit_velocity(time[sl], centre[sl])


def _states(s: TrackSummary, n: int, at_end: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every track's :func:`_end_state`: times ``(T,)``, centres and velocities ``(T, 3)``."""
    states = [_end_state(s, t, n, at_end) for t in range(s.ids.size)]
    if not states:
        return np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3))
    return (
        np.array([x[0] for x in states]),
        np.stack([x[1] for x in states]),
        np.stack([x[2] for x in states]),
    )


def _costs(end: tuple, start: tuple) -> np.ndarray:
    """Mean miss (metres) of each pair's extrapolations: ``end`` of the earlier tracks and ``start``
    of the later ones, as (time, centre, velocity) arrays that broadcast against each other."""
    (ta, ca, va), (tb, cb, vb) = end, start
    dt = (tb - ta)[..., None]
    fwd = ca + va * dt - cb
    bwd = cb - vb * dt - ca
    norm = lambda d: np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2])  # noqa: E731
    return 0.5 * (norm(fwd) + norm(bwd))


def join_tracks(
    s: TrackSummary,
    eligible: np.ndarray,
    group: np.ndarray,
    max_gap: int,
    max_distance: float,
    velocity_frames: int = 5,
) -> list[Join]:
    """The joins of a sequence's tracks.

    Args:
        s: the tracks.
        eligible: ``(T,) bool`` tracks that may be joined (not dissolved).
        group: ``(T,) int64`` class group of each track; only tracks of one group are joined.
        max_gap: G, the most frames without a sighting between the two.
        max_distance: the largest accepted mean extrapolation miss across the gap, metres.
        velocity_frames: sightings each end velocity is fitted to.

    Returns:
        The joins, sorted by the later track's first frame.
    """
    first, last = s.first, s.last
    order = np.argsort(first, kind="stable")
    firsts = first[order]
    ends, starts = _states(s, velocity_frames, True), _states(s, velocity_frames, False)
    pairs: list[tuple[int, int, float]] = []
    for a in np.flatnonzero(eligible):
        lo = np.searchsorted(firsts, last[a] + 1, side="left")
        hi = np.searchsorted(firsts, last[a] + 1 + max_gap, side="right")
        cand = order[lo:hi]
        cand = cand[(cand != a) & eligible[cand] & (group[cand] == group[a])]
        if cand.size == 0:
            continue
        cost = _costs(tuple(x[a] for x in ends), tuple(x[cand] for x in starts))
        ok = cost <= max_distance
        pairs += [(int(a), int(b), float(c)) for b, c in zip(cand[ok], cost[ok], strict=True)]
    if not pairs:
        return []
    joins = [
        Join(int(s.ids[a]), int(s.ids[b]), int(first[b] - last[a] - 1), c)
        for a, b, c in _assign(pairs, max_distance)
    ]
    id_first = dict(zip(s.ids.tolist(), first.tolist(), strict=True))
    return sorted(joins, key=lambda j: (id_first[j.later], j.later))


def _assign(pairs: list[tuple[int, int, float]], max_distance: float) -> list[tuple[int, int, float]]:
    """The one-to-one choice of least total cost among candidate ``(earlier, later, cost)`` pairs.

    The candidates form a sparse bipartite graph: each connected group of tracks is assigned on
    its own (the optimum of a block-diagonal problem is its blocks' optima), so memory and time
    follow the largest group, not the number of tracks in the sequence squared.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rows = sorted({p[0] for p in pairs})
    cols = sorted({p[1] for p in pairs})
    ri = {a: i for i, a in enumerate(rows)}
    ci = {b: j for j, b in enumerate(cols)}
    n = len(rows) + len(cols)
    edges = coo_matrix(
        (np.ones(len(pairs)), ([ri[a] for a, _, _ in pairs], [len(rows) + ci[b] for _, b, _ in pairs])),
        shape=(n, n),
    )
    _, component = connected_components(edges, directed=False)
    groups: dict[int, list[tuple[int, int, float]]] = {}
    for a, b, c in pairs:
        groups.setdefault(int(component[ri[a]]), []).append((a, b, c))
    big = 1e6 * (1.0 + max_distance)
    out = []
    for group in groups.values():
        g_rows = sorted({p[0] for p in group})
        g_cols = sorted({p[1] for p in group})
        gi = {a: i for i, a in enumerate(g_rows)}
        gj = {b: j for j, b in enumerate(g_cols)}
        cost = np.full((len(g_rows), len(g_cols)), big)
        for a, b, c in group:
            cost[gi[a], gj[b]] = c
        r, c = linear_sum_assignment(cost)
        out += [
            (g_rows[i], g_cols[j], float(cost[i, j])) for i, j in zip(r, c, strict=True) if cost[i, j] < big
        ]
    return out


def chain_heads(ids: np.ndarray, joins: list[Join]) -> np.ndarray:
    """``(T,) int64``: for each id of ``ids``, the id of the earliest track of its chain of joins."""
    prev = {j.later: j.earlier for j in joins}
    out = np.empty(ids.size, np.int64)
    for k, i in enumerate(ids.tolist()):
        while i in prev:
            i = prev[i]
        out[k] = i
    return out


def keep_ids_apart(s: TrackSummary, joins: list[Join], keeps_id: np.ndarray) -> tuple[list[Join], int]:
    """The joins that keep every label id on one track at a time, and how many were refused.

    A chain of joins labels all its tracks with its earliest track's id, from that track's first
    frame to its last track's last frame. Where ids were reused, another track may hold the same id
    in that span; a join that would stretch the chain over it is refused (the later track keeps
    its own id). Without reused ids (every key's generation 0) nothing is refused.

    Args:
        s: the tracks (keys in ``s.ids``).
        joins: candidate joins, sorted by the later track's first frame (:func:`join_tracks`).
        keeps_id: ``(T,) bool`` tracks whose points keep an id (not dissolved).
    """
    if not joins or not (key_generation(s.ids) > 0).any():
        return joins, 0
    row = {int(k): i for i, k in enumerate(s.ids.tolist())}
    first, last, label_id = s.first, s.last, key_id(s.ids)
    prev: dict[int, int] = {}  # later -> earlier, kept joins
    members: dict[int, set[int]] = {}  # chain head -> its tracks
    end: dict[int, int] = {}  # chain head -> its last frame
    kept, refused = [], 0
    for j in joins:
        head = j.earlier
        while head in prev:
            head = prev[head]
        h, b = row[head], row[j.later]
        chain = members.get(head, {head})
        span_end = max(end.get(head, int(last[h])), int(last[b]))
        others = np.flatnonzero((label_id == label_id[h]) & keeps_id)
        clash = [
            o
            for o in others.tolist()
            if int(s.ids[o]) not in chain and int(s.ids[o]) != j.later
            and first[o] <= span_end and last[o] >= first[h]
        ]  # fmt: skip
        if clash:
            refused += 1
            continue
        kept.append(j)
        prev[j.later] = j.earlier
        members[head] = chain | {j.later}
        end[head] = span_end
    return kept, refused

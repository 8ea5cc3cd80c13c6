"""Tracks repaired in both directions: a track that ends and one that starts at most ``G`` frames
later are the same object when each one's position, extrapolated across the gap with its own
velocity (forwards from the end of the first, backwards from the start of the second), lands near
the other's observed centre. Pairs are chosen one-to-one (an optimal assignment), only within a
class group; a chain of joined tracks keeps the id of its earliest track."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from dsnet_core.refine.history import TrackSummary
from dsnet_core.refine.motion import fit_velocity


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


def join_cost(s: TrackSummary, a: int, b: int, velocity_frames: int) -> float:
    """Mean distance (metres) between each track's extrapolation across the gap and the other's
    centre, for track ``a`` ending before track ``b`` starts (indices into ``s.ids``)."""
    ta, ca, va = _end_state(s, a, velocity_frames, at_end=True)
    tb, cb, vb = _end_state(s, b, velocity_frames, at_end=False)
    dt = tb - ta
    forward = ca + va * dt
    backward = cb - vb * dt
    return 0.5 * (float(np.linalg.norm(forward - cb)) + float(np.linalg.norm(backward - ca)))


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
        max_distance: the largest accepted :func:`join_cost`, metres.
        velocity_frames: sightings each end velocity is fitted to.

    Returns:
        The joins, sorted by the later track's first frame.
    """
    first, last = s.first, s.last
    order = np.argsort(first, kind="stable")
    firsts = first[order]
    pairs: list[tuple[int, int, float]] = []
    for a in np.flatnonzero(eligible):
        lo = np.searchsorted(firsts, last[a] + 1, side="left")
        hi = np.searchsorted(firsts, last[a] + 1 + max_gap, side="right")
        for b in order[lo:hi]:
            if b == a or not eligible[b] or group[b] != group[a]:
                continue
            cost = join_cost(s, int(a), int(b), velocity_frames)
            if cost <= max_distance:
                pairs.append((int(a), int(b), cost))
    if not pairs:
        return []
    rows = sorted({p[0] for p in pairs})
    cols = sorted({p[1] for p in pairs})
    ri = {a: i for i, a in enumerate(rows)}
    ci = {b: j for j, b in enumerate(cols)}
    big = 1e6 * (1.0 + max_distance)
    cost = np.full((len(rows), len(cols)), big)
    for a, b, c in pairs:
        cost[ri[a], ci[b]] = c
    r, c = linear_sum_assignment(cost)
    joins = [
        Join(
            int(s.ids[rows[i]]),
            int(s.ids[cols[j]]),
            int(first[cols[j]] - last[rows[i]] - 1),
            float(cost[i, j]),
        )
        for i, j in zip(r.tolist(), c.tolist(), strict=True)
        if cost[i, j] < big
    ]
    id_first = dict(zip(s.ids.tolist(), first.tolist(), strict=True))
    return sorted(joins, key=lambda j: (id_first[j.later], j.later))


def chain_heads(ids: np.ndarray, joins: list[Join]) -> np.ndarray:
    """``(T,) int64``: for each id of ``ids``, the id of the earliest track of its chain of joins."""
    prev = {j.later: j.earlier for j in joins}
    out = np.empty(ids.size, np.int64)
    for k, i in enumerate(ids.tolist()):
        while i in prev:
            i = prev[i]
        out[k] = i
    return out

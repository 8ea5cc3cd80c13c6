"""A track's motion in the world frame: does it move over its life, and how fast at its ends."""

from __future__ import annotations

import numpy as np


def smoothed(centre: np.ndarray) -> np.ndarray:
    """``(n, 3)`` centres -> their median over each sighting and its two neighbours (one at the
    ends), damping single sightings where an occlusion pulled the centroid away."""
    n = centre.shape[0]
    if n < 3:
        return centre.copy()
    windows = np.stack([centre[:-2], centre[1:-1], centre[2:]], axis=0)
    mid = np.median(windows, axis=0)
    return np.concatenate([centre[:1], mid, centre[-1:]])


def excursion(centre: np.ndarray) -> float:
    """The farthest horizontal distance (metres) of a track's smoothed centre from where it started."""
    if centre.shape[0] < 2:
        return 0.0
    s = smoothed(centre)
    d = s[:, :2] - s[0, :2]
    return float(np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]).max())


def is_static(
    centre: np.ndarray, extent: np.ndarray, min_frames: int, distance: float, extent_share: float
) -> bool:
    """Whether a track stays put: seen in at least ``min_frames`` frames and its centre never strays
    more than ``distance + extent_share × median extent`` metres (see
    :class:`~dsnet_core.refine.params.TrackParams`).

    Args:
        centre: ``(n, 3) float64`` its centres per sighting, world frame, in time order.
        extent: ``(n,) float64`` its horizontal extent per sighting, metres.
    """
    if centre.shape[0] < max(min_frames, 1):
        return False
    return excursion(centre) <= distance + extent_share * float(np.median(extent))


def fit_velocity(time: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """``(3,)`` least-squares velocity (metres per second) of centres ``(n, 3)`` at times ``(n,)``;
    zero with fewer than two distinct times."""
    t = np.asarray(time, np.float64)
    if t.size < 2 or np.ptp(t) <= 0:
        return np.zeros(3)
    dt = t - t.mean()
    dc = centre - centre.mean(axis=0)
    return (dt[:, None] * dc).sum(axis=0) / float((dt * dt).sum())

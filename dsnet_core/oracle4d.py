"""Oracle 4D labelling for tests and benchmarks: ground-truth semantics and noisy ground-truth
centres instead of the network, then the real clustering → stitching (or tracking) path.

This isolates what the 4D machinery contributes: with perfect semantics and centres that only
carry regression noise, the stitched ids should give LSTQ close to 1, and the temporally
unified volumes can be compared with single-frame clustering + the tracking baseline on equal
terms.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from dsnet_core.labels import LabelMap
from dsnet_core.stitching import Stitcher, VolumeLabels
from dsnet_core.tracking import Tracker

Clusterer = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class CentreNoise:
    """Regression noise of predicted centres, metres: Gaussian, elongated along the sensor ray
    and growing with range (σ = base + per_metre · range; along the ray × ``ray_factor``)."""

    base: float = 0.03
    per_metre: float = 0.004
    ray_factor: float = 2.5


def box_centres(xyz: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Per point, the centre of its instance's axis-aligned tight box (the DS-Net target).

    Args:
        xyz: ``(N, 3)`` points, metres. ids: ``(N,) int`` instance keys (any integers).

    Returns:
        ``(N, 3) float64``.
    """
    uniq, inv = np.unique(ids, return_inverse=True)
    lo = np.full((uniq.size, 3), np.inf)
    hi = np.full((uniq.size, 3), -np.inf)
    np.minimum.at(lo, inv, xyz)
    np.maximum.at(hi, inv, xyz)
    return ((lo + hi) / 2)[inv]


def noisy(centres: np.ndarray, xyz: np.ndarray, rng: np.random.Generator, noise: CentreNoise) -> np.ndarray:
    """``centres`` ``(N, 3)`` plus noise shaped by each point's ray from the sensor at the origin."""
    r = np.linalg.norm(xyz, axis=1, keepdims=True)
    ray = xyz / np.maximum(r, 1e-6)
    sigma = noise.base + noise.per_metre * r
    iso = rng.normal(size=xyz.shape) * sigma
    along = (iso * ray).sum(1, keepdims=True)
    return centres + iso + along * (noise.ray_factor - 1.0) * ray


_OFFSETS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)])[14:]


def grid_components(centres: np.ndarray, cell: float = 0.3, min_size: int = 5) -> np.ndarray:
    """Connected components of centres on a grid: centres in the same or 26-adjacent cells of
    size ``cell`` metres are connected (linear time, unlike all pairs within a radius).

    Points of components smaller than ``min_size`` join the nearest large component (by
    centre), so regression outliers do not become tiny instances.

    Returns:
        ``(N,) int64`` ids ≥ 1, numbered by each component's first point.
    """
    n = centres.shape[0]
    if n == 0:
        return np.zeros(0, np.int64)
    ijk = np.floor(centres / cell).astype(np.int64)
    ijk -= ijk.min(0) - 1
    dims = ijk.max(0) + 2
    code = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    cells, point_cell = np.unique(code, return_inverse=True)
    cell_ijk = np.stack(np.unravel_index(cells, tuple(dims)), 1)
    rows, cols = [], []
    for off in _OFFSETS:  # 13 half-neighbourhood offsets: each adjacent pair once
        nb = cell_ijk + off
        nb_code = (nb[:, 0] * dims[1] + nb[:, 1]) * dims[2] + nb[:, 2]
        pos = np.searchsorted(cells, nb_code).clip(max=cells.size - 1)
        hit = cells[pos] == nb_code
        rows.append(np.flatnonzero(hit))
        cols.append(pos[hit])
    r, c = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(r.size), (r, c)), shape=(cells.size, cells.size))
    _, comp_of_cell = connected_components(graph, directed=False)
    comp = comp_of_cell[point_cell]
    sizes = np.bincount(comp)
    big = sizes[comp] >= min_size
    if big.any() and not big.all():
        _, nearest = cKDTree(centres[big]).query(centres[~big])
        comp[~big] = comp[big][nearest]
    uniq, first = np.unique(comp, return_index=True)
    rank = np.argsort(np.argsort(first))
    return rank[np.searchsorted(uniq, comp)].astype(np.int64) + 1


def _to_ref(xyz: np.ndarray, pose: np.ndarray, ref: np.ndarray) -> np.ndarray:
    m = np.linalg.solve(ref, pose)
    return xyz @ m[:3, :3].T + m[:3, 3]


def windows(n_frames: int, k: int, stride: int) -> list[list[int]]:
    """Windows of ``k`` frames with step ``stride``; the last one ends at the last frame."""
    if n_frames <= k:
        return [list(range(n_frames))]
    starts = list(range(0, n_frames - k + 1, stride))
    if starts[-1] + k < n_frames:
        starts.append(n_frames - k)
    return [list(range(s, s + k)) for s in starts]


def oracle_4d(
    scans: Sequence[np.ndarray],
    semantic: Sequence[np.ndarray],
    instance: Sequence[np.ndarray],
    poses: np.ndarray,
    label_map: LabelMap,
    k: int,
    rng: np.random.Generator,
    stride: int | None = None,
    noise: CentreNoise = CentreNoise(),
    cluster: Clusterer = grid_components,
) -> list[np.ndarray]:
    """Label a sequence with k-scan volumes: aligned scans → noisy volume-wide centres → cluster
    → stitch. Returns the per-frame ``(N_f,) uint32`` labels.

    Args:
        scans: per frame ``(N_f, 3+)`` sensor-frame points. semantic: ``(N_f,)`` train ids.
        instance: ``(N_f,)`` ground-truth instance ids. poses: ``(F, 4, 4)`` LiDAR-frame poses.
        k: scans per volume; stride: step between volumes (default ``k - 1``: one shared frame).
    """
    thing_lut = label_map.is_thing()
    stitcher = Stitcher(label_map)
    out: dict[int, np.ndarray] = {}
    for w in windows(len(scans), k, stride or max(k - 1, 1)):
        ref = poses[w[-1]]
        xyz = np.concatenate([_to_ref(np.asarray(scans[f])[:, :3], poses[f], ref) for f in w])
        sem = np.concatenate([semantic[f] for f in w]).astype(np.int64)
        key = sem * (1 << 32) + np.concatenate([instance[f] for f in w]).astype(np.int64)
        thing = thing_lut[sem]
        raw = np.zeros(sem.size, np.int64)
        centres = noisy(box_centres(xyz[thing], key[thing]), xyz[thing], rng, noise)
        raw[thing] = cluster(centres)
        frame = np.concatenate([np.full(len(scans[f]), f) for f in w])
        index = np.concatenate([np.arange(len(scans[f])) for f in w])
        vol = VolumeLabels(np.asarray(w), frame, index, sem, raw, thing=thing)
        for ff in stitcher.add_volume(vol):
            out[ff.frame] = ff.label
    return [out[f] for f in range(len(scans))]


def oracle_tracking(
    scans: Sequence[np.ndarray],
    semantic: Sequence[np.ndarray],
    instance: Sequence[np.ndarray],
    poses: np.ndarray,
    label_map: LabelMap,
    rng: np.random.Generator,
    noise: CentreNoise = CentreNoise(),
    cluster: Clusterer = grid_components,
    **tracker_kwargs,
) -> list[np.ndarray]:
    """The baseline: single-scan noisy centres → cluster → :class:`Tracker`; per-frame labels."""
    thing_lut = label_map.is_thing()
    tracker = Tracker(label_map, **tracker_kwargs)
    out = []
    for f, scan in enumerate(scans):
        xyz = np.asarray(scan)[:, :3].astype(np.float64)
        sem = np.asarray(semantic[f], dtype=np.int64)
        key = sem * (1 << 32) + np.asarray(instance[f], dtype=np.int64)
        thing = thing_lut[sem]
        raw = np.zeros(sem.size, np.int64)
        raw[thing] = cluster(noisy(box_centres(xyz[thing], key[thing]), xyz[thing], rng, noise))
        out.append(tracker.add_frame(xyz, sem, raw, poses[f], thing=thing))
    return out

"""Instance clustering of the thing points of one scan/volume: dynamic shifting and heuristics.

Every clusterer takes the thing points' positions, their regressed centres (``xyz + offset``)
and, when the network gives them, their 32-d instance features, and returns instance ids
``1..K`` (0 = unassigned). The heuristics (mean shift, DBSCAN, HDBSCAN, BFS) run on the
regressed centres, as in the DS-Net ablation. A clusterer is chosen by a pydantic config (a
discriminated union on ``kind``) through :func:`get_clusterer`; algorithms never see the config.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

import numpy as np
import torch
from scipy.spatial import cKDTree

from dsnet_core.instance.clustering_config import (  # noqa: F401  (re-exported: configs live beside the algorithms' registry)
    BFSConfig,
    ClustererConfig,
    DBSCANConfig,
    DynamicShiftConfig,
    HDBSCANConfig,
    MeanShiftConfig,
)
from dsnet_core.instance.components import dbscan, radius_components
from dsnet_core.instance.fps import sample_with_nearest
from dsnet_core.instance.meanshift import cluster_seeds, mean_shift
from dsnet_core.instance.shifting import DynamicShift


class Clusterer(Protocol):
    def cluster(self, xyz: np.ndarray, centres: np.ndarray, features: np.ndarray | None) -> np.ndarray:
        """Instance ids of the thing points.

        Args:
            xyz: float32 (M, 3) thing point positions, metres.
            centres: float32 (M, 3) regressed instance centres, metres.
            features: float32/float16 (M, 32) instance features, or None.

        Returns:
            int64 (M,) ids, 1..K, 0 = unassigned.
        """
        ...


def _ranked_ids(labels: np.ndarray) -> np.ndarray:
    """Relabel non-negative cluster labels to ids 1..K by decreasing size (ties: lower label); -1 → 0."""
    ids = np.zeros(labels.shape[0], dtype=np.int64)
    valid = labels >= 0
    if not valid.any():
        return ids
    uniq, inverse, counts = np.unique(labels[valid], return_inverse=True, return_counts=True)
    rank = np.empty(uniq.size, dtype=np.int64)
    rank[np.lexsort((uniq, -counts))] = np.arange(1, uniq.size + 1)
    ids[valid] = rank[inverse]
    return ids


def _nearest_fill(xyz: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Give unassigned points (id 0) the id of their nearest assigned point in ``xyz``."""
    missing = ids == 0
    if not missing.any() or missing.all():
        return ids
    _, nn = cKDTree(xyz[~missing]).query(xyz[missing], k=1)
    out = ids.copy()
    out[missing] = ids[~missing][nn]
    return out


class ShiftOutput(NamedTuple):
    """ids int64 (M,) 1..K; seeds int64 (M',) indices of the seeds; converged float32 (M', 3) metres."""

    ids: np.ndarray
    seeds: np.ndarray
    converged: np.ndarray


class DynamicShiftClusterer:
    """DS-Net: FPS seeds, dynamic shifting, mean shift of the converged seeds, nearest-seed ids."""

    def __init__(
        self,
        module: DynamicShift,
        n_seeds: int = 10_000,
        final_bandwidth: float = 0.65,
        device: str = "cpu",
    ) -> None:
        self.module = module.to(device).eval()
        self.n_seeds = n_seeds
        self.final_bandwidth = final_bandwidth
        self.device = device

    def _converge(self, seeds: np.ndarray, centres: np.ndarray, features: np.ndarray) -> np.ndarray:
        x = torch.from_numpy(np.ascontiguousarray(centres[seeds], dtype=np.float32)).to(self.device)
        f = torch.from_numpy(np.ascontiguousarray(features[seeds])).to(self.device)
        with torch.no_grad():
            return self.module(x, f).positions[-1].cpu().numpy()

    def run(self, xyz: np.ndarray, centres: np.ndarray, features: np.ndarray) -> ShiftOutput:
        """The whole DS-Net instance step, keeping the seeds for inspection (the ``shift`` stage).

        Every point takes the id of its nearest seed (in ``xyz``), which the sampling itself finds.

        Args:
            xyz: float32 (M, 3) thing point positions, metres.
            centres: float32 (M, 3) regressed centres, metres.
            features: float32/float16 (M, D) instance features.
        """
        m = xyz.shape[0]
        if m == 0:
            return ShiftOutput(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3), np.float32))
        if m == 1:  # batch norm cannot run on one seed; one point is one instance
            return ShiftOutput(np.ones(1, np.int64), np.zeros(1, np.int64), centres.astype(np.float32))
        seeds, nearest = sample_with_nearest(xyz, self.n_seeds)
        converged = self._converge(seeds, centres, features)
        seed_ids = cluster_seeds(converged, self.final_bandwidth)
        return ShiftOutput(seed_ids[nearest], seeds, converged)

    def cluster(self, xyz: np.ndarray, centres: np.ndarray, features: np.ndarray | None) -> np.ndarray:
        if features is None:
            raise ValueError("dynamic shifting needs the per-point instance features (got None)")
        return self.run(xyz, centres, features).ids


class MeanShiftClusterer:
    """Flat-kernel mean shift with bin seeding on the regressed centres (fixed bandwidth)."""

    def __init__(self, bandwidth: float = 1.2) -> None:
        self.bandwidth = bandwidth

    def cluster(self, xyz: np.ndarray, centres: np.ndarray, features: np.ndarray | None) -> np.ndarray:
        if centres.shape[0] == 0:
            return np.zeros(0, dtype=np.int64)
        labels, _ = mean_shift(centres, self.bandwidth)
        return labels + 1


class DBSCANClusterer:
    """DBSCAN on the regressed centres (:func:`dsnet_core.instance.components.dbscan`, without neighbour
    lists: scikit-learn's runs out of memory on dense regressed centres). Noise points take their
    nearest clustered point's id (in ``xyz``) unless ``assign_noise`` is off (then they stay 0)."""

    def __init__(self, eps: float = 0.4, min_samples: int = 10, assign_noise: bool = True) -> None:
        self.eps, self.min_samples, self.assign_noise = eps, min_samples, assign_noise

    def cluster(self, xyz: np.ndarray, centres: np.ndarray, features: np.ndarray | None) -> np.ndarray:
        if centres.shape[0] == 0:
            return np.zeros(0, dtype=np.int64)
        labels = dbscan(centres, self.eps, self.min_samples)
        ids = _ranked_ids(labels)
        return _nearest_fill(xyz, ids) if self.assign_noise else ids


class HDBSCANClusterer:
    """HDBSCAN (scikit-learn) on the regressed centres; noise handled as in :class:`DBSCANClusterer`."""

    def __init__(self, min_cluster_size: int = 20, assign_noise: bool = True) -> None:
        self.min_cluster_size, self.assign_noise = min_cluster_size, assign_noise

    def cluster(self, xyz: np.ndarray, centres: np.ndarray, features: np.ndarray | None) -> np.ndarray:
        from sklearn.cluster import HDBSCAN

        if centres.shape[0] < 2:
            return np.ones(centres.shape[0], dtype=np.int64)
        hdb = HDBSCAN(min_cluster_size=self.min_cluster_size, allow_single_cluster=True, copy=True)
        ids = _ranked_ids(hdb.fit(centres.astype(np.float64)).labels_)
        return _nearest_fill(xyz, ids) if self.assign_noise else ids


class BFSClusterer:
    """Connected components of the graph linking regressed centres closer than ``radius``;
    components smaller than ``min_size`` are treated as noise (nearest fill or 0)."""

    def __init__(self, radius: float = 0.3, min_size: int = 5, assign_noise: bool = True) -> None:
        self.radius, self.min_size, self.assign_noise = radius, min_size, assign_noise

    def cluster(self, xyz: np.ndarray, centres: np.ndarray, features: np.ndarray | None) -> np.ndarray:
        m = centres.shape[0]
        if m == 0:
            return np.zeros(0, dtype=np.int64)
        labels = radius_components(centres, self.radius)
        sizes = np.bincount(labels)
        labels = np.where(sizes[labels] >= self.min_size, labels, -1)
        ids = _ranked_ids(labels)
        return _nearest_fill(xyz, ids) if self.assign_noise else ids


CLUSTERERS: dict[str, type] = {
    "dynamic_shift": DynamicShiftClusterer,
    "meanshift": MeanShiftClusterer,
    "dbscan": DBSCANClusterer,
    "hdbscan": HDBSCANClusterer,
    "bfs": BFSClusterer,
}


def build_shift_module(config: DynamicShiftConfig, state_dict: dict | None = None) -> DynamicShift:
    """The :class:`DynamicShift` module a config describes, with ``state_dict`` loaded if given."""
    module = DynamicShift(config.bandwidths, config.iterations, config.feature_dim, config.kernel)
    if state_dict is not None:
        module.load_state_dict(state_dict)
    return module


def get_clusterer(config: ClustererConfig, shift_weights: dict | DynamicShift | None = None) -> Clusterer:
    """Turn a clusterer config into a clusterer.

    Args:
        config: one of the ``*Config`` models (``kind`` picks the class in ``CLUSTERERS``).
        shift_weights: for ``dynamic_shift``, the shifting MLPs' state dict or a ready module
            (required: untrained weights are not a clusterer). Ignored by the heuristics.
    """
    params = config.model_dump(exclude={"kind"})
    if isinstance(config, DynamicShiftConfig):
        if shift_weights is None:
            raise ValueError("dynamic_shift needs trained shifting weights (a state dict or a DynamicShift)")
        module = shift_weights
        if not isinstance(module, DynamicShift):
            module = build_shift_module(config, shift_weights)
        module.kernel = config.kernel
        return DynamicShiftClusterer(module, config.n_seeds, config.final_bandwidth, config.device)
    return CLUSTERERS[config.kind](**params)

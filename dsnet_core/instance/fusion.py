"""Consensus-driven fusion of semantics and class-agnostic instances (DS-Net majority voting).

Every point of an instance takes the most frequent predicted thing class inside the instance
(ties: the smaller class id, as ``scipy.stats.mode`` in the reference). Stuff points keep their
class and instance 0; thing points the clusterer left unassigned keep their class and instance 0.
The per-instance table carries what a review queue needs.

The per-instance sums (votes, probabilities, positions) and boxes come from one pass over the
instance points in point order (:func:`_group_stats`): the float64 sums add the same terms in the
same order as ``np.add.at`` did, so the table is bit-identical to that formulation.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np


@dataclass(frozen=True)
class InstanceTable:
    """One row per instance of a scan/volume (K rows, sorted by id).

    Attributes:
        id: int64 (K,) instance ids as in the fused labels.
        class_id: int64 (K,) winning thing class (train id).
        n_points: int64 (K,) points in the instance.
        agreement: float32 (K,) fraction of the instance's points predicted as ``class_id``.
        confidence: float32 (K,) mean predicted probability of ``class_id`` over the instance's
            points (NaN without probabilities).
        centroid: float32 (K, 3) mean position, metres.
        box_min: float32 (K, 3) axis-aligned box minimum corner, metres.
        box_max: float32 (K, 3) axis-aligned box maximum corner, metres.
    """

    id: np.ndarray
    class_id: np.ndarray
    n_points: np.ndarray
    agreement: np.ndarray
    confidence: np.ndarray
    centroid: np.ndarray
    box_min: np.ndarray
    box_max: np.ndarray

    def __len__(self) -> int:
        return int(self.id.shape[0])


@dataclass(frozen=True)
class FusedLabels:
    """Panoptic labels of a scan/volume.

    Attributes:
        semantic: int64 (N,) train ids after voting.
        instance: int64 (N,) instance ids, 0 for stuff and unassigned points.
        instances: the per-instance table.
    """

    semantic: np.ndarray
    instance: np.ndarray
    instances: InstanceTable


def fuse(
    xyz: np.ndarray,
    semantic: np.ndarray,
    instance: np.ndarray,
    thing_classes: Sequence[int],
    probabilities: np.ndarray | None = None,
) -> FusedLabels:
    """Majority-vote each instance's class and build the instance table.

    Args:
        xyz: float32 (N, 3) point positions, metres.
        semantic: int (N,) predicted train ids.
        instance: int (N,) clusterer ids (1..K on thing points, 0 elsewhere). Ids on points
            predicted as stuff are dropped (set to 0).
        thing_classes: train ids of the thing classes (SemanticKITTI: 1..8).
        probabilities: optional (N, C) class probabilities, column = train id: float16/float32,
            or uint8 quantised as in the infer stage (p = q / 255).

    Returns:
        :class:`FusedLabels`.
    """
    n = semantic.shape[0]
    if xyz.shape != (n, 3) or instance.shape != (n,):
        raise ValueError(f"xyz {xyz.shape}, semantic {semantic.shape}, instance {instance.shape} disagree")
    if probabilities is not None and probabilities.shape[0] != n:
        raise ValueError(f"probabilities {probabilities.shape} do not match {n} points")
    sem = semantic.astype(np.int64)
    things = np.asarray(thing_classes, dtype=np.int64)
    lut = np.zeros(max(int(sem.max(initial=0)), int(things.max(initial=0))) + 1, bool)
    lut[things[things >= 0]] = True
    is_thing = lut[np.maximum(sem, 0)] & (sem >= 0)
    inst = np.where(is_thing, instance.astype(np.int64), 0)
    members = np.flatnonzero(inst > 0)
    ids, inverse = _dense_ids(inst[members])
    k = ids.size
    n_cls = int(sem.max(initial=0)) + 1
    sem_m = sem[members]
    votes = np.bincount(inverse * n_cls + sem_m, minlength=k * n_cls).reshape(k, n_cls)
    winner = votes.argmax(axis=1)  # first maximum = smallest class id on ties
    n_points = votes.sum(axis=1)
    agreement = votes[np.arange(k), winner] / np.maximum(n_points, 1)
    out_sem = sem.copy()
    out_sem[members] = winner[inverse]
    if probabilities is not None:
        p = probabilities[members, winner[inverse]].astype(np.float64)
        if probabilities.dtype == np.uint8:
            p /= 255.0
    else:
        p = np.zeros(0)
    sums, box_min, box_max = _group_stats(inverse, np.ascontiguousarray(xyz[members], np.float64), p, k)
    centroid = sums[:, :3] / np.maximum(n_points, 1)[:, None]
    confidence = sums[:, 3] / np.maximum(n_points, 1) if probabilities is not None else np.full(k, np.nan)
    table = InstanceTable(
        id=ids.astype(np.int64),
        class_id=winner.astype(np.int64),
        n_points=n_points,
        agreement=agreement.astype(np.float32),
        confidence=confidence.astype(np.float32),
        centroid=centroid.astype(np.float32),
        box_min=box_min.astype(np.float32),
        box_max=box_max.astype(np.float32),
    )
    return FusedLabels(out_sem, inst, table)


def _dense_ids(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(values, return_inverse=True)`` for positive ids: by a lookup table where the
    largest id is small (the clusterers' 1..K), else by sorting."""
    top = int(values.max(initial=0))
    if top > 4 * values.size + 1024:
        ids, inverse = np.unique(values, return_inverse=True)
        return ids, inverse.reshape(-1)
    present = np.bincount(values, minlength=top + 1) > 0
    ids = np.flatnonzero(present)
    remap = np.cumsum(present) - 1
    return ids, remap[values]


@numba.njit(cache=True)
def _group_stats(inverse, pts, p, k):  # pragma: no cover - compiled
    """Per group: ``sums (k, 4)`` (x, y, z, p summed in point order; p only where given) and the
    boxes ``lo, hi (k, 3)`` of the float64 positions ``pts (n, 3)``."""
    sums = np.zeros((k, 4))
    lo = np.full((k, 3), np.inf)
    hi = np.full((k, 3), -np.inf)
    with_p = p.shape[0] == inverse.shape[0]
    for i in range(inverse.shape[0]):
        g = inverse[i]
        for a in range(3):
            v = pts[i, a]
            sums[g, a] += v
            if v <= lo[g, a]:  # ties (+0.0, -0.0) take the new value, as np.minimum.at does
                lo[g, a] = v
            if v >= hi[g, a]:
                hi[g, a] = v
        if with_p:
            sums[g, 3] += p[i]
    return sums, lo, hi

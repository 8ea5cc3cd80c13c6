"""Consensus-driven fusion of semantics and class-agnostic instances (DS-Net majority voting).

Every point of an instance takes the most frequent predicted thing class inside the instance
(ties: the smaller class id, as ``scipy.stats.mode`` in the reference). Stuff points keep their
class and instance 0; thing points the clusterer left unassigned keep their class and instance 0.
The per-instance table carries what a review queue needs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

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
    is_thing = np.isin(sem, np.asarray(thing_classes, dtype=np.int64))
    inst = np.where(is_thing, instance.astype(np.int64), 0)
    members = np.flatnonzero(inst > 0)
    ids, inverse = np.unique(inst[members], return_inverse=True)
    k = ids.size
    n_cls = int(sem.max(initial=0)) + 1
    votes = np.zeros((k, n_cls), dtype=np.int64)
    np.add.at(votes, (inverse, sem[members]), 1)
    winner = votes.argmax(axis=1)  # first maximum = smallest class id on ties
    n_points = votes.sum(axis=1)
    agreement = votes[np.arange(k), winner] / np.maximum(n_points, 1)
    out_sem = sem.copy()
    out_sem[members] = winner[inverse]
    if probabilities is not None:
        p = probabilities[members, winner[inverse]].astype(np.float64)
        if probabilities.dtype == np.uint8:
            p /= 255.0
        confidence = np.zeros(k)
        np.add.at(confidence, inverse, p)
        confidence /= np.maximum(n_points, 1)
    else:
        confidence = np.full(k, np.nan)
    pts = xyz[members].astype(np.float64)
    centroid = np.zeros((k, 3))
    np.add.at(centroid, inverse, pts)
    centroid /= np.maximum(n_points, 1)[:, None]
    box_min = np.full((k, 3), np.inf)
    box_max = np.full((k, 3), -np.inf)
    np.minimum.at(box_min, inverse, pts)
    np.maximum.at(box_max, inverse, pts)
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

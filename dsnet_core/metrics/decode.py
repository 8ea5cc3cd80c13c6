"""Class definitions and label decoders: whole labels -> (train class, instance id).

Raw SemanticKITTI ids missing from ``learning_map`` (any value 0..65535) decode to class 0 and so
are ignored, in both modes. The reference evaluator does the same for ids below
``max(learning_map) + 100`` (= 359) and crashes with an IndexError above; we never crash.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from dsnet_core.labels import LabelMap

from .cells import Cells, count_pairs


@dataclass(frozen=True)
class ClassSpec:
    """The train classes a benchmark scores.

    Attributes:
        names: class name per train id (index 0 is the ignore class).
        things: train ids of thing classes.
        stuff: train ids of stuff classes.
        ignore: ignored train ids (ground-truth points of these classes are not scored).
    """

    names: tuple[str, ...]
    things: tuple[int, ...]
    stuff: tuple[int, ...]
    ignore: tuple[int, ...] = (0,)

    @property
    def n_classes(self) -> int:
        return len(self.names)

    @property
    def include(self) -> np.ndarray:
        """``(C',) int64`` the scored classes, ascending (every class not ignored)."""
        return np.array([c for c in range(self.n_classes) if c not in self.ignore], dtype=np.int64)

    def mask(self, ids: tuple[int, ...] | np.ndarray) -> np.ndarray:
        """``(C,) bool`` True at ``ids``."""
        m = np.zeros(self.n_classes, dtype=bool)
        m[np.asarray(ids, dtype=np.int64)] = True
        return m

    @classmethod
    def from_label_map(cls, label_map: LabelMap, ignore: tuple[int, ...] = (0,)) -> ClassSpec:
        """Classes of a label map; ``ignore`` lists ignored train ids (``learning_ignore``)."""
        ign = tuple(sorted(set(ignore)))
        things = tuple(c for c in label_map.things if c not in ign)
        stuff = tuple(c for c in label_map.stuff if c not in ign)
        return cls(label_map.class_names, things, stuff, ign)


class LabelDecoder(Protocol):
    """Turns whole labels into classes and instance ids."""

    def classes(self, labels: np.ndarray) -> np.ndarray:
        """``(K,) uint64`` labels -> ``(K,) int64`` train classes."""
        ...

    def ids(self, labels: np.ndarray) -> np.ndarray:
        """``(K,) uint64`` labels -> ``(K,) int64`` instance ids (0 = none) for tracking metrics."""
        ...


class KittiDecoder:
    """SemanticKITTI raw labels: class = ``learning_map[v & 0xFFFF]``, id = ``v >> 16``."""

    def __init__(self, label_map: LabelMap) -> None:
        self.lut = label_map.lut(1 << 16, fill=0).astype(np.int64)

    def classes(self, labels: np.ndarray) -> np.ndarray:
        return self.lut[(labels & np.uint64(0xFFFF)).astype(np.int64)]

    def ids(self, labels: np.ndarray) -> np.ndarray:
        return (labels >> np.uint64(16)).astype(np.int64)


class TrainDecoder:
    """Labels built from train ids as ``class | inst << 16`` (see :func:`train_labels`)."""

    def classes(self, labels: np.ndarray) -> np.ndarray:
        return (labels & np.uint64(0xFFFF)).astype(np.int64)

    def ids(self, labels: np.ndarray) -> np.ndarray:
        return (labels >> np.uint64(16)).astype(np.int64)


def train_labels(sem: np.ndarray, inst: np.ndarray, n_classes: int, name: str) -> np.ndarray:
    """Pack train classes ``(N,) int`` and instance ids ``(N,) int < 2¹⁶`` into ``(N,) uint32`` labels."""
    sem = np.asarray(sem)
    inst = np.asarray(inst)
    if sem.shape != inst.shape or sem.ndim != 1:
        raise ValueError(f"{name}: semantic and instance arrays must be (N,) of equal length")
    if sem.size:
        if sem.min() < 0 or sem.max() >= n_classes:
            raise ValueError(f"{name}: semantic train ids must lie in [0, {n_classes}), got {sem.max()}")
        if inst.min() < 0 or inst.max() > 0xFFFF:
            raise ValueError(f"{name}: instance ids must lie in [0, 65535]")
    return sem.astype(np.uint32) | (inst.astype(np.uint32) << np.uint32(16))


def make_cells(
    gt: np.ndarray, pred: np.ndarray, gt_decoder: LabelDecoder, pred_decoder: LabelDecoder
) -> Cells:
    """Count a frame's (gt, pred) label pairs and decode their classes and ids."""
    g, p, n = count_pairs(gt, pred)
    return Cells(
        gt=g,
        pred=p,
        count=n,
        gt_cls=gt_decoder.classes(g),
        pred_cls=pred_decoder.classes(p),
        gt_id=gt_decoder.ids(g),
        pred_id=pred_decoder.ids(p),
        n_points=int(np.asarray(gt).shape[0]),
    )

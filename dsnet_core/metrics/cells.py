"""Joint counting of (ground-truth label, predicted label) pairs: the one pass over points.

Every metric in this package is computed from a frame's *cells*: the distinct
(ground-truth label, predicted label) pairs of its points and how many points carry each pair.
A frame of 120 000 points has a few hundred cells, so after one sort of the points everything
else works on small arrays. Labels are whole uint32 values (SemanticKITTI ``sem | inst << 16``,
Panoptic nuScenes ``class * 1000 + inst``); a label decoder turns them into classes and ids.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Cells:
    """The distinct (gt, pred) label pairs of one frame, sorted by (gt label, pred label).

    Attributes:
        gt: ``(K,) uint64`` whole ground-truth label of each cell.
        pred: ``(K,) uint64`` whole predicted label of each cell.
        count: ``(K,) int64`` points in each cell (> 0).
        gt_cls: ``(K,) int64`` ground-truth train class of each cell.
        pred_cls: ``(K,) int64`` predicted train class of each cell.
        gt_id: ``(K,) int64`` ground-truth instance id (0 = none) used by the tracking metrics.
        pred_id: ``(K,) int64`` predicted instance id (0 = none) used by the tracking metrics.
        n_points: points of the frame.
    """

    gt: np.ndarray
    pred: np.ndarray
    count: np.ndarray
    gt_cls: np.ndarray
    pred_cls: np.ndarray
    gt_id: np.ndarray
    pred_id: np.ndarray
    n_points: int

    def select(self, mask: np.ndarray) -> Cells:
        """The cells where ``mask`` (``(K,) bool``) is True, order kept."""
        return Cells(
            self.gt[mask],
            self.pred[mask],
            self.count[mask],
            self.gt_cls[mask],
            self.pred_cls[mask],
            self.gt_id[mask],
            self.pred_id[mask],
            int(self.count[mask].sum()),
        )


def count_pairs(gt: np.ndarray, pred: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distinct (gt, pred) pairs of two uint32 label arrays and their point counts.

    Args:
        gt: ``(N,)`` ground-truth labels, values < 2³².
        pred: ``(N,)`` predicted labels, values < 2³².

    Returns:
        ``(gt_labels, pred_labels, counts)``: ``(K,) uint64``, ``(K,) uint64``, ``(K,) int64``,
        sorted by gt label then pred label.
    """
    gt = np.asarray(gt)
    pred = np.asarray(pred)
    if gt.shape != pred.shape or gt.ndim != 1:
        raise ValueError(f"gt and pred must be (N,) arrays of equal length, got {gt.shape} and {pred.shape}")
    if gt.size == 0:
        empty = np.zeros(0, dtype=np.uint64)
        return empty, empty.copy(), np.zeros(0, dtype=np.int64)
    key = (gt.astype(np.uint64) << np.uint64(32)) | pred.astype(np.uint64)
    key.sort()
    starts = np.flatnonzero(np.concatenate(([True], key[1:] != key[:-1])))
    uniq = key[starts]
    counts = np.diff(np.append(starts, key.size)).astype(np.int64)
    return uniq >> np.uint64(32), uniq & np.uint64(0xFFFFFFFF), counts


def check_labels(label: np.ndarray, name: str) -> np.ndarray:
    """Return ``label`` as a 1-D integer array with values in [0, 2³²); raise ``ValueError`` otherwise."""
    arr = np.asarray(label)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be a 1-D array, got shape {arr.shape}")
    if arr.dtype.kind not in "iu":
        raise ValueError(f"{name} must hold integers, got dtype {arr.dtype}")
    if arr.size and arr.dtype.kind == "i" and arr.min() < 0:
        raise ValueError(f"{name} holds negative values")
    if arr.size and arr.dtype.itemsize > 4 and arr.max() > 0xFFFFFFFF:
        raise ValueError(f"{name} holds values ≥ 2^32")
    return arr


class CountTable:
    """A streaming sum of integer counts keyed by uint64 (memory: distinct keys, not additions).

    Additions are buffered and compacted (sort + segment sum) when the buffer grows, so adding
    a frame costs one ``np.concatenate`` and merging two tables is exact.
    """

    def __init__(self, compact_every: int = 1 << 13) -> None:
        self._keys = np.zeros(0, dtype=np.uint64)
        self._vals = np.zeros(0, dtype=np.int64)
        self._pending: list[tuple[np.ndarray, np.ndarray]] = []
        self._n_pending = 0
        self._compact_every = compact_every

    def add(self, keys: np.ndarray, values: np.ndarray) -> None:
        """Add ``values`` (``(M,) int``) at ``keys`` (``(M,) uint64``); repeated keys are summed."""
        if len(keys) == 0:
            return
        self._pending.append((np.asarray(keys, dtype=np.uint64), np.asarray(values, dtype=np.int64)))
        self._n_pending += len(keys)
        if self._n_pending > max(self._compact_every, self._keys.size):
            self.compact()

    def merge(self, other: CountTable) -> None:
        """Add every entry of ``other`` into this table."""
        keys, vals = other.items()
        self.add(keys, vals)

    def state(self, key: str) -> dict[str, np.ndarray]:
        """The table as ``{key}_keys`` / ``{key}_vals`` arrays (copies)."""
        keys, vals = self.items()
        return {f"{key}_keys": keys.copy(), f"{key}_vals": vals.copy()}

    @classmethod
    def from_state(cls, state: dict[str, np.ndarray], key: str) -> CountTable:
        """The table :meth:`state` saved under ``key``."""
        table = cls()
        table.add(state[f"{key}_keys"], state[f"{key}_vals"])
        return table

    def items(self) -> tuple[np.ndarray, np.ndarray]:
        """``(keys (K,) uint64 sorted, values (K,) int64)``."""
        self.compact()
        return self._keys, self._vals

    def __len__(self) -> int:
        self.compact()
        return int(self._keys.size)

    def compact(self) -> None:
        """Fold buffered additions into the sorted table (memory: distinct keys only)."""
        if not self._pending:
            return
        keys = np.concatenate([self._keys, *(k for k, _ in self._pending)])
        vals = np.concatenate([self._vals, *(v for _, v in self._pending)])
        self._pending.clear()
        self._n_pending = 0
        order = np.argsort(keys, kind="stable")
        keys, vals = keys[order], vals[order]
        if keys.size:
            starts = np.flatnonzero(np.concatenate(([True], keys[1:] != keys[:-1])))
            self._keys = keys[starts]
            self._vals = np.add.reduceat(vals, starts)
        else:
            self._keys, self._vals = keys, vals


class ExactSum:
    """A float sum that is exact until read (Shewchuk partials, as ``math.fsum``).

    The value is the correctly rounded sum of everything added, so it does not depend on the
    order of additions: merged accumulators give bit-identical results to one pass.
    """

    __slots__ = ("_partials",)

    def __init__(self) -> None:
        self._partials: list[float] = []

    def add(self, x: float) -> None:
        x = float(x)
        partials = self._partials
        i = 0
        for y in partials:
            if abs(x) < abs(y):
                x, y = y, x
            hi = x + y
            lo = y - (hi - x)
            if lo:
                partials[i] = lo
                i += 1
            x = hi
        partials[i:] = [x]

    def merge(self, other: ExactSum) -> None:
        for p in other._partials:
            self.add(p)

    @property
    def partials(self) -> tuple[float, ...]:
        """The exact state: non-overlapping partials whose exact sum is everything added."""
        return tuple(self._partials)

    @classmethod
    def from_partials(cls, partials) -> ExactSum:
        """A sum holding ``partials`` (from :attr:`partials`), bit for bit."""
        s = cls()
        s._partials = [float(x) for x in partials]
        return s

    @property
    def value(self) -> float:
        return math.fsum(self._partials)


def sums_state(sums: list[ExactSum], key: str) -> dict[str, np.ndarray]:
    """Exact sums as two arrays: ``key`` (every partial, float64) and ``{key}_len`` (int64 counts)."""
    parts = [s.partials for s in sums]
    return {
        key: np.array([x for ps in parts for x in ps], dtype=np.float64),
        f"{key}_len": np.array([len(ps) for ps in parts], dtype=np.int64),
    }


def sums_from_state(state: dict[str, np.ndarray], key: str) -> list[ExactSum]:
    """Inverse of :func:`sums_state`."""
    flat = np.asarray(state[key], dtype=np.float64)
    ends = np.cumsum(np.asarray(state[f"{key}_len"], dtype=np.int64))
    starts = np.concatenate(([0], ends[:-1])).astype(np.int64)
    return [ExactSum.from_partials(flat[a:b]) for a, b in zip(starts, ends, strict=True)]

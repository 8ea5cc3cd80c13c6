"""Realistic corruption of a ground-truth semantic prior, so that D-PLS's instance network learns
to use an imperfect prior (a real segmenter's output) instead of trusting it blindly.

A real segmenter's errors are not independent per point. Two kinds dominate and are modelled:

- **class confusions of whole segments**: an object or a patch of ground predicted as a class it
  is confused with (truck as car, parking as road). Segments are the thing instances and, for
  stuff, one patch per class and ``cell`` × ``cell`` metres of ground plan; each segment of true
  class ``c`` keeps ``c`` with probability ``C[c, c]`` of the confusion matrix, else takes a class
  drawn from the rest of row ``c``. The expected IoU of this step is :func:`expected_iou`.
- **blob errors at boundaries**: the prediction bleeds across a boundary between two classes
  (the base of a car labelled road, a pole's foot labelled sidewalk). Seeds are points with another
  class within ``boundary`` metres; every point of the seed's class within a random radius
  takes that other class.

The confusion matrix is measured (:func:`confusion_matrix` of a model's predictions on held-out
data) or made up (:func:`uniform_confusion`); :func:`scale_confusion` makes it milder or harsher.
Seeded: the same ``rng`` state gives the same corruption.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class PriorNoise:
    """How a ground-truth prior is corrupted.

    Attributes:
        confusion: float ``(C, C)`` row-stochastic: ``[true, predicted]`` probabilities.
        cell: stuff segments' size in the ground plane, metres.
        blobs_per_100k: mean number of boundary blobs per 100 000 points (Poisson).
        blob_radius: (min, max) blob radius, metres (uniform).
        boundary: distance within which a point with another class makes a seed a boundary point, m.
        strength: (min, max) of a per-sample :func:`scale_confusion` factor (uniform): samples from
            clean (0) to harsher than measured (> 1).
    """

    confusion: np.ndarray
    cell: float = 4.0
    blobs_per_100k: float = 20.0
    blob_radius: tuple[float, float] = (0.3, 1.2)
    boundary: float = 0.5
    strength: tuple[float, float] = (1.0, 1.0)


def uniform_confusion(num_classes: int, accuracy: float) -> np.ndarray:
    """A ``(C, C)`` confusion matrix: ``accuracy`` on the diagonal, the rest spread evenly over the
    other classes 1..C-1 (class 0, ignore, is never predicted; its row is the identity)."""
    c = num_classes
    out = np.full((c, c), (1.0 - accuracy) / max(c - 2, 1))
    out[:, 0] = 0.0
    np.fill_diagonal(out, accuracy)
    out[0] = 0.0
    out[0, 0] = 1.0
    return out


def confusion_matrix(true: np.ndarray, pred: np.ndarray, num_classes: int) -> np.ndarray:
    """Row-normalised ``(C, C)`` confusion of predicted train ids against true ones (rows of classes
    never seen are the identity; class 0 rows are the identity)."""
    counts = np.bincount(
        np.asarray(true, np.int64) * num_classes + np.asarray(pred, np.int64), minlength=num_classes**2
    ).reshape(num_classes, num_classes)
    return normalise_confusion(counts)


def normalise_confusion(counts: np.ndarray) -> np.ndarray:
    """Counts ``(C, C)`` → row-stochastic probabilities (empty rows and row 0 → identity)."""
    counts = np.asarray(counts, np.float64)
    rows = counts.sum(1, keepdims=True)
    out = np.divide(counts, rows, out=np.zeros_like(counts), where=rows > 0)
    empty = rows[:, 0] == 0
    out[empty] = np.eye(len(counts))[empty]
    out[0] = np.eye(len(counts))[0]
    return out


def scale_confusion(confusion: np.ndarray, s: float) -> np.ndarray:
    """Off-diagonal mass times ``s`` (0 = no errors, 1 = as given, > 1 harsher; clipped so that each
    row keeps a non-negative diagonal)."""
    off = confusion * (1.0 - np.eye(len(confusion)))
    err = off.sum(1, keepdims=True)
    factor = np.minimum(s, np.divide(1.0, err, out=np.full_like(err, np.inf), where=err > 0))
    out = off * factor
    np.fill_diagonal(out, 1.0 - out.sum(1))
    return out


def expected_iou(confusion: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Per-class IoU that confusing ``counts[c]`` points of each class ``c`` by ``confusion`` gives in
    expectation, ``(C,)`` (NaN for classes without points or predictions)."""
    counts = np.asarray(counts, np.float64)
    tp = counts * np.diag(confusion)
    predicted = counts @ confusion
    union = counts + predicted - tp
    return np.divide(tp, union, out=np.full_like(tp, np.nan), where=union > 0)


def corrupt_prior(
    xyz: np.ndarray, sem: np.ndarray, inst: np.ndarray, noise: PriorNoise, rng: np.random.Generator
) -> np.ndarray:
    """A realistic wrong prediction made from ground truth.

    Args:
        xyz: float ``(N, 3)`` metres.
        sem: int ``(N,)`` true train ids (0 = unlabelled, kept).
        inst: int ``(N,)`` instance keys, 0 for stuff (distinct per thing instance).
        noise: the corruption model.
        rng: the random source.

    Returns:
        int64 ``(N,)`` corrupted train ids.
    """
    sem = np.asarray(sem, np.int64)
    lo, hi = noise.strength
    confusion = scale_confusion(noise.confusion, rng.uniform(lo, hi)) if hi > 0 else noise.confusion
    out = _swap_segments(xyz, sem, inst, confusion, noise.cell, rng)
    return _grow_blobs(xyz, sem, out, noise, rng)


def _swap_segments(xyz, sem, inst, confusion, cell, rng) -> np.ndarray:
    cells = np.floor(np.asarray(xyz)[:, :2] / cell).astype(np.int64)
    key = np.where(
        np.asarray(inst) > 0,
        -np.asarray(inst, np.int64) - 1,  # thing instances: one segment each
        (sem * 1_000_003 + cells[:, 0]) * 1_000_003 + cells[:, 1],
    )
    seg, first, inv = np.unique(key, return_index=True, return_inverse=True)
    seg_class = sem[first]
    keep = rng.random(seg.size) < confusion[seg_class, seg_class]
    new = seg_class.copy()
    for k in np.flatnonzero(~keep & (seg_class > 0)):
        row = confusion[seg_class[k]].copy()
        row[seg_class[k]] = 0.0
        total = row.sum()
        if total > 0:
            new[k] = rng.choice(row.size, p=row / total)
    return new[inv.ravel()]


def _grow_blobs(xyz, sem, out, noise: PriorNoise, rng) -> np.ndarray:
    n = sem.size
    n_blobs = rng.poisson(noise.blobs_per_100k * n / 1e5)
    if n_blobs == 0 or n < 2:
        return out
    tree = cKDTree(np.asarray(xyz, np.float64))
    candidates = rng.choice(n, size=min(n, 20 * n_blobs), replace=False)
    made = 0
    for seed in candidates:
        if made >= n_blobs:
            break
        near = np.asarray(tree.query_ball_point(xyz[seed], noise.boundary), np.int64)
        other = sem[near]
        other = other[(other != sem[seed]) & (other > 0)]
        if sem[seed] == 0 or other.size == 0:
            continue
        into = np.bincount(other).argmax()
        blob = np.asarray(tree.query_ball_point(xyz[seed], rng.uniform(*noise.blob_radius)), np.int64)
        blob = blob[sem[blob] == sem[seed]]
        out[blob] = into
        made += 1
    return out

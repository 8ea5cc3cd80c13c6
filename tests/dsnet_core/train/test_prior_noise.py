"""The realistic corruption of a ground-truth prior: segment swaps reach the confusion matrix's
expected IoU, blob errors sit at class boundaries and are spatially coherent (not per-point noise),
and everything is seeded."""

from __future__ import annotations

import numpy as np

from dsnet_core.train.prior_noise import (
    PriorNoise,
    confusion_matrix,
    corrupt_prior,
    expected_iou,
    scale_confusion,
    uniform_confusion,
)

C = 6


def _scene(rng: np.random.Generator, n_objects: int = 400):
    """Stuff classes 3..5 on a 200 m × 200 m plane in 10 m bands; thing classes 1, 2 as small clusters."""
    ground = rng.uniform(-100, 100, size=(60_000, 3)) * [1, 1, 0]
    sem_g = 3 + (np.floor(ground[:, 0] / 10).astype(int) % 3)
    centres = rng.uniform(-95, 95, size=(n_objects, 3)) * [1, 1, 0] + [0, 0, 1]
    pts = np.repeat(centres, 40, axis=0) + rng.normal(0, 0.4, size=(n_objects * 40, 3))
    sem_t = np.repeat(1 + rng.integers(0, 2, n_objects), 40)
    inst_t = np.repeat(np.arange(1, n_objects + 1), 40)
    xyz = np.concatenate([ground, pts]).astype(np.float32)
    return xyz, np.concatenate([sem_g, sem_t]), np.concatenate([np.zeros(len(ground), int), inst_t])


def _miou(true, pred):
    iou = []
    for c in range(1, C):
        tp = np.sum((true == c) & (pred == c))
        union = np.sum((true == c) | (pred == c))
        if union:
            iou.append(tp / union)
    return float(np.mean(iou))


def test_segment_swaps_reach_the_confusion_matrix_expected_miou():
    rng = np.random.default_rng(0)
    xyz, sem, inst = _scene(rng)
    conf = uniform_confusion(C, 0.8)
    conf[1, 2], conf[1, 3:] = 0.2, 0.0  # things are confused with each other: car as truck
    noise = PriorNoise(conf, blobs_per_100k=0.0, cell=4.0)
    counts = np.bincount(sem, minlength=C)
    target = float(np.nanmean(expected_iou(conf, counts)[1:]))
    achieved = [_miou(sem, corrupt_prior(xyz, sem, inst, noise, np.random.default_rng(s))) for s in range(4)]
    assert abs(np.mean(achieved) - target) < 0.03, (achieved, target)
    out = corrupt_prior(xyz, sem, inst, noise, np.random.default_rng(1))
    for i in np.unique(inst[inst > 0])[:50]:  # an instance is swapped whole, never point by point
        assert np.unique(out[inst == i]).size == 1
    assert set(np.unique(out[sem == 1])) <= {1, 2}


def test_blob_errors_sit_at_boundaries_and_are_coherent():
    rng = np.random.default_rng(1)
    xyz, sem, inst = _scene(rng)
    noise = PriorNoise(np.eye(C), blobs_per_100k=200.0, blob_radius=(0.5, 1.0))
    out = corrupt_prior(xyz, sem, inst, noise, np.random.default_rng(2))
    wrong = out != sem
    assert 0.001 < wrong.mean() < 0.1
    # every wrong point lies within a blob radius plus the boundary distance of a point of the class
    # it was given
    from scipy.spatial import cKDTree

    for c in np.unique(out[wrong]):
        tree = cKDTree(xyz[sem == c])
        d, _ = tree.query(xyz[wrong & (out == c)])
        assert d.max() <= 1.0 + 0.5 + 1e-6
    # coherent: a wrong point's nearest neighbours are mostly wrong too (independent noise at this
    # rate would give ~wrong.mean())
    tree = cKDTree(xyz)
    _, nn = tree.query(xyz[wrong], k=6)
    assert wrong[nn[:, 1:]].mean() > 0.5


def test_corruption_is_seeded_and_scaling_spans_clean_to_harsh():
    rng = np.random.default_rng(3)
    xyz, sem, inst = _scene(rng, 100)
    noise = PriorNoise(uniform_confusion(C, 0.7), strength=(0.5, 1.5))
    a = corrupt_prior(xyz, sem, inst, noise, np.random.default_rng(9))
    b = corrupt_prior(xyz, sem, inst, noise, np.random.default_rng(9))
    assert np.array_equal(a, b)
    conf = uniform_confusion(C, 0.7)
    assert np.allclose(scale_confusion(conf, 0.0), np.eye(C))
    assert np.allclose(scale_confusion(conf, 1.0), conf)
    harsh = scale_confusion(conf, 5.0)
    assert (
        np.allclose(harsh.sum(1), 1) and (np.diag(harsh)[1:] >= 0).all() and np.diag(harsh)[1:].max() < 1e-9
    )
    m = confusion_matrix(np.array([1, 1, 2, 2]), np.array([1, 2, 2, 2]), 3)
    assert np.allclose(m, [[1, 0, 0], [0, 0.5, 0.5], [0, 0, 1]])

"""Generators of noisy panoptic frames shared by the metric tests and the benchmark."""

from __future__ import annotations

import numpy as np


def random_sequence(rng: np.random.Generator, frames: int, n: int, n_inst: int = 6, noise: float = 0.2):
    """Yield ``(gt_sem, gt_inst, pred_sem, pred_inst)`` train-id frames with relabelled points."""
    for _ in range(frames):
        gs = rng.integers(0, 20, n)
        gi = rng.integers(0, n_inst, n)
        ps, pi = gs.copy(), gi.copy()
        m = rng.random(n) < noise
        ps[m] = rng.integers(0, 20, m.sum())
        m = rng.random(n) < noise
        pi[m] = rng.integers(0, n_inst + 2, m.sum())
        yield gs, gi, ps, pi


def raw_frame(rng: np.random.Generator, label_map, n: int, n_inst: int = 5, noise: float = 0.3):
    """``(gt, pred)`` raw uint32 labels drawn from every raw id of the map, ids < ``n_inst``."""
    raws = np.array(sorted(label_map.learning_map), dtype=np.uint32)
    gt = raws[rng.integers(0, raws.size, n)] | (rng.integers(0, n_inst, n).astype(np.uint32) << 16)
    pred = gt.copy()
    m = rng.random(n) < noise
    pred[m] = raws[rng.integers(0, raws.size, m.sum())] | (
        rng.integers(0, n_inst + 2, m.sum()).astype(np.uint32) << 16
    )
    return gt, pred

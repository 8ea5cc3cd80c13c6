"""Training the dynamic-shifting MLPs with everything upstream frozen (DS-Net's third stage).

A sample is one scan's seeds: their regressed centres, their instance features and their
ground-truth centres. The loss is DS-Net eq. 4 (:func:`dsnet_core.shifting.shift_loss`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from dsnet_core.fps import farthest_point_sampling
from dsnet_core.shifting import DynamicShift, shift_loss

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ShiftSample:
    """Seeds of one scan. centres/gt float32 (M, 3) metres; features float32/float16 (M, D)."""

    centres: np.ndarray
    features: np.ndarray
    gt: np.ndarray


def make_sample(
    xyz: np.ndarray, centres: np.ndarray, features: np.ndarray, gt: np.ndarray, n_seeds: int
) -> ShiftSample:
    """Pick the seeds by FPS on ``xyz`` (as at inference) and keep their inputs and targets.

    Args:
        xyz, centres, gt: float32 (M, 3) thing points, regressed and true centres, metres.
        features: (M, D) instance features.
        n_seeds: seeds per scan (10 000 in 3D).
    """
    idx = farthest_point_sampling(xyz, n_seeds)
    return ShiftSample(centres[idx], features[idx], gt[idx])


def train_shift(
    module: DynamicShift,
    samples: Sequence[ShiftSample],
    steps: int,
    lr: float = 1e-3,
    seed: int = 0,
    device: str = "cpu",
) -> list[float]:
    """Adam on the shifting MLPs, one random sample per step.

    Args:
        module: the module to train (modified in place, left in eval mode).
        samples: training scans (each with at least 2 seeds).
        steps: optimiser steps.
        lr: learning rate.
        seed: seeds the sample order.
        device: where the module and tensors live.

    Returns:
        The loss of every step.
    """
    rng = np.random.default_rng(seed)
    module.to(device).train()
    opt = torch.optim.Adam(module.parameters(), lr=lr)
    tensors = [
        tuple(torch.from_numpy(np.ascontiguousarray(a)).to(device) for a in (s.centres, s.features, s.gt))
        for s in samples
    ]
    losses = []
    for step in range(steps):
        x, f, gt = tensors[int(rng.integers(len(tensors)))]
        loss = shift_loss(module(x, f).positions, gt)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
        if step % 50 == 0:
            log.info("shift training step %d loss %.4f", step, losses[-1])
    module.eval()
    return losses

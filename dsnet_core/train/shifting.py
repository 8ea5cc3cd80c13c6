"""DS-Net's third training stage: the dynamic-shifting MLPs on a frozen network.

A sample is one volume's seeds: farthest-point-sampled ground-truth thing points (as many as the
clusterer uses at inference: 10 000 in 3D, 20 000 in 4D), their regressed centres from the frozen
network, their instance features and their targets, the instances' tight-box centres (over the
whole volume in 4D). The loss is DS-Net eq. 4 (:func:`dsnet_core.instance.shifting.shift_loss`).
The bandwidths and seed counts are the clusterer's (:class:`DynamicShiftConfig`), never repeated.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from dsnet_core.instance.clustering_config import DynamicShiftConfig
from dsnet_core.instance.fps import farthest_point_sampling
from dsnet_core.instance.shifting import DynamicShift, shift_loss
from dsnet_core.io.reader import FrameRef, LogReader
from dsnet_core.labels import LabelMap
from dsnet_core.model.losses import instance_centres
from dsnet_core.model.network import DSNet
from dsnet_core.train.data import load_sample

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ShiftSample:
    """Seeds of one scan. centres/gt float32 (M, 3) metres; features float32/float16 (M, D)."""

    centres: np.ndarray
    features: np.ndarray
    gt: np.ndarray


def clusterer_for(scans: int) -> DynamicShiftConfig:
    """The dynamic-shifting setting of ``scans``-scan volumes: 3D for k = 1, 4D-DS-Net's otherwise."""
    return DynamicShiftConfig() if scans <= 1 else DynamicShiftConfig.for_4d()


def make_shift_module(scans: int, feature_dim: int) -> DynamicShift:
    """The shifting module with the paper's bandwidths for 3D (k = 1) or 4D (k > 1)."""
    cfg = clusterer_for(scans)
    return DynamicShift(cfg.bandwidths, iterations=cfg.iterations, feature_dim=feature_dim)


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


def shift_samples(
    model: DSNet,
    reader: LogReader,
    volumes: list[list[FrameRef]],
    label_map: LabelMap,
    n_seeds: int,
    device: torch.device,
) -> list[ShiftSample]:
    """Run the frozen network on every volume and keep its seeds (skips volumes with < 2 thing points)."""
    model.eval()
    out = []
    with torch.inference_mode():
        for refs in volumes:
            s = load_sample(reader, refs, label_map)
            if int(s.thing.sum()) < 2:
                continue
            pts = torch.from_numpy(s.points).to(device)
            res = model([pts])
            xyz = pts[:, :3]
            th = torch.from_numpy(s.thing).to(device)
            gt = instance_centres(xyz, torch.from_numpy(s.inst).to(device), th)
            out.append(
                make_sample(
                    xyz[th].cpu().numpy(),
                    (xyz + res.offsets)[th].cpu().numpy(),
                    res.features[th].float().cpu().numpy(),
                    gt[th].cpu().numpy(),
                    n_seeds,
                )
            )
    return out


def train_shift(
    module: DynamicShift,
    samples: Sequence[ShiftSample],
    steps: int,
    lr: float = 1e-3,
    seed: int | Sequence[int] = 0,
    device: str = "cpu",
    wrap: Callable[[nn.Module], nn.Module] | None = None,
) -> list[float]:
    """Adam on the shifting MLPs, one random sample per step.

    Args:
        module: the module to train (modified in place, left in eval mode).
        samples: training scans (each with at least 2 seeds).
        steps: optimiser steps.
        lr: learning rate.
        seed: seeds the sample order (a NumPy seed: an int or a sequence of ints).
        device: where the module and tensors live.
        wrap: runs the forward passes through ``wrap(module)`` (data-parallel training: its
            ``DistributedDataParallel`` wrapper, which averages the gradients over processes).

    Returns:
        The loss of every step.
    """
    rng = np.random.default_rng(seed)
    module.to(device).train()
    net = module if wrap is None else wrap(module)
    opt = torch.optim.Adam(module.parameters(), lr=lr)
    tensors = [_tensors(s, device) for s in samples]
    losses = []
    for step in range(steps):
        x, f, gt = tensors[int(rng.integers(len(tensors)))]
        loss = shift_loss(net(x, f).positions, gt)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
        if step % 50 == 0:
            log.info("shift training step %d loss %.4f", step, losses[-1])
    module.eval()
    return losses


def shift_error(module: DynamicShift, samples: list[ShiftSample], device: torch.device) -> float:
    """Mean eq. 4 loss (summed over iterations, metres) of the module in eval mode."""
    if not samples:
        return float("nan")
    return float(np.mean(shift_errors(module, samples, device)))


def shift_errors(module: DynamicShift, samples: list[ShiftSample], device: torch.device) -> list[float]:
    """Eq. 4 loss (summed over iterations, metres) of every sample, the module in eval mode."""
    module.eval()
    losses = []
    with torch.no_grad():
        for s in samples:
            x, f, gt = _tensors(s, device)
            losses.append(float(shift_loss(module(x, f).positions, gt)))
    return losses


def _tensors(s: ShiftSample, device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    return tuple(torch.from_numpy(np.ascontiguousarray(a)).to(device) for a in (s.centres, s.features, s.gt))

"""DS-Net's third training stage: the dynamic-shifting MLPs on a frozen network.

Seeds come from the ground-truth thing points of each volume (FPS, 10 000 in 3D, 20 000 in 4D);
their positions are the frozen network's regressed centres, their targets the instances'
tight-box centres (over the whole volume in 4D).
"""

from __future__ import annotations

import numpy as np
import torch

from dsnet_core.io.reader import FrameRef, LogReader
from dsnet_core.labels import LabelMap
from dsnet_core.model.losses import instance_centres
from dsnet_core.model.network import DSNet
from dsnet_core.shift_training import ShiftSample, make_sample
from dsnet_core.shifting import BANDWIDTHS_3D, BANDWIDTHS_4D, DynamicShift, shift_loss
from dsnet_core.train.data import load_sample


def make_shift_module(scans: int, feature_dim: int) -> DynamicShift:
    """The shifting module with the paper's bandwidths for 3D (k = 1) or 4D (k > 1)."""
    return DynamicShift(BANDWIDTHS_4D if scans > 1 else BANDWIDTHS_3D, feature_dim=feature_dim)


def seeds_per_volume(scans: int) -> int:
    return 20_000 if scans > 1 else 10_000


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
            valid = torch.from_numpy(s.thing).to(device)
            gt = instance_centres(xyz, torch.from_numpy(s.inst).to(device), valid)
            th = valid
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


def shift_error(module: DynamicShift, samples: list[ShiftSample], device: torch.device) -> float:
    """Mean eq. 4 loss (summed over iterations, metres) of the module in eval mode."""
    if not samples:
        return float("nan")
    module.eval()
    losses = []
    with torch.no_grad():
        for s in samples:
            x, f, gt = (
                torch.from_numpy(np.ascontiguousarray(a)).to(device) for a in (s.centres, s.features, s.gt)
            )
            losses.append(float(shift_loss(module(x, f).positions, gt)))
    return float(np.mean(losses))

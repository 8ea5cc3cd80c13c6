"""A tiny random-weight DS-Net checkpoint for wiring tests (a real checkpoint, not a trained model)."""

from __future__ import annotations

import math
from pathlib import Path

import torch

from dsnet_core.instance.shifting import DynamicShift
from dsnet_core.labels import class_map_of, load_label_map
from dsnet_core.model.bundle import save_shift_weights
from dsnet_core.model.checkpoint import ModelCard, save_checkpoint
from dsnet_core.model.cylinder import CylinderGrid
from dsnet_core.model.network import DSNet
from dsnet_core.model.presets import ModelConfig

# coarse grid and narrow layers: ~0.1 s a 27k-point scan on one CPU thread; 20 classes and
# 32-d features as the infer contract stores
TEST_CONFIG = ModelConfig(
    width=2,
    point_mlp=(8, 8),
    compress=4,
    ins_dim=32,
    grid=CylinderGrid(size=(48, 36, 8), min_bound=(0.0, -math.pi, -3.0), max_bound=(50.0, math.pi, 2.0)),
)


def make_checkpoint(path: Path, seed: int = 0, shift_weights: bool = True) -> Path:
    """Write a random-weight checkpoint (seeded) to folder ``path``; with random shifting MLPs."""
    torch.manual_seed(seed)
    model = DSNet(TEST_CONFIG)
    card = ModelCard(
        architecture={},
        class_map=class_map_of(load_label_map("semantic-kitti")),
        training_data={"note": f"random weights, seed {seed}: wiring tests only"},
        code_version="test",
    )
    save_checkpoint(path, model, card)
    if shift_weights:
        save_shift_weights(path, DynamicShift().eval())
    return Path(path)


# Prelude of a subprocess script: SIGKILLs its own process when stitching reaches the third volume.
KILL_STITCH_AT_THIRD_VOLUME = """
import os, signal, sys
import dsnet_core.temporal.stitching as st
_orig, _calls = st.Stitcher.add_volume, [0]
def add_volume(self, volume):
    _calls[0] += 1
    if _calls[0] == 3:
        os.kill(os.getpid(), signal.SIGKILL)
    return _orig(self, volume)
st.Stitcher.add_volume = add_volume
"""


def make_most_checkpoint(path: Path, seed: int = 0, cars: bool = False) -> Path:
    """Write a random-weight MOST checkpoint (seeded, :data:`TEST_CONFIG`'s backbone, a 1 m BEV grid).

    ``cars``: bias the semantic head towards car, the car heatmap and the memberships up, so that
    random weights
    still detect instances and give them points (wiring tests of the whole inference path).
    """
    from dataclasses import replace

    from dsnet_core.model.presets import PRESETS
    from dsnet_core.most.checkpoint import save_most_checkpoint
    from dsnet_core.most.config import BevGrid, MostConfig
    from dsnet_core.most.network import MostNet

    torch.manual_seed(seed)
    backbone = replace(PRESETS["tiny"], width=2, point_mlp=(8, 8), compress=4, grid=TEST_CONFIG.grid)
    config = MostConfig(
        backbone=backbone, bev=BevGrid(half_extent=50.0, cell=1.0), bev_channels=8, mem_widths=(16, 16, 8)
    )
    card = ModelCard(
        architecture={},
        class_map=class_map_of(load_label_map("semantic-kitti")),
        training_data={"note": f"random weights, seed {seed}: wiring tests only"},
        code_version="test",
    )
    net = MostNet(config).eval()
    if cars:
        with torch.no_grad():
            net.sem_head.conv.bias[1] += 4.0
            net.bev_head.heatmap.bias[0] = 2.0
            last = [m for m in net.pointseg.modules() if isinstance(m, torch.nn.Linear)][-1]
            last.bias += 3.0  # PointSegMLP: most RoI points are members
    save_most_checkpoint(path, net, card)
    return Path(path)


def make_dpls_checkpoint(path: Path, seed: int = 0) -> Path:
    """Write a random-weight D-PLS checkpoint (seeded, :data:`TEST_CONFIG` with the 20-class prior input
    and no semantic head; with random shifting MLPs)."""
    from dsnet_core.model.dpls import dpls_config

    torch.manual_seed(seed)
    model = DSNet(dpls_config(TEST_CONFIG))
    card = ModelCard(
        architecture={},
        class_map=class_map_of(load_label_map("semantic-kitti")),
        training_data={"method": "dpls", "note": f"random weights, seed {seed}: wiring tests only"},
        code_version="test",
    )
    save_checkpoint(path, model, card)
    save_shift_weights(path, DynamicShift().eval())
    return Path(path)


def write_gt_prior(log: Path, out: Path, sequence: str = "00", layout: str = "predictions") -> Path:
    """The ground-truth labels of ``log``'s ``sequence`` written as prior files (``.label``) under
    ``out`` in one of the layouts :mod:`dsnet_core.io.prior` reads: ``predictions``
    (``out/sequences/SEQ/predictions/ID.label``) or ``flat`` (``out/SEQ/ID.label``)."""
    import shutil

    src = Path(log) / "sequences" / sequence / "labels"
    dst = out / "sequences" / sequence / "predictions" if layout == "predictions" else out / sequence
    dst.mkdir(parents=True, exist_ok=True)
    for f in sorted(src.glob("*.label")):
        shutil.copyfile(f, dst / f.name)
    return out

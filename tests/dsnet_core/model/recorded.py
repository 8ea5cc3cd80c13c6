"""The reference networks' state dicts as recorded from their own code (``fixtures/
reference_state_dicts.json``; how: ``fixtures/README.md``), and checkpoint files built from them.

Recorded from hongfz16/DS-Net at commit 4a73e2fe529798ad4ec3256d89411f59d2c10416 (``dsnet``,
``dsnet4d``, ``dsnet_offset``) and xinge008/Cylinder3D at commit
30a0abb2ca4c657a821a5e9a343934b0789b2365 (``cylinder3d``), with spconv 1.1 / 1.2.1's layer classes.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch

RECORDED = json.loads((Path(__file__).parent / "fixtures" / "reference_state_dicts.json").read_text())
NETWORKS = RECORDED["networks"]
COMMITS = {
    "hongfz16/DS-Net": "4a73e2fe529798ad4ec3256d89411f59d2c10416",
    "xinge008/Cylinder3D": "30a0abb2ca4c657a821a5e9a343934b0789b2365",
}


def rows(name: str) -> list[list]:
    """``[key, shape, dtype, "parameter" | "buffer", owner class]`` of every state-dict entry."""
    return NETWORKS[name]["state_dict"]


def shapes(name: str) -> dict[str, list[int]]:
    return {key: shape for key, shape, *_ in rows(name)}


def random_state(name: str, seed: int = 0) -> dict[str, torch.Tensor]:
    """Random tensors of the recorded shapes and dtypes (spconv 1.x layout): BatchNorm statistics
    that a BN can use (variance > 0), weights scaled by their fan-in so that activations stay finite."""
    g = torch.Generator().manual_seed(seed)
    out = {}
    for key, shape, dtype, _, owner in rows(name):
        t = torch.empty(shape, dtype=getattr(torch, dtype))
        if not t.is_floating_point():
            t.fill_(7)
        elif key.endswith("running_var") or (owner.startswith("BatchNorm") and key.endswith("weight")):
            t.uniform_(0.5, 1.5, generator=g)
        elif owner == "CrossEntropyLoss":
            t.uniform_(1.0, 90.0, generator=g)
        elif key.endswith(("running_mean", "bias")):
            t.normal_(0.0, 0.1, generator=g)
        else:  # linear (out, in) or spconv 1.x (*kernel, in, out)
            fan_in = shape[-1] if len(shape) == 2 else shape[-2] * math.prod(shape[:3])
            t.normal_(0.0, 1.0 / math.sqrt(fan_in), generator=g)
        out[key] = t
    return out


def save_wrapped(state: dict[str, torch.Tensor], path: Path, epoch: int = 7) -> Path:
    """``state`` in the DS-Net reference's checkpoint dict (utils/train_utils.py checkpoint_state):
    an Adam optimizer state and numpy scalars in ``other_state``, as its training loop saves them."""
    p = torch.nn.Parameter(torch.zeros(3))
    opt = torch.optim.Adam([p], lr=0.002)
    p.grad = torch.ones(3)
    opt.step()
    obj = {
        "epoch": epoch,
        "model_state": state,
        "optimizer_state": opt.state_dict(),
        "other_state": {"best_pq": np.float64(0.577), "best_miou": np.float32(0.6)},
    }
    torch.save(obj, path)
    return path

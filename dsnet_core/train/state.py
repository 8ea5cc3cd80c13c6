"""Resumable training state: optimiser tensors in safetensors, the rest in JSON (no pickle)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch
from safetensors.torch import load_file

from dsnet_core.model.checkpoint import save_tensors

STATE_TENSORS, STATE_JSON = "train_state.safetensors", "train_state.json"


def save_train_state(path: Path, optimizer: torch.optim.Optimizer, marker: dict) -> None:
    """Write the optimiser state of the current stage, tagged with ``marker`` (stage, epochs done)."""
    sd = optimizer.state_dict()
    tensors = {}
    for pid, st in sd["state"].items():
        for name, value in st.items():
            tensors[f"{pid}.{name}"] = value if torch.is_tensor(value) else torch.tensor(value)
    save_tensors(tensors, path / STATE_TENSORS)
    meta = {"marker": marker, "param_groups": sd["param_groups"]}
    tmp = path / (STATE_JSON + ".tmp")
    tmp.write_text(json.dumps(meta, indent=2, sort_keys=True))
    os.replace(tmp, path / STATE_JSON)


def load_train_state(path: Path, optimizer: torch.optim.Optimizer, marker: dict) -> bool:
    """Restore the optimiser if the saved state carries ``marker``; returns whether it did."""
    if not (path / STATE_JSON).is_file() or not (path / STATE_TENSORS).is_file():
        return False
    meta = json.loads((path / STATE_JSON).read_text())
    if meta.get("marker") != marker:
        return False
    tensors = load_file(str(path / STATE_TENSORS))
    state: dict[int, dict] = {}
    for key, value in tensors.items():
        pid, name = key.split(".", 1)
        state.setdefault(int(pid), {})[name] = value
    optimizer.load_state_dict({"state": state, "param_groups": meta["param_groups"]})
    return True

"""Resumable training state: optimiser tensors in safetensors, the rest in JSON (no pickle)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file

from dsnet_core.errors import CheckpointError
from dsnet_core.model.checkpoint import save_tensors, sha256_file

STATE_TENSORS, STATE_JSON = "train_state.safetensors", "train_state.json"


def save_train_state(path: Path, optimizer: torch.optim.Optimizer, marker: dict) -> None:
    """Write the optimiser state of the current stage, tagged with ``marker`` (stage, epochs done)."""
    sd = optimizer.state_dict()
    tensors = {}
    for pid, st in sd["state"].items():
        for name, value in st.items():
            tensors[f"{pid}.{name}"] = value if torch.is_tensor(value) else torch.tensor(value)
    save_tensors(tensors, path / STATE_TENSORS)
    meta = {
        "marker": marker,
        "param_groups": sd["param_groups"],
        "tensors_sha256": sha256_file(path / STATE_TENSORS),
    }
    tmp = path / (STATE_JSON + ".tmp")
    tmp.write_text(json.dumps(meta, indent=2, sort_keys=True))
    os.replace(tmp, path / STATE_JSON)


def load_train_state(path: Path, optimizer: torch.optim.Optimizer, marker: dict) -> bool:
    """Restore the optimiser if the saved state carries ``marker``; returns whether it did.

    Raises:
        CheckpointError: one of the two state files is missing, they do not read, their tensors do
            not match the digest the JSON records, or they do not fit the optimiser (never a silent
            mix of states, nor a silently fresh optimiser).
    """
    fix = f"delete {STATE_JSON} and {STATE_TENSORS} to resume with a fresh optimiser (not bit-identical)"
    lost = f"optimiser state is missing, its other half is there: {fix}"  # a fresh one: a silent change
    if not (path / STATE_JSON).is_file():
        if (path / STATE_TENSORS).is_file():  # which epoch it holds is not known: refused
            raise CheckpointError(path / STATE_JSON, lost)
        return False
    try:
        meta = json.loads((path / STATE_JSON).read_text())
        if not isinstance(meta, dict):
            raise ValueError("not a JSON object")
    except (ValueError, UnicodeDecodeError) as exc:
        raise CheckpointError(path / STATE_JSON, f"optimiser state is damaged ({exc}): {fix}") from None
    if meta.get("marker") != marker:
        return False  # another stage's (or epoch's) state: not needed
    if not (path / STATE_TENSORS).is_file():
        raise CheckpointError(path / STATE_TENSORS, lost)
    recorded = meta.get("tensors_sha256")  # states written before it was recorded have none
    if recorded is not None and sha256_file(path / STATE_TENSORS) != recorded:
        raise CheckpointError(path / STATE_TENSORS, f"optimiser state does not match its record: {fix}")
    try:
        tensors = load_file(str(path / STATE_TENSORS))
        state: dict[int, dict] = {}
        for key, value in tensors.items():
            pid, name = key.split(".", 1)
            state.setdefault(int(pid), {})[name] = value
        optimizer.load_state_dict({"state": state, "param_groups": meta["param_groups"]})
    except (SafetensorError, OSError, ValueError, KeyError, RuntimeError) as exc:
        raise CheckpointError(path / STATE_TENSORS, f"optimiser state does not load ({exc}): {fix}") from None
    return True

"""Checkpoints: safetensors weights (never unpickled) plus a JSON model card.

A checkpoint is a folder::

    CKPT/model.safetensors    weights (and BN buffers)
    CKPT/card.json            the model card, written last; holds the weights' sha256 (and
                              that of ``shift.safetensors`` when the folder has one)
    CKPT/train_state.*        optimiser state and schedule position (training only)

Every file is written to a temporary name and renamed into place, so a killed writer leaves
either the previous checkpoint or the new one.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from dsnet_core.errors import CheckpointError, CheckpointMismatchError
from dsnet_core.labels import LabelMap, class_map_of
from dsnet_core.model.card import (
    CARD,
    FORMAT,
    SHIFT_WEIGHTS,
    WEIGHTS,
    ModelCard,
    read_card,
    sha256_file,
    write_card,
)
from dsnet_core.model.network import DSNet
from dsnet_core.model.presets import ModelConfig
from dsnet_core.version import code_version

__all__ = [  # the card's names are re-exported: a checkpoint is its weights and its card
    "CARD",
    "FORMAT",
    "SHIFT_WEIGHTS",
    "WEIGHTS",
    "ModelCard",
    "class_map_of",
    "code_version",
    "load_checkpoint",
    "read_card",
    "save_checkpoint",
    "save_tensors",
    "sha256_file",
    "write_card",
]


def save_tensors(
    tensors: dict[str, torch.Tensor], path: Path, metadata: dict[str, str] | None = None
) -> None:
    """Write tensors to ``path`` atomically (safetensors)."""
    tmp = path.with_name(path.name + ".tmp")
    save_file({k: v.detach().contiguous().cpu() for k, v in tensors.items()}, str(tmp), metadata=metadata)
    os.replace(tmp, path)


def save_checkpoint(path: str | Path, model: DSNet, card: ModelCard) -> Path:
    """Write weights then the card (with the weights' hash) into folder ``path``; returns it."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    save_tensors(model.state_dict(), path / WEIGHTS, metadata={"format": FORMAT})
    card.weights_sha256 = sha256_file(path / WEIGHTS)
    card.architecture = model.config.to_dict()
    card.code_version = card.code_version or code_version()
    write_card(path, card)
    return path


def _diff(expected: dict, found: dict) -> list[str]:
    keys = sorted(set(expected) | set(found))
    return [
        f"{k}: expected {expected.get(k)!r}, checkpoint has {found.get(k)!r}"
        for k in keys
        if expected.get(k) != found.get(k)
    ]


def load_checkpoint(
    path: str | Path,
    device: str | torch.device = "cpu",
    expect_config: ModelConfig | None = None,
    expect_label_map: LabelMap | None = None,
) -> tuple[DSNet, ModelCard]:
    """Load a checkpoint, verifying the weights' hash, the architecture and the class map.

    Raises:
        CheckpointError: missing/unreadable files, or weights that do not match the card's hash.
        CheckpointMismatchError: architecture or class map differs from the expected ones.
    """
    path = Path(path)
    card = read_card(path)
    weights = path / WEIGHTS
    if not weights.is_file():
        raise CheckpointError(weights, "weights file is missing")
    if sha256_file(weights) != card.weights_sha256:
        raise CheckpointError(
            weights, "weights do not match the model card's sha256 (tampered or half-written)"
        )
    if expect_config is not None and expect_config.to_dict() != card.architecture:
        diff = "; ".join(_diff(expect_config.to_dict(), card.architecture))
        raise CheckpointMismatchError(path / CARD, f"architecture differs from the configured one: {diff}")
    if expect_label_map is not None and class_map_of(expect_label_map) != card.class_map:
        diff = "; ".join(_diff(class_map_of(expect_label_map), card.class_map))
        raise CheckpointMismatchError(path / CARD, f"class map differs from the configured one: {diff}")
    config = card.config
    try:
        state = load_file(str(weights), device=str(device))
    except (SafetensorError, OSError) as exc:
        raise CheckpointError(weights, f"cannot read weights: {exc}") from exc
    check_finite(state, weights)
    model = DSNet(config).to(device)
    try:
        result = model.load_state_dict(state, strict=False)
    except RuntimeError as exc:
        raise CheckpointMismatchError(weights, f"weights do not fit the card's architecture: {exc}") from exc
    if result.missing_keys or result.unexpected_keys:
        raise CheckpointMismatchError(
            weights,
            f"weights do not fit the card's architecture (missing {result.missing_keys[:5]}, "
            f"unexpected {result.unexpected_keys[:5]})",
        )
    return model, card


def check_finite(state: dict[str, torch.Tensor], file: Path) -> None:
    """Refuse weights holding NaN or infinity when a checkpoint is loaded (not later, in a stage
    that sees only NaN positions). A finite sum proves a tensor finite; an infinite one is checked
    element-wise (the sum of finite values may overflow).

    Raises:
        CheckpointError: naming ``file`` and the first tensors with non-finite values.
    """
    bad = [
        key
        for key, value in state.items()
        if value.is_floating_point()
        and not bool(torch.isfinite(value.sum()))
        and not bool(torch.isfinite(value).all())
    ]
    if bad:
        raise CheckpointError(
            file,
            f"weights hold NaN or infinite values ({len(bad)} tensor(s): {', '.join(bad[:4])}"
            f"{' …' if len(bad) > 4 else ''}): the training diverged or the file is damaged; retrain, "
            "resume from an earlier copy, or use another checkpoint",
        )

"""MOST checkpoints: the project's checkpoint folder layout (safetensors weights, a JSON model card
written last with the weights' sha256) with its own format tag and architecture (``MostConfig``).

Every card carries ``format``; :func:`dsnet_core.checkpoints.card_kind` tells them apart.
"""

from __future__ import annotations

from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file

from dsnet_core.errors import CheckpointError, CheckpointMismatchError
from dsnet_core.labels import LabelMap
from dsnet_core.model.card import _atomic_write_text, card_text
from dsnet_core.model.checkpoint import (
    CARD,
    WEIGHTS,
    ModelCard,
    class_map_of,
    code_version,
    save_tensors,
    sha256_file,
)
from dsnet_core.most.card import MOST_FORMAT, read_most_card
from dsnet_core.most.config import MostConfig
from dsnet_core.most.network import MostNet

__all__ = [  # the card's names are re-exported: a checkpoint is its weights and its card
    "MOST_FORMAT",
    "load_most_checkpoint",
    "read_most_card",
    "save_most_checkpoint",
]


def save_most_checkpoint(path: str | Path, model: MostNet, card: ModelCard) -> Path:
    """Write the weights then the card (with their hash) into folder ``path``; returns it."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    save_tensors(model.state_dict(), path / WEIGHTS, metadata={"format": MOST_FORMAT})
    card.format = MOST_FORMAT
    card.weights_sha256 = sha256_file(path / WEIGHTS)
    card.architecture = model.config.to_dict()
    card.code_version = card.code_version or code_version()
    _atomic_write_text(path / CARD, card_text(card.__dict__))
    return path


def load_most_checkpoint(
    path: str | Path, device: str | torch.device = "cpu", expect_label_map: LabelMap | None = None
) -> tuple[MostNet, ModelCard]:
    """Load a MOST checkpoint, verifying the weights' hash and (optionally) the class map.

    Raises:
        CheckpointError: missing/unreadable files, weights that do not match the card's hash.
        CheckpointMismatchError: a different class map, or weights that do not fit the architecture.
    """
    path = Path(path)
    card = read_most_card(path)
    weights = path / WEIGHTS
    if not weights.is_file():
        raise CheckpointError(weights, "weights file is missing")
    if sha256_file(weights) != card.weights_sha256:
        raise CheckpointError(
            weights, "weights do not match the model card's sha256 (tampered or half-written)"
        )
    if expect_label_map is not None and class_map_of(expect_label_map) != card.class_map:
        raise CheckpointMismatchError(
            path / CARD,
            f"class map differs: checkpoint has {card.class_map.get('name')!r}, "
            f"expected {expect_label_map.name!r}",
        )
    config = MostConfig.from_dict(card.architecture)
    try:
        state = load_file(str(weights), device=str(device))
    except (SafetensorError, OSError) as exc:
        raise CheckpointError(weights, f"cannot read weights: {exc}") from exc
    model = MostNet(config).to(device)
    try:
        model.load_state_dict(state)
    except RuntimeError as exc:
        raise CheckpointMismatchError(weights, f"weights do not fit the card's architecture: {exc}") from exc
    return model, card

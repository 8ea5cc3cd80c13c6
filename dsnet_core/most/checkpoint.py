"""MOST checkpoints: the project's checkpoint folder layout (safetensors weights, a JSON model card
written last with the weights' sha256) with its own format tag and architecture (``MostConfig``).

Both methods' cards carry ``format``; :func:`checkpoint_method` tells them apart.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file

from dsnet_core.errors import CheckpointError, CheckpointMismatchError, ConfigError
from dsnet_core.labels import LabelMap
from dsnet_core.model.checkpoint import (
    CARD,
    WEIGHTS,
    ModelCard,
    _atomic_write_text,
    class_map_of,
    code_version,
    save_tensors,
    sha256_file,
)
from dsnet_core.model.checkpoint import (
    FORMAT as DSNET_FORMAT,
)
from dsnet_core.most.config import MostConfig
from dsnet_core.most.network import MostNet

MOST_FORMAT = "most-checkpoint/1"
FORMATS = {DSNET_FORMAT: "dsnet", MOST_FORMAT: "most"}


def _card_json(path: Path) -> dict:
    card_path = path / CARD
    if not card_path.is_file():
        raise CheckpointError(card_path, "no model card (is this a checkpoint folder?)")
    try:
        data = json.loads(card_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CheckpointError(card_path, f"model card is not valid JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise CheckpointError(card_path, "model card is not a JSON object")
    return data


def checkpoint_method(path: str | Path) -> str:
    """``dsnet`` or ``most``: which method's network a checkpoint folder holds.

    Raises:
        CheckpointError: no readable card, or an unknown format.
    """
    data = _card_json(Path(path))
    fmt = data.get("format")
    if fmt not in FORMATS:
        raise CheckpointError(
            Path(path) / CARD, f"unknown checkpoint format {fmt!r} (known: {sorted(FORMATS)})"
        )
    return FORMATS[fmt]


def read_most_card(path: str | Path) -> ModelCard:
    """Read and validate a MOST checkpoint's ``card.json``."""
    path = Path(path)
    data = _card_json(path)
    if data.get("format") != MOST_FORMAT:
        hint = (
            " — a DS-Net checkpoint: label with --method dsnet" if data.get("format") == DSNET_FORMAT else ""
        )
        raise CheckpointError(
            path / CARD,
            f"not a MOST checkpoint (format {data.get('format')!r}, expected {MOST_FORMAT}){hint}",
        )
    try:
        card = ModelCard(**data)
    except TypeError as exc:
        raise CheckpointError(path / CARD, f"model card has unexpected fields: {exc}") from exc
    try:  # the architecture's error (a grid beyond its bound, a missing field) is the card's
        MostConfig.from_dict(card.architecture)
    except (ConfigError, TypeError, KeyError, ValueError, AttributeError) as exc:
        raise CheckpointError(path / CARD, f"model card architecture is malformed: {exc}") from exc
    return card


def save_most_checkpoint(path: str | Path, model: MostNet, card: ModelCard) -> Path:
    """Write the weights then the card (with their hash) into folder ``path``; returns it."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    save_tensors(model.state_dict(), path / WEIGHTS, metadata={"format": MOST_FORMAT})
    card.format = MOST_FORMAT
    card.weights_sha256 = sha256_file(path / WEIGHTS)
    card.architecture = model.config.to_dict()
    card.code_version = card.code_version or code_version()
    _atomic_write_text(path / CARD, json.dumps(card.__dict__, indent=2, sort_keys=True))
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

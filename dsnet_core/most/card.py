"""A MOST checkpoint's model card, readable without torch (its format); which method a checkpoint
folder holds is :func:`dsnet_core.checkpoints.card_kind`'s; :mod:`dsnet_core.most.checkpoint` adds
the weights."""

from __future__ import annotations

from pathlib import Path

from dsnet_core.errors import CheckpointError, ConfigError
from dsnet_core.model.card import CARD, ModelCard, card_json
from dsnet_core.most.config import MostConfig

MOST_FORMAT = "most-checkpoint/1"


def read_most_card(path: str | Path) -> ModelCard:
    """Read and validate a MOST checkpoint's ``card.json``."""
    path = Path(path)
    data = card_json(path)
    if data.get("format") != MOST_FORMAT:  # which method's it is: dsnet_core.checkpoints.card_kind
        raise CheckpointError(
            path / CARD, f"not a MOST checkpoint (format {data.get('format')!r}, expected {MOST_FORMAT})"
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

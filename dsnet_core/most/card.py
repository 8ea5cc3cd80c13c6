"""A MOST checkpoint's model card, readable without torch (its format, which method a checkpoint
folder holds); :mod:`dsnet_core.most.checkpoint` adds the weights."""

from __future__ import annotations

from pathlib import Path

from dsnet_core.errors import CheckpointError, ConfigError
from dsnet_core.model.card import CARD, ModelCard, card_json
from dsnet_core.model.card import FORMAT as DSNET_FORMAT
from dsnet_core.most.config import MostConfig

MOST_FORMAT = "most-checkpoint/1"
FORMATS = {DSNET_FORMAT: "dsnet", MOST_FORMAT: "most"}


def checkpoint_method(path: str | Path) -> str:
    """``dsnet`` or ``most``: which method's network a checkpoint folder holds.

    Raises:
        CheckpointError: no readable card, or an unknown format.
    """
    data = card_json(Path(path))
    fmt = data.get("format")
    if fmt not in FORMATS:
        raise CheckpointError(
            Path(path) / CARD, f"unknown checkpoint format {fmt!r} (known: {sorted(FORMATS)})"
        )
    return FORMATS[fmt]


def read_most_card(path: str | Path) -> ModelCard:
    """Read and validate a MOST checkpoint's ``card.json``."""
    path = Path(path)
    data = card_json(path)
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

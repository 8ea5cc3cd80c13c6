"""A checkpoint's model card (``CKPT/card.json``), readable without torch: commands that only need
a model's grid, classes or digest (``dsnet label``'s checks before a server starts) stay fast.
:mod:`dsnet_core.model.checkpoint` adds the weights.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from dsnet_core.errors import CheckpointError, ConfigError
from dsnet_core.labels import label_map_from_class_map
from dsnet_core.model.presets import ModelConfig

FORMAT = "dsnet-checkpoint/1"
WEIGHTS, CARD = "model.safetensors", "card.json"
SHIFT_WEIGHTS = "shift.safetensors"


@dataclass
class ModelCard:
    """What a checkpoint is.

    Attributes:
        architecture: :meth:`ModelConfig.to_dict`.
        class_map: label map name, class names, thing ids, train→raw ids.
        training_data: fingerprint and description of the training data.
        epochs: completed epochs per stage.
        metrics: validation metrics, one dict per epoch.
        code_version: git commit (or package version) that wrote it.
        weights_sha256: hash of ``model.safetensors``.
        shift_sha256: hash of ``shift.safetensors`` (:mod:`dsnet_core.model.bundle`), "" without one.
    """

    architecture: dict
    class_map: dict
    training_data: dict = field(default_factory=dict)
    epochs: dict = field(default_factory=dict)
    metrics: list = field(default_factory=list)
    code_version: str = ""
    weights_sha256: str = ""
    shift_sha256: str = ""
    format: str = FORMAT

    @property
    def config(self) -> ModelConfig:
        return ModelConfig.from_dict(self.architecture)


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _atomic_write_text(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


CARD_DIGEST = "card_sha256"
"""The card's digest of itself: sha256 of its canonical JSON without this key (:func:`card_text`)."""


def _digest(data: dict) -> str:
    body = {k: v for k, v in data.items() if k != CARD_DIGEST}
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def card_text(data: dict) -> str:
    """A card's JSON text (any method's card), with its digest of itself (:data:`CARD_DIGEST`), so
    that an edit that still parses (a class name, a metric, an import record) is found on read."""
    body = {k: v for k, v in data.items() if k != CARD_DIGEST}
    return json.dumps({**body, CARD_DIGEST: _digest(body)}, indent=2, sort_keys=True)


def write_card(path: str | Path, card: ModelCard) -> None:
    """Write ``CKPT/card.json`` atomically, recording the sha256 of ``shift.safetensors`` if present."""
    path = Path(path)
    shift = path / SHIFT_WEIGHTS
    card.shift_sha256 = sha256_file(shift) if shift.is_file() else ""
    _atomic_write_text(path / CARD, card_text(card.__dict__))


def card_json(path: str | Path) -> dict:
    """The JSON object of ``CKPT/card.json`` (any method's card), unvalidated.

    Raises:
        CheckpointError: no card, not JSON, or not a JSON object; a committed epoch not yet moved
            into place (``.pending/COMMIT``: the folder's files may mix two epochs).
    """
    card_path = Path(path) / CARD
    commit = Path(path) / ".pending" / "COMMIT"  # dsnet_core.train.commit's marker
    if commit.is_file():
        raise CheckpointError(
            commit.parent,
            "an epoch is being saved here, or its save was killed half-way (its files are a mix of two "
            "epochs): wait for the training to finish, or finish the save with the same `dsnet train` "
            "(or `dsnet adapt`) command and --resume",
        )
    if not card_path.is_file():
        if (Path(path) / WEIGHTS).is_file():
            raise CheckpointError(
                card_path,
                f"no model card beside {WEIGHTS}: an import or a first save was stopped before its card "
                "was written (the card is written last); rerun the command that wrote this folder",
            )
        raise CheckpointError(card_path, "no model card (is this a checkpoint folder?)")
    try:
        data = json.loads(card_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CheckpointError(card_path, f"model card is not valid JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise CheckpointError(card_path, "model card is not a JSON object")
    if CARD_DIGEST in data:  # cards written before the digest existed (the bundled ones) have none
        recorded = data.pop(CARD_DIGEST)
        if recorded != _digest(data):
            raise CheckpointError(
                card_path,
                f"model card does not match its own sha256 (edited or damaged); if you edited it on "
                f'purpose, delete its "{CARD_DIGEST}" entry',
            )
    return data


def check_card_files(path: str | Path) -> None:
    """The files the card of checkpoint ``path`` records are there with its sha256: the weights and,
    when recorded, the shifting weights. What loading finds, without torch (``dsnet label`` checks
    it before any server starts, so a damaged checkpoint is one line, not a failed infer stage).

    Raises:
        CheckpointError: the card does not read, or a file is missing or not the card's, naming it.
    """
    path = Path(path)
    data = card_json(path)
    for name, key, what in (
        (WEIGHTS, "weights_sha256", "weights"),
        (SHIFT_WEIGHTS, "shift_sha256", "shifting weights"),
    ):
        file, recorded = path / name, data.get(key) or ""
        if not file.is_file():
            if recorded or name == WEIGHTS:
                raise CheckpointError(file, f"{what} file is missing though the model card records it")
            continue
        if key in data and sha256_file(file) != recorded:
            raise CheckpointError(
                file, f"{what} do not match the model card's sha256 (tampered, damaged or half-written)"
            )


def read_card(path: str | Path) -> ModelCard:
    """Read and validate ``CKPT/card.json``."""
    card_path = Path(path) / CARD
    data = card_json(path)
    if data.get("format") != FORMAT:  # which method's it is: dsnet_core.checkpoints.card_kind
        raise CheckpointError(card_path, f"not a {FORMAT} model card (format {data.get('format')!r})")
    try:
        card = ModelCard(**data)
    except TypeError as exc:
        raise CheckpointError(card_path, f"model card has unexpected fields: {exc}") from exc
    # a changed class map or architecture is the card's error, found here, not a stage's later
    try:
        label_map_from_class_map(card.class_map)
    except ConfigError as exc:
        raise CheckpointError(card_path, str(exc)) from exc
    try:
        card.config  # noqa: B018 - parses the architecture
    except (ConfigError, TypeError, KeyError, ValueError, AttributeError) as exc:
        raise CheckpointError(card_path, f"model card architecture is malformed: {exc}") from exc
    return card

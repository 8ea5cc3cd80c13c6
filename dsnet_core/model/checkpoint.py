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

import hashlib
import json
import os
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from dsnet_core.errors import CheckpointError, CheckpointMismatchError, ConfigError
from dsnet_core.labels import LabelMap, class_map_of, label_map_from_class_map
from dsnet_core.model.network import DSNet
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


def code_version() -> str:
    """``$DSNET_CODE_VERSION``, else the git commit of this code, else the package version."""
    if os.environ.get("DSNET_CODE_VERSION"):
        return os.environ["DSNET_CODE_VERSION"]
    here = Path(__file__).resolve().parent
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here,
            capture_output=True,
            text=True,
            timeout=5,
        ).stdout.strip()
        return sha + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        from importlib.metadata import PackageNotFoundError, version

        try:
            return version("dsnet-pipeline")
        except PackageNotFoundError:
            return "unknown"


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


def write_card(path: str | Path, card: ModelCard) -> None:
    """Write ``CKPT/card.json`` atomically, recording the sha256 of ``shift.safetensors`` if present."""
    path = Path(path)
    shift = path / SHIFT_WEIGHTS
    card.shift_sha256 = sha256_file(shift) if shift.is_file() else ""
    _atomic_write_text(path / CARD, json.dumps(card.__dict__, indent=2, sort_keys=True))


def read_card(path: str | Path) -> ModelCard:
    """Read and validate ``CKPT/card.json``."""
    card_path = Path(path) / CARD
    if not card_path.is_file():
        raise CheckpointError(card_path, "no model card (is this a checkpoint folder?)")
    try:
        data = json.loads(card_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CheckpointError(card_path, f"model card is not valid JSON: {exc}") from exc
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        hint = ""
        if isinstance(data, dict) and str(data.get("format", "")).startswith("most-checkpoint"):
            hint = " — a MOST checkpoint: label with --method most"
        raise CheckpointError(card_path, f"not a {FORMAT} model card{hint}")
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

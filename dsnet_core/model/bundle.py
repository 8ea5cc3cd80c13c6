"""The bundled demo model, the shifting MLPs' weights next to a checkpoint, and a checkpoint's
content digest (what the ``infer`` stage puts in its fingerprint).

A checkpoint folder (see :mod:`dsnet_core.model.checkpoint`) may also hold::

    CKPT/shift.safetensors    the dynamic-shifting MLPs (``DynamicShift.state_dict()``), optional;
                              its sha256 is in the card (``shift_sha256``) and checked on load

The bundled DS-Net models live in the package at ``dsnet_core/data/models/tiny-v2/`` (single scans)
and ``dsnet_core/data/models/tiny-v2-4d/`` (its joint 2-scan fine-tune), shipped by ``pyproject``'s
package data; ``tiny/`` and ``tiny-4d/`` are their predecessors (trained on one street style), kept
because the bundled MOST and D-PLS models started from ``tiny`` and for comparison.
When a copy of the package lacks them, :func:`bundled_checkpoint` returns None and callers say so.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file

from dsnet_core.model.checkpoint import (
    SHIFT_WEIGHTS,
    CheckpointError,
    read_card,
    save_tensors,
    sha256_file,
    write_card,
)

BUNDLED_NAME = "tiny-v2"
BUNDLED_4D_NAME = "tiny-v2-4d"
#: bundled MOST models: the accumulated-input one (k = 3) and, when present, a single-scan one
BUNDLED_MOST_NAMES = {3: "most", 1: "most-1"}
BUNDLED_DPLS_NAME = "dpls"


def bundled_dir(scans: int = 1) -> Path:
    """Where the bundled demo checkpoint for ``scans``-scan volumes lives inside the package:
    ``tiny-v2`` (single scans) or ``tiny-v2-4d`` (fine-tuned jointly on 2-scan volumes, used for
    every k > 1)."""
    name = BUNDLED_NAME if scans <= 1 else BUNDLED_4D_NAME
    return Path(__file__).resolve().parents[1] / "data" / "models" / name


def _is_checkpoint(path: Path) -> bool:
    return (path / "card.json").is_file() and (path / "model.safetensors").is_file()


def bundled_checkpoint(scans: int = 1) -> Path | None:
    """The bundled demo checkpoint for ``scans``-scan volumes (the 4D one when k > 1 and it is
    bundled, else the single-scan one), or None when no trained model is bundled."""
    for path in (bundled_dir(scans), bundled_dir(1)):
        if _is_checkpoint(path):
            return path
    return None


def bundled_most_checkpoint(scans: int = 3) -> Path | None:
    """The bundled MOST checkpoint for ``scans``-scan input: the single-scan one for k = 1 when it
    is bundled, else the accumulated-input one; None when no MOST model is bundled."""
    root = Path(__file__).resolve().parents[1] / "data" / "models"
    names = [BUNDLED_MOST_NAMES[1]] if scans <= 1 else []
    for path in [root / n for n in [*names, BUNDLED_MOST_NAMES[3]]]:
        if _is_checkpoint(path):
            return path
    return None


def resolve_checkpoint(path: str | Path | None, scans: int = 1) -> Path:
    """``path``, or the bundled model for ``scans``-scan volumes when None.

    Raises:
        CheckpointError: None given and no bundled model, or ``path`` holds no model card.
    """
    if path is None:
        found = bundled_checkpoint(scans)
        if found is None:
            raise CheckpointError(
                bundled_dir(), "no bundled model: pass a checkpoint (dsnet label --checkpoint PATH)"
            )
        return found
    path = Path(path).expanduser()
    read_card(path)  # typed error naming the file when it is not a checkpoint
    return path


def bundled_dpls_checkpoint() -> Path | None:
    """The bundled D-PLS instance network (``dsnet_core/data/models/dpls/``), or None when absent."""
    path = bundled_dir().parent / BUNDLED_DPLS_NAME
    return path if _is_checkpoint(path) else None


def resolve_dpls_checkpoint(path: str | Path | None) -> Path:
    """``path`` (a D-PLS checkpoint folder), or the bundled D-PLS model when None.

    Raises:
        CheckpointError: None given and no bundled D-PLS model, or ``path`` holds no model card.
    """
    if path is None:
        found = bundled_dpls_checkpoint()
        if found is None:
            raise CheckpointError(
                bundled_dir().parent / BUNDLED_DPLS_NAME,
                "no bundled D-PLS model: pass a D-PLS checkpoint (dsnet label --method dpls --checkpoint "
                "PATH; train one with dsnet train --method dpls)",
            )
        return found
    path = Path(path).expanduser()
    read_card(path)
    return path


def resolve_most_checkpoint(path: str | Path | None, scans: int = 3) -> Path:
    """``path`` (a MOST checkpoint folder), or the bundled MOST model for ``scans``-scan input.

    Raises:
        CheckpointError: None given and no bundled MOST model, or ``path`` is not a MOST checkpoint
            (a DS-Net one included: the message says which method it belongs to).
    """
    from dsnet_core.most.checkpoint import read_most_card

    if path is None:
        found = bundled_most_checkpoint(scans)
        if found is None:
            raise CheckpointError(
                bundled_dir().parent,
                "no bundled MOST model: pass a MOST checkpoint (dsnet label --method most --checkpoint "
                "PATH; train one with dsnet train --method most)",
            )
        return found
    path = Path(path).expanduser()
    read_most_card(path)  # typed error naming the card when it is not a MOST checkpoint
    return path


def checkpoint_digest(path: str | Path) -> str:
    """A content digest of a checkpoint (either method's): the card (which holds the weights'
    sha256) and the shifting weights' sha256. Cheap: the network weights are not re-read
    (``load_checkpoint`` verifies them against the card's hash when the model is loaded).

    Returns:
        32 hex digits.
    """
    from dsnet_core.most.checkpoint import checkpoint_method, read_most_card

    path = Path(path)
    card = read_most_card(path) if checkpoint_method(path) == "most" else read_card(path)
    h = hashlib.blake2b(digest_size=16)
    h.update(
        json.dumps({k: v for k, v in card.__dict__.items() if k != "code_version"}, sort_keys=True).encode()
    )
    shift = path / SHIFT_WEIGHTS
    h.update(sha256_file(shift).encode() if shift.is_file() else b"no-shift-weights")
    return h.hexdigest()


def save_shift_weights(path: str | Path, module: torch.nn.Module) -> Path:
    """Write a :class:`~dsnet_core.instance.shifting.DynamicShift`'s weights into checkpoint ``path``
    and record their sha256 in its card (when the folder has one)."""
    out = Path(path) / SHIFT_WEIGHTS
    bandwidths = ",".join(str(b) for b in getattr(module, "bandwidths", ()))
    save_tensors(module.state_dict(), out, metadata={"bandwidths": bandwidths})
    if (Path(path) / "card.json").is_file():
        write_card(path, read_card(path))
    return out


def load_shift_weights(path: str | Path) -> dict[str, torch.Tensor] | None:
    """The shifting MLPs' state dict stored with checkpoint ``path``, or None if it has none.

    Raises:
        CheckpointError: the file is missing though the card records its ``shift_sha256``, or
            it exists but its sha256 is not the card's ``shift_sha256``
            (tampered, half-written, or saved by a version whose cards did not record it), or it
            cannot be read.
    """
    file = Path(path) / SHIFT_WEIGHTS
    if not file.is_file():
        if (Path(path) / "card.json").is_file() and read_card(path).shift_sha256:
            # the card says the checkpoint had them: lost, not absent (no silent fallback weights)
            raise CheckpointError(file, "shifting weights are missing though the model card records them")
        return None
    card = read_card(path)
    if sha256_file(file) != card.shift_sha256:
        recorded = card.shift_sha256[:12] or "none"
        raise CheckpointError(
            file,
            f"shifting weights do not match the model card's shift_sha256 ({recorded}): tampered, "
            "half-written, or saved before cards recorded it",
        )
    try:
        return load_file(str(file))
    except (SafetensorError, OSError) as exc:
        raise CheckpointError(file, f"cannot read the shifting weights: {exc}") from exc

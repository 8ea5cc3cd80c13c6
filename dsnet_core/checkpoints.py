"""Every method's checkpoints in one place, above the packages of the networks (``model/``,
``most/``): the bundled demo models, resolving a ``--checkpoint`` (or the bundled one) per method,
and a checkpoint's content digest (what a model stage puts in its fingerprint).

The bundled DS-Net models live in the package at ``dsnet_core/data/models/tiny-v2/`` (single
scans) and ``tiny-v2-4d/`` (its joint 2-scan fine-tune), shipped by ``pyproject``'s package data;
``most/`` (and ``most-1/`` when present) and ``dpls/`` are MOST's and D-PLS's. ``tiny/`` and
``tiny-4d/`` are the predecessors the MOST and D-PLS models started from, kept for the benchmarks
that compare with them; nothing defaults to them. When a copy of the package lacks a model,
``bundled_*`` returns None and callers say so.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from dsnet_core.model.card import SHIFT_WEIGHTS, CheckpointError, read_card, sha256_file

MODELS = Path(__file__).resolve().parent / "data" / "models"
BUNDLED_NAME = "tiny-v2"
BUNDLED_4D_NAME = "tiny-v2-4d"
#: bundled MOST models: the accumulated-input one (k = 3) and, when present, a single-scan one
BUNDLED_MOST_NAMES = {3: "most", 1: "most-1"}
BUNDLED_DPLS_NAME = "dpls"
#: bundled C_n-equivariant DS-Net models (Eq-4D), by n
BUNDLED_EQUIVARIANT_NAMES = {4: "tiny-v2-eq4"}


def bundled_dir(scans: int = 1) -> Path:
    """Where the bundled demo checkpoint for ``scans``-scan volumes lives inside the package:
    ``tiny-v2`` (single scans) or ``tiny-v2-4d`` (fine-tuned jointly on 2-scan volumes, used for
    every k > 1)."""
    name = BUNDLED_NAME if scans <= 1 else BUNDLED_4D_NAME
    return MODELS / name


def _is_checkpoint(path: Path) -> bool:
    return (path / "card.json").is_file() and (path / "model.safetensors").is_file()


def bundled_equivariant_checkpoint(n: int) -> Path | None:
    """The bundled C_n-equivariant DS-Net model (``dsnet label --equivariant n`` without
    ``--checkpoint``), or None when none is bundled for ``n``."""
    name = BUNDLED_EQUIVARIANT_NAMES.get(n)
    return None if name is None or not _is_checkpoint(MODELS / name) else MODELS / name


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
    root = MODELS
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
                "PATH; train one with dsnet train dpls)",
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
    from dsnet_core.most.card import read_most_card

    if path is None:
        found = bundled_most_checkpoint(scans)
        if found is None:
            raise CheckpointError(
                bundled_dir().parent,
                "no bundled MOST model: pass a MOST checkpoint (dsnet label --method most --checkpoint "
                "PATH; train one with dsnet train most)",
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
    from dsnet_core.most.card import checkpoint_method, read_most_card

    path = Path(path)
    card = read_most_card(path) if checkpoint_method(path) == "most" else read_card(path)
    h = hashlib.blake2b(digest_size=16)
    h.update(
        json.dumps({k: v for k, v in card.__dict__.items() if k != "code_version"}, sort_keys=True).encode()
    )
    shift = path / SHIFT_WEIGHTS
    h.update(sha256_file(shift).encode() if shift.is_file() else b"no-shift-weights")
    return h.hexdigest()

"""The shifting MLPs' weights next to a DS-Net checkpoint (the bundled models and checkpoint
digests of every method are in :mod:`dsnet_core.checkpoints`).

A checkpoint folder (see :mod:`dsnet_core.model.checkpoint`) may also hold::

    CKPT/shift.safetensors    the dynamic-shifting MLPs (``DynamicShift.state_dict()``), optional;
                              its sha256 is in the card (``shift_sha256``) and checked on load

"""

from __future__ import annotations

from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file

from dsnet_core.model.checkpoint import (
    SHIFT_WEIGHTS,
    CheckpointError,
    check_finite,
    read_card,
    save_tensors,
    sha256_file,
    write_card,
)


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
        state = load_file(str(file))
    except (SafetensorError, OSError) as exc:
        raise CheckpointError(file, f"cannot read the shifting weights: {exc}") from exc
    check_finite(state, file)
    return state

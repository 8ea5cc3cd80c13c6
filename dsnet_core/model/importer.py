"""``import_checkpoint``: a released reference checkpoint → this project's checkpoint folder.

The folder gets ``model.safetensors``, ``shift.safetensors`` (when the file has the shifting MLPs)
and a model card whose ``training_data["imported"]`` names the source file, its sha256 and what was
converted (naming scheme, width, sparse-weight layout, rulebooks, grid convention, counts) and what
was dropped (the reference's training-only buffers, kernel taps). Reading the file is
:mod:`dsnet_core.model.reference_file`, conversion :mod:`dsnet_core.model.reference_convert`.
"""

from __future__ import annotations

from pathlib import Path

from dsnet_core.errors import CheckpointImportError
from dsnet_core.instance.shifting import DynamicShift
from dsnet_core.labels import LabelMap, load_label_map
from dsnet_core.model.bundle import save_shift_weights
from dsnet_core.model.checkpoint import (
    CARD,
    SHIFT_WEIGHTS,
    ModelCard,
    class_map_of,
    save_checkpoint,
    sha256_file,
)
from dsnet_core.model.network import DSNet
from dsnet_core.model.reference_convert import BANDWIDTHS, KINDS, convert_state
from dsnet_core.model.reference_file import load_reference_file

__all__ = ["KINDS", "import_checkpoint"]

_ABOUT = {
    "dsnet": "DS-Net (CVPR 2021) 3D panoptic network with its dynamic-shifting MLPs",
    "dsnet4d": "4D-DS-Net 2-scan panoptic network (label with k = 2) with its dynamic-shifting MLPs",
    "cylinder3d": "Cylinder3D semantic network: semantic head only, the instance head is untrained",
}


def import_checkpoint(
    src: str | Path,
    out: str | Path,
    kind: str,
    layout: str = "auto",
    rulebooks: str = "auto",
    label_map: LabelMap | None = None,
) -> ModelCard:
    """Convert a reference checkpoint file into checkpoint folder ``out``.

    Args:
        src: the released file (DS-Net ``*.pth`` with ``model_state``, or a bare state dict).
        out: checkpoint folder to write (created).
        kind: ``"dsnet"`` (3D, bandwidths 0.2/1.7/3.2 m), ``"dsnet4d"`` (2-scan, 0.2/1.8/3.4 m) or
            ``"cylinder3d"`` (semantic only; the instance head is left untrained, for
            ``dsnet train dsnet --init-from``).
        layout: ``"auto"``, ``"spconv1"`` or ``"spconv2"`` (sparse weights' layout).
        rulebooks: ``"auto"`` (spconv 1.x layout → ``"spconv1-shared"``, 2.x → ``"per-layer"``).
        label_map: the classes the file was trained on (default: SemanticKITTI, both references').

    Returns:
        The written card.

    Raises:
        CheckpointImportError: not a torch file, unsafe or unreadable, keys that do not match,
            non-finite weights, wrong class count.
    """
    src, out = Path(src), Path(out)
    state, info = load_reference_file(src)
    config, weights, shift_state, summary = convert_state(state, kind, src, layout, rulebooks)
    label_map = label_map or load_label_map("semantic-kitti")
    if label_map.num_classes != config.num_classes:
        raise CheckpointImportError(
            src,
            f"{config.num_classes} output classes; the {label_map.name} label map has "
            f"{label_map.num_classes}",
        )
    model = DSNet(config)
    model.load_state_dict(weights, strict=True)
    bandwidths = BANDWIDTHS.get(kind, ())
    summary |= {
        "kind": kind,
        "source_file": src.name,
        "source_sha256": sha256_file(src),
        "top_level_keys": info.get("top_level_keys"),
        "reference_epoch": info.get("epoch"),
        "width": config.width,
        "grid_convention": config.grid.convention,
        "bandwidths": list(bandwidths) if shift_state else [],
        "point_pooling": "max over every point of a voxel (the reference: a random subset of at most 256)",
    }
    card = ModelCard(
        architecture=config.to_dict(),
        class_map=class_map_of(label_map),
        training_data={"description": f"imported: {_ABOUT[kind]}", "imported": summary},
    )
    out.mkdir(parents=True, exist_ok=True)
    # an earlier import's card goes first: until the new card lands (last) the folder holds no
    # checkpoint, never the old card over new weights or the new shifting weights
    for stale in (out / CARD, out / SHIFT_WEIGHTS):
        stale.unlink(missing_ok=True)
    if shift_state:
        iterations = summary["converted"]["shifting_iterations"]
        shift = DynamicShift(bandwidths, iterations=iterations, feature_dim=config.ins_dim)
        shift.load_state_dict(shift_state, strict=True)
        save_shift_weights(out, shift)
    save_checkpoint(out, model, card)
    return card

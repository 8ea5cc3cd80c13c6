"""Export a run store's final labels as Panoptic nuScenes ``.npz`` files.

``OUT/panoptic/<version>/<token>_panoptic.npz`` (array ``data``, uint16 general class * 1000 +
instance, the scan's point order), one per frame; a sequence is a scene, and the token is
``<sequence>-<frame_id>`` (the run store has no nuScenes sample tokens). ``OUT/tokens.json``
lists the tokens by sequence. Plain functions: no Prefect.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from flows.export import final_labels
from storage.run import RunStore


@dataclass
class NuScenesExport:
    """What was written: the folder and, per sequence, the tokens in frame order."""

    folder: Path
    tokens: dict[str, list[str]] = field(default_factory=dict)


def export_nuscenes(
    root: str,
    out: str | Path,
    sequences: list[str] | None = None,
    version: str = "v1.0-trainval",
    storage_options: dict | None = None,
) -> NuScenesExport:
    """Write every frame of every sequence whose labels stage is done.

    Raises:
        StoreError: a requested sequence has no finished labels stage, or none has.
        ExportError: a scene needs more than 999 instances of one class.
    """
    from dsnet_core.io.nuscenes_export import SceneEncoder
    from dsnet_core.metrics import write_panoptic_npz

    store = RunStore(root, storage_options)
    folder = Path(out) / "panoptic" / version
    result = NuScenesExport(folder)
    encoders: dict[str, SceneEncoder] = {}
    for seq, frame_id, label in final_labels(store, sequences):
        if seq not in encoders:
            encoders[seq] = SceneEncoder(seq)
        tokens = result.tokens.setdefault(seq, [])
        if label is None:
            continue
        token = f"{seq}-{frame_id}"
        write_panoptic_npz(folder / f"{token}_panoptic.npz", encoders[seq].encode(label))
        tokens.append(token)
    folder.mkdir(parents=True, exist_ok=True)
    (Path(out) / "tokens.json").write_text(json.dumps(result.tokens, indent=1))
    return result

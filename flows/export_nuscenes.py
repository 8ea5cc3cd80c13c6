"""Export a run store's final labels (stage ``stitch``) as Panoptic nuScenes ``.npz`` files.

``OUT/panoptic/<version>/<token>_panoptic.npz`` (array ``data``, uint16 general class * 1000 +
instance, the scan's point order), one per frame; a sequence is a scene, and the token is
``<sequence>-<frame_id>`` (the run store has no nuScenes sample tokens). ``OUT/tokens.json``
lists the tokens by sequence. Plain functions: no Prefect.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from storage.errors import StoreError
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
    """Write every frame of every sequence whose ``stitch`` stage is done.

    Raises:
        StoreError: a requested sequence has no finished ``stitch``, or none has.
        ExportError: a scene needs more than 999 instances of one class.
    """
    from dsnet_core.io.nuscenes_export import SceneEncoder
    from dsnet_core.metrics import write_panoptic_npz

    store = RunStore(root, storage_options)
    folder = Path(out) / "panoptic" / version
    result = NuScenesExport(folder)
    for seq in sorted(sequences if sequences is not None else store.sequences()):
        m = store.read_manifest(seq, "stitch")
        if m is None or m.status != "done":
            if sequences is not None:
                raise StoreError(store.root.url(store.stage_rel(seq, "stitch")), "stage 'stitch' is not done")
            continue
        ids = store.read_table(seq, "ingest", "frames")["frame_id"].to_pylist()
        arrays = store.arrays(seq, "stitch")
        done = arrays.done()
        encoder = SceneEncoder(seq)
        result.tokens[seq] = []
        for index, frame_id in enumerate(ids):
            if not done[index]:
                continue
            token = f"{seq}-{frame_id}"
            label = arrays.read_item(index, ["label"])["label"]
            write_panoptic_npz(folder / f"{token}_panoptic.npz", encoder.encode(label))
            result.tokens[seq].append(token)
    if not result.tokens:
        raise StoreError(store.uri, "no sequence has a finished 'stitch' stage to export")
    folder.mkdir(parents=True, exist_ok=True)
    (Path(out) / "tokens.json").write_text(json.dumps(result.tokens, indent=1))
    return result

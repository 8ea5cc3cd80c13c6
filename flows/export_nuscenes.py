"""Export a nuScenes log's run as results nuscenes-devkit's evaluators read, keyed by the log's own
sample_data tokens (the frame ids of the run's frame table)::

    OUT/lidarseg/<split>/<sample_data token>_lidarseg.bin    uint8 challenge class (1..16)
    OUT/panoptic/<split>/<sample_data token>_panoptic.npz    uint16 challenge class * 1000 + instance
    OUT/<split>/submission.json                              {"meta": {"use_lidar": true, ...}}

The devkit's lidarseg and panoptic evaluators (``--result_path OUT --eval_set <split>``) look
for exactly these paths. Classes: the model's classes -> nuScenes general classes through the
recorded class mapping (``semantic-kitti-to-panoptic-nuscenes.yaml``) -> challenge classes
(:class:`dsnet_core.io.nuscenes_export.SceneEncoder`, instances renumbered 1..999 per class and
scene in order of appearance). Only a run of a nuScenes log has the tokens. Plain functions: no
Prefect.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from flows.export import final_labels
from storage.run import RunStore

SUBMISSION_META = {
    "use_camera": False,
    "use_lidar": True,
    "use_radar": False,
    "use_map": False,
    "use_external": False,
}


@dataclass
class NuScenesExport:
    """What was written: the results root, the split folder name, per scene the tokens written in
    frame order and the tokens without a final label (quarantined frames), and the class mapping."""

    out: Path
    split: str
    tokens: dict[str, list[str]] = field(default_factory=dict)
    missing: dict[str, list[str]] = field(default_factory=dict)
    mapping: dict[str, object] = field(default_factory=dict)


def model_label_map(store: RunStore):
    """The label map the run's model predicts in (its card's class map, from the run's model stage).

    Raises:
        StoreError: no sequence of the run recorded a model class map.
    """
    from dsnet_core.labels import label_map_from_class_map
    from flows.report.merge import model_plan
    from storage.errors import StoreError
    from tasks.base import CLASS_MAP
    from tasks.run_config import read_run

    plan = model_plan(store, read_run(store).pipeline(), sorted(store.sequences()))
    if CLASS_MAP not in plan:
        raise StoreError(store.uri, "no stage of this run recorded the model's class map")
    return label_map_from_class_map(plan[CLASS_MAP])


def export_nuscenes(
    root: str,
    out: str | Path,
    sequences: list[str] | None = None,
    split: str = "val",
    storage_options: dict | None = None,
) -> NuScenesExport:
    """Write the results of every scene whose labels stage is done.

    Args:
        split: the devkit's ``eval_set`` folder name (``val``, ``mini_val``, ``test``...).

    Raises:
        ExportError: the run's log is not a nuScenes log, or a scene needs more than 999 instances
            of one class.
        ConfigError: no class mapping from the model's classes to Panoptic nuScenes.
        StoreError: a requested scene has no finished labels stage, or none has.
    """
    from dsnet_core.io.nuscenes_export import ExportError, SceneEncoder
    from dsnet_core.label_mapping import class_mapping
    from dsnet_core.labels import load_label_map
    from dsnet_core.metrics import write_panoptic_npz

    store = RunStore(root, storage_options)
    from tasks.run_config import read_run

    run = read_run(store)
    if run.format != "nuscenes":
        raise ExportError(
            f"{store.uri}: the run labelled a {run.format} log; nuScenes results are "
            "keyed by sample_data tokens, which only a nuscenes log has (export it in its own format)"
        )
    model = model_label_map(store)
    result = NuScenesExport(
        Path(out), split, mapping=class_mapping(model, load_label_map("panoptic-nuscenes")).record()
    )
    lidarseg, panoptic = result.out / "lidarseg" / split, result.out / "panoptic" / split
    encoders: dict[str, SceneEncoder] = {}
    for scene, token, label in final_labels(store, sequences):
        if scene not in encoders:
            encoders[scene] = SceneEncoder(scene, source=model, classes="challenge")
        tokens, missing = result.tokens.setdefault(scene, []), result.missing.setdefault(scene, [])
        if label is None:
            missing.append(token)
            continue
        pan = encoders[scene].encode(label)
        write_panoptic_npz(panoptic / f"{token}_panoptic.npz", pan)
        lidarseg.mkdir(parents=True, exist_ok=True)
        (pan // 1000).astype(np.uint8).tofile(lidarseg / f"{token}_lidarseg.bin")
        tokens.append(token)
    meta = result.out / split / "submission.json"
    meta.parent.mkdir(parents=True, exist_ok=True)
    meta.write_text(json.dumps({"meta": SUBMISSION_META}, indent=1) + "\n")
    return result


def nuscenes_lines(result: NuScenesExport) -> list[str]:
    """What ``dsnet export --format nuscenes`` prints: per scene the files, the mapping, where."""
    out = []
    for scene, tokens in result.tokens.items():
        line = f"scene {scene}: {len(tokens)} lidarseg and panoptic files"
        missing = result.missing[scene]
        if missing:
            line += f" ({len(missing)} sample_data without a label: {', '.join(missing[:3])})"
        out.append(line)
    out.append(f"class mapping {result.mapping['file']} (model classes -> nuScenes challenge classes)")
    out.append(
        f"wrote nuScenes results to {result.out.resolve()} "
        f"(devkit: --result_path OUT --eval_set {result.split})"
    )
    return out

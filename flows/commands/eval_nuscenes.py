"""``dsnet eval --gt NUSCENES_LOG``: a nuScenes log's labels scored against its own Panoptic nuScenes
ground truth, in the nuScenes metrics (:class:`dsnet_core.metrics.nuscenes_scorer.NuScenesScorer`).

Predictions are read from either layout ``dsnet export`` writes for a nuScenes run:

* nuScenes results (``PRED/panoptic/<split>/<sample_data token>_panoptic.npz``, challenge classes,
  what the devkit reads): scored as they are;
* SemanticKITTI predictions (``PRED/sequences/<scene>/predictions/<token>.label``, the model's
  classes): taken to the nuScenes classes through the class mapping in package data.

Either way the scores cover all 16 challenge classes and the classes the model's label map
(``--data-config``, default semantic-kitti) can express through its mapping.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def score_nuscenes(
    gt: Path,
    pred: Path,
    sequences: list[str] | None = None,
    data_config: Path | None = None,
    split: str | None = None,
    reader_options: dict | None = None,
):
    """Score every keyframe with ground truth of the log's scenes (or ``sequences``), in time order.

    Returns:
        the :class:`~dsnet_core.metrics.nuscenes_scorer.NuScenesScorer`.

    Raises:
        LabelFormatError: a prediction file is missing or does not fit its scan (named).
        ConfigError: no class mapping from the model's label map to Panoptic nuScenes.
        ValueError: ``pred`` holds neither layout, or several splits and none chosen.
    """
    from dsnet_core.errors import LabelFormatError
    from dsnet_core.io.formats import open_log
    from dsnet_core.io.kitti import read_label
    from dsnet_core.labels import load_label_map
    from dsnet_core.metrics import read_panoptic_npz
    from dsnet_core.metrics.scoring import make_scorer

    reader = open_log(gt, "nuscenes", reader_options)
    model = load_label_map(data_config or "semantic-kitti")
    scorer = make_scorer(reader.label_map, model)
    results = _results_folder(pred, split)
    scenes = sequences or reader.sequences()
    for scene in scenes:
        for ref in reader.frames(scene):
            truth = reader.labels(ref)
            if truth is None:
                continue
            if results is not None:
                path = results / f"{ref.frame_id}_panoptic.npz"
                if not path.is_file():
                    raise LabelFormatError(path, f"no prediction for sample_data {ref.frame_id} of {scene}")
                p = read_panoptic_npz(path).astype(np.int64)
                _check_size(path, p, truth)
                scorer.add_challenge(truth, p // 1000, p % 1000, frame=ref.frame_id, sequence=scene)
            else:
                path = pred / "sequences" / scene / "predictions" / f"{ref.frame_id}.label"
                if not path.is_file():
                    raise LabelFormatError(path, f"no prediction for sample_data {ref.frame_id} of {scene}")
                scorer.add(truth, read_label(path, truth.shape[0]), frame=ref.frame_id, sequence=scene)
    return scorer


def _results_folder(pred: Path, split: str | None) -> Path | None:
    """``PRED/panoptic/<split>`` for nuScenes results, None for SemanticKITTI predictions."""
    pred = Path(pred)
    if (pred / "panoptic").is_dir():
        splits = sorted(p.name for p in (pred / "panoptic").iterdir() if p.is_dir())
        if split is None:
            if len(splits) != 1:
                raise ValueError(
                    f"{pred / 'panoptic'} holds splits {splits or 'none'}: choose one with --split"
                )
            split = splits[0]
        if split not in splits:
            raise ValueError(f"{pred / 'panoptic'} has no split {split!r} (found {', '.join(splits)})")
        return pred / "panoptic" / split
    if (pred / "sequences").is_dir():
        return None
    raise ValueError(
        f"{pred}: neither nuScenes results (panoptic/<split>/) nor SemanticKITTI predictions (sequences/)"
    )


def _check_size(path: Path, pred: np.ndarray, truth: np.ndarray) -> None:
    from dsnet_core.errors import LabelFormatError

    if pred.shape[0] != truth.shape[0]:
        raise LabelFormatError(path, f"has {pred.shape[0]} labels but the scan has {truth.shape[0]} points")


def print_nuscenes(scorer) -> None:
    """Every registered metric's values over all 16 challenge classes (the ``expressible`` ones over
    the classes the model can express), then per class, then the mapping."""
    from rich.console import Console

    from flows.commands.eval_print import print_scores

    res = scorer.result()
    names = scorer.spec.names
    title = f"Panoptic nuScenes ({res.frames} frames, min points {scorer.min_points})"
    print_scores(title, res.values, res.classes, frozenset(names[c] for c in scorer.unexpressible))
    m, expressible = scorer.mapping.record(), [names[c] for c in scorer.expressible.spec.include]
    console = Console(width=140)
    console.print(f"all ({len(scorer.spec.include)}): the challenge classes")
    console.print(
        f"expressible ({len(expressible)}): those the model's classes can name ({', '.join(expressible)})"
    )
    console.print(f"class mapping: {m['file']} (sha256 {m['sha256'][:12]})")

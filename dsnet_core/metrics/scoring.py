"""One factory for the scorer of a (model label map, ground-truth label map) pair.

* The same map on both sides: :class:`~.evaluator.PanopticEvaluator` (SemanticKITTI semantics:
  PQ family, mIoU, LSTQ of 4D-PLS), predictions scored as they are.
* Different maps: the explicit class mapping between them (package data, by the pair of names:
  :func:`dsnet_core.label_mapping.class_mapping`; none is a ConfigError), and the ground truth's
  benchmark: :class:`~.nuscenes_scorer.NuScenesScorer` for ``panoptic-nuscenes``.

The score stage, ``dsnet eval`` and the report build scorers only here, and save and restore their
accumulator states through :func:`scorer_state` / :func:`restore_scorer`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from dsnet_core.errors import ConfigError
from dsnet_core.label_mapping import class_mapping
from dsnet_core.labels import LabelMap

from .evaluator import PanopticEvaluator
from .nuscenes_scorer import NuScenesScorer
from .report import Mode

Scorer = PanopticEvaluator | NuScenesScorer


def same_map(a: LabelMap, b: LabelMap) -> bool:
    """True when two label maps name the same classes with the same raw ids."""
    return a.name == b.name and a.learning_map_inv == b.learning_map_inv


def make_scorer(
    gt: LabelMap, model: LabelMap, mode: Mode | str = Mode.OFFICIAL, min_points: int | None = None
) -> Scorer:
    """The scorer of predictions in ``model``'s classes against ground truth in ``gt``'s.

    Args:
        mode: ``official`` or ``corrected`` (Panoptic nuScenes has only ``official``: its labels
            never reach the reference's overflow, see ``docs/metrics.md``).
        min_points: minimum segment size (default: the ground truth's map's, 50 or 15).

    Raises:
        ConfigError: the maps differ and no mapping, or no scorer, exists for the pair.
    """
    if same_map(model, gt):
        return PanopticEvaluator(gt, min_points=min_points, mode=mode, keep_rows=False)
    mapping = class_mapping(model, gt)
    if gt.name == "panoptic-nuscenes":
        return NuScenesScorer(gt, mapping, gt.min_points if min_points is None else min_points)
    raise ConfigError(
        f"ground truth in {gt.name!r}: no scorer for it with predictions in {model.name!r} classes"
    )


def describe_scorer(scorer: Scorer) -> dict[str, Any]:
    """What a run records of how it scored: the metric family, min_points, the class mapping and
    the metrics computed (the registry's that apply)."""
    mapping = scorer.mapping
    return {
        "metric": scorer.label_map.name,
        "min_points": scorer.min_points,
        "mapping": mapping.record() if mapping is not None else None,
        "metrics": [m.name for m in scorer.metrics.metrics()],
    }


def scorer_state(scorer: Scorer) -> dict[str, np.ndarray]:
    """A scorer's accumulator state as named arrays (``np.savez`` ready): its ``state()``."""
    return scorer.state()


def restore_scorer(fresh: Scorer, state: dict[str, np.ndarray]) -> Scorer:
    """``fresh`` (a new scorer with the same maps and settings) holding ``state``, ready to merge.

    Raises:
        ValueError: the state's layout (one from before the metric registry), metrics, kind or
            settings do not fit: score the frames again.
    """
    return fresh.restore(state)

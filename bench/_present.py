"""Means over the classes present, beside the official means.

The official mIoU and PQ average over every evaluated class and count a class the ground truth
lacks as 0 (SemanticKITTI's ``evaluate_panoptic.py``). On a log that lacks classes (PandaSet lacks
9 of the 19) that caps the official mean below 1 whatever the labels; the present-class mean
averages only the classes that are there.

Rule: a class is **present** in a cell when the cell's ground truth has at least one point of it
(the ground-truth column of the official-mode confusion matrix is non-zero; ignored classes, e.g.
``unlabeled``, are never counted). The same rule serves IoU and PQ. When the metric registry of
``dsnet_core.metrics`` offers present-class means, this module can be switched to it.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np


def gt_points(conf: np.ndarray, names: list[str]) -> dict[str, int]:
    """Ground-truth points per class of a ``(C, C)`` ``conf[pred, gt]`` matrix (class 0 ignored)."""
    conf = np.asarray(conf)
    return {names[g]: int(conf[:, g].sum()) for g in range(1, conf.shape[1])}


def present_classes(points: Mapping[str, int]) -> list[str]:
    """The classes with ground-truth points, in ``points``' order."""
    return [name for name, n in points.items() if n > 0]


def present_mean(per_class: Mapping[str, float | None], points: Mapping[str, int]) -> float:
    """Mean of ``per_class`` (class name → IoU or PQ) over the classes present (``points`` > 0).

    Raises:
        KeyError: a present class has no score in ``per_class``.
    """
    present = present_classes(points)
    if not present:
        return float("nan")
    missing = [c for c in present if per_class.get(c) is None]
    if missing:
        raise KeyError(f"no score for present classes {missing}")
    return float(np.mean([per_class[c] for c in present]))


def present_scores(scores: Mapping) -> dict:
    """``miou_present``, ``pq_present``, ``pq_things_present``, ``pq_stuff_present`` and the
    ``absent`` class names of one bench_methods result's ``scores`` (its ``class_iou``,
    ``class_pq``, ``class_things``, ``confusion`` and ``class_names``)."""
    points = gt_points(np.asarray(scores["confusion"]), list(scores["class_names"]))
    points = {c: n for c, n in points.items() if c in scores["class_iou"]}  # evaluated classes only
    things = set(scores.get("class_things", ()))
    out = {
        "miou_present": present_mean(scores["class_iou"], points),
        "absent": [c for c, n in points.items() if n == 0],
    }
    if "class_pq" in scores:
        out["pq_present"] = present_mean(scores["class_pq"], points)
        out["pq_things_present"] = present_mean(
            scores["class_pq"], {c: n for c, n in points.items() if c in things}
        )
        out["pq_stuff_present"] = present_mean(
            scores["class_pq"], {c: n for c, n in points.items() if c not in things}
        )
    return out

"""Frame confidence of a run, with or without ground truth: one row per labelled frame with the
terms of :func:`dsnet_core.review.confidence.frame_confidence` and their product.

A frame is judged on the volume that owns its label (the first volume containing it, the stitch
stage's ownership rule): the winning-class probability of its points, the agreement and size of
the instances it holds, and the weakest link IoU of its tracks, each read from the stage that
declares it (:mod:`tasks.confidence`; no stage is named here), so every method that declares
probabilities or instances, MOST included, gets rows.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from storage.run import RunStore
from tasks.confidence import confidence_sources, sequence_confidence
from tasks.pipeline import Pipeline


@dataclass
class ConfidencePass:
    """What one read of the model's probabilities gives.

    Attributes:
        rows: ``frame_confidence`` rows, lowest score first.
        classes: per sequence, ``(points (C,) int64, sum of winning-class probability (C,) float64)``
            over the points the model predicted as each class (train id), each frame counted once.
    """

    rows: list[dict[str, Any]] = field(default_factory=list)
    classes: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


def frame_confidence_rows(store: RunStore, pipeline: Pipeline, sequences: list[str]) -> list[dict[str, Any]]:
    """Rows (sequence, index, frame_id, the four terms, score, instances, points), lowest score first."""
    return confidence_pass(store, pipeline, sequences).rows


def confidence_pass(store: RunStore, pipeline: Pipeline, sequences: list[str]) -> ConfidencePass:
    """Frame confidence rows and per-class model confidence of every finished sequence (empty for a
    method that declares nothing to judge a frame on: :func:`tasks.confidence.confidence_sources`)."""
    out = ConfidencePass()
    sources = confidence_sources(pipeline)
    for seq in sequences:
        found = sequence_confidence(store, pipeline, seq, sources)
        if found is None:
            continue
        out.rows += found[0]
        out.classes[seq] = found[1]
    out.rows.sort(key=lambda r: (r["score"], r["sequence"], r["index"]))
    return out

"""Frame confidence of a run, with or without ground truth: one row per labelled frame with the
terms of :func:`dsnet_core.review.confidence.frame_confidence` and their product.

A frame is judged on the volume that owns its label (the first volume containing it, the stitch
stage's ownership rule): the winning-class probability of its points (``infer``), the agreement and
size of the instances it holds (``fuse``), and the weakest link IoU of its tracks (``stitch``).
Only the DS-Net stages' declared arrays and tables are read; a method without them gets no rows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from storage.run import RunStore
from tasks.pipeline import Pipeline

NEEDED = ("align", "infer", "fuse")  # and the labels stage; stitch's link IoUs where it is that stage


def _needed(pipeline: Pipeline) -> tuple[str, ...]:
    """:data:`NEEDED` with the stage fuse reads in place of ``infer`` (``dpls`` for D-PLS)."""
    source = getattr(pipeline["fuse"], "source", "infer") if "fuse" in pipeline else "infer"
    return tuple(source if n == "infer" else n for n in NEEDED)


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
    method without the stages of :data:`NEEDED`)."""
    out = ConfidencePass()
    needed = _needed(pipeline)
    if any(name not in pipeline.names() for name in (*needed, "ingest")):
        return out
    for seq in sequences:
        manifests = [store.read_manifest(seq, s) for s in (*needed, pipeline.labels)]
        if any(m is None or m.status != "done" for m in manifests):
            continue
        rows, classes = _sequence_rows(store, pipeline, seq)
        out.rows += rows
        out.classes[seq] = classes
    out.rows.sort(key=lambda r: (r["score"], r["sequence"], r["index"]))
    return out


def _sequence_rows(
    store: RunStore, pipeline: Pipeline, seq: str
) -> tuple[list[dict[str, Any]], tuple[np.ndarray, np.ndarray]]:
    from dsnet_core.review.confidence import frame_confidence
    from tasks.infer import dequantise_probs

    frames = store.read_table(seq, pipeline["ingest"].table("frames")).to_pydict()
    frame_ids = dict(zip(frames["index"], frames["frame_id"], strict=True))
    inst_t = store.read_table(seq, pipeline["fuse"].table("instances")).to_pydict()
    agreement = {
        (v, i): a for v, i, a in zip(inst_t["index"], inst_t["id"], inst_t["agreement"], strict=True)
    }
    links: dict[int, list[float]] = {}  # a tracked run has no link IoUs: that term is 1
    if "stitch" in pipeline:
        tracks = store.read_table(seq, pipeline["stitch"].table("tracks")).to_pydict()
        for fr, iou in zip(tracks["frames"], tracks["min_link_iou"], strict=True):
            for f in fr:
                links.setdefault(int(f), []).append(math.nan if iou is None else float(iou))
    align = store.arrays(seq, pipeline["align"].contract)
    infer = store.arrays(seq, pipeline[_needed(pipeline)[1]].contract)
    fuse = store.arrays(seq, pipeline["fuse"].contract)
    owned: set[int] = set()
    rows = []
    class_points = np.zeros(0, np.int64)
    class_sum = np.zeros(0, np.float64)
    for v in range(align.n_items):
        src = align.read_item(v, ["source_frame"])["source_frame"]
        new = [int(f) for f in np.unique(src) if int(f) not in owned]
        if not new:
            continue
        model = infer.read_item(v, ["sem", "probs"])
        probs = dequantise_probs(model["probs"]).max(axis=1)
        sem = model["sem"].astype(np.int64)
        if class_points.size < model["probs"].shape[1]:
            class_points = np.zeros(model["probs"].shape[1], np.int64)
            class_sum = np.zeros(model["probs"].shape[1], np.float64)
        inst = fuse.read_item(v, ["inst"])["inst"]
        for f in new:
            owned.add(f)
            sel = src == f
            class_points += np.bincount(sem[sel], minlength=class_points.size)[: class_points.size]
            class_sum += np.bincount(sem[sel], weights=probs[sel], minlength=class_sum.size)[: class_sum.size]
            ids, counts = np.unique(inst[sel & (inst > 0)], return_counts=True)
            agree = np.array([agreement.get((v, int(i)), math.nan) for i in ids], dtype=np.float64)
            ok = np.isfinite(agree)
            c = frame_confidence(probs[sel], counts[ok], agree[ok], np.asarray(links.get(f, []), np.float64))
            rows.append(
                {
                    "sequence": seq,
                    "index": f,
                    "frame_id": str(frame_ids.get(f, f)),
                    **{k: float(getattr(c, k)) for k in ("semantic", "agreement", "size", "stitch", "score")},
                    "n_instances": c.n_instances,
                    "n_points": int(sel.sum()),
                }
            )
    return rows, (class_points, class_sum)

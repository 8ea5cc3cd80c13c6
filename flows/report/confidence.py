"""Frame confidence of a run, with or without ground truth: one row per labelled frame with the
terms of :func:`dsnet_core.review.confidence.frame_confidence` and their product.

A frame is judged on the volume that owns its label (the first volume containing it, the stitch
stage's ownership rule): the winning-class probability of its points (``infer``), the agreement and
size of the instances it holds (``fuse``), and the weakest link IoU of its tracks (``stitch``).
Only the DS-Net stages' declared arrays and tables are read; a method without them gets no rows.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from storage.run import RunStore
from tasks.pipeline import Pipeline

NEEDED = ("align", "infer", "fuse")  # and the labels stage; stitch's link IoUs where it is that stage


def _needed(pipeline: Pipeline) -> tuple[str, ...]:
    """:data:`NEEDED` with the stage fuse reads in place of ``infer`` (``dpls`` for D-PLS)."""
    source = getattr(pipeline["fuse"], "source", "infer") if "fuse" in pipeline else "infer"
    return tuple(source if n == "infer" else n for n in NEEDED)


def frame_confidence_rows(store: RunStore, pipeline: Pipeline, sequences: list[str]) -> list[dict[str, Any]]:
    """Rows (sequence, index, frame_id, the four terms, score, instances, points), lowest score first."""
    needed = _needed(pipeline)
    if any(name not in pipeline.names() for name in (*needed, "ingest")):
        return []
    rows = []
    for seq in sequences:
        manifests = [store.read_manifest(seq, s) for s in (*needed, pipeline.labels)]
        if any(m is None or m.status != "done" for m in manifests):
            continue
        rows += _sequence_rows(store, pipeline, seq)
    rows.sort(key=lambda r: (r["score"], r["sequence"], r["index"]))
    return rows


def _sequence_rows(store: RunStore, pipeline: Pipeline, seq: str) -> list[dict[str, Any]]:
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
    for v in range(align.n_items):
        src = align.read_item(v, ["source_frame"])["source_frame"]
        new = [int(f) for f in np.unique(src) if int(f) not in owned]
        if not new:
            continue
        probs = dequantise_probs(infer.read_item(v, ["probs"])["probs"]).max(axis=1)
        inst = fuse.read_item(v, ["inst"])["inst"]
        for f in new:
            owned.add(f)
            sel = src == f
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
    return rows

"""Frame confidence of any method's run, from what its stages declare (no stage is named).

The terms of :func:`dsnet_core.review.confidence.frame_confidence` come from the stages at or
upstream of the pipeline's labels stage that declare them (:func:`confidence_sources`):

- ``semantic``: a stage declaring infer's class probabilities :data:`PROBS` and a ``sem`` array
  (DS-Net's ``infer``, D-PLS's ``dpls``, or any method's own stage); without one the term is 1;
- ``agreement`` and ``size``: a stage declaring an ``inst`` array (volume- or frame-local instance
  ids) and a table with the ``item`` and ``id`` roles and an ``agreement`` role (DS-Net's fusion
  vote) or else a ``confidence`` role (MOST's detection score);
- ``stitch``: a table declaring the ``frames`` and ``link_iou`` roles (``stitch``'s tracks); 1 without.

Per-frame values of volume stages come through :class:`tasks.frames.FrameValues` (a frame is judged
on the volume that owns it). A method declaring neither probabilities nor instances gets no rows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from storage.contract import TableSpec
from storage.run import RunStore
from tasks.frames import FrameValues, nearest
from tasks.infer import InferStage
from tasks.pipeline import Pipeline

PROBS = next(a for a in InferStage.arrays if a.name == "probs")
"""The declaration of per-point class probabilities (uint8 ``q / 255``)."""
LINK_ROLES = ("frames", "link_iou")
"""The roles of a track table whose rows carry the frames a track is in and its weakest link IoU."""


@dataclass(frozen=True)
class ConfidenceSources:
    """Where a pipeline's frame confidence terms come from (stage names, found by declaration).

    Attributes:
        probs: the stage declaring :data:`PROBS` and ``sem`` (None: no semantic term).
        instances: the stage declaring ``inst``, and its table with ``item``/``id`` roles.
        instance_table: that table; ``instance_role``: ``agreement`` or ``confidence``.
        links: the stage and table declaring :data:`LINK_ROLES` (None: no stitch term).
    """

    probs: str | None
    instances: str | None
    instance_table: TableSpec | None
    instance_role: str | None
    links: tuple[str, TableSpec] | None

    def stages(self) -> list[str]:
        out = [self.probs, self.instances, self.links[0] if self.links else None]
        return [s for s in out if s is not None]


def _instance_table(spec) -> tuple[TableSpec, str] | None:
    for role in ("agreement", "confidence"):
        for table in spec.tables:
            if table.role("item") and table.role("id") and table.role(role):
                return table, role
    return None


def confidence_sources(pipeline: Pipeline) -> ConfidenceSources:
    """The declarations of ``pipeline`` its frame confidence reads (nearest the labels stage first)."""
    names = [*pipeline.upstream_closure(pipeline.labels), pipeline.labels]
    probs = nearest(pipeline, pipeline.labels, (PROBS,), itself=True)
    if probs is not None and "sem" not in {a.name for a in pipeline[probs].arrays}:
        probs = None
    instances = table = role = None
    for name in reversed(names):
        spec = pipeline[name]
        found = _instance_table(spec)
        if "inst" in {a.name for a in spec.arrays} and found is not None:
            instances, (table, role) = name, found
            break
    links = next(
        ((n, t) for n in reversed(names) for t in pipeline[n].tables if all(t.role(r) for r in LINK_ROLES)),
        None,
    )
    return ConfidenceSources(probs, instances, table, role, links)


def sequence_confidence(
    store: RunStore, pipeline: Pipeline, seq: str, sources: ConfidenceSources | None = None
) -> tuple[list[dict[str, Any]], tuple[np.ndarray, np.ndarray]] | None:
    """One finished sequence's frame rows (sequence, index, frame_id, the four terms, score,
    n_instances, n_points) and per-class ``(points (C,) int64, sum of winning probability (C,))``
    over the points each class was predicted for; None when a stage it reads is not done or the
    method declares nothing to judge a frame on."""
    from dsnet_core.review.confidence import frame_confidence
    from tasks.infer import dequantise_probs

    sources = sources or confidence_sources(pipeline)
    if sources.probs is None and sources.instances is None:
        return None
    for name in ("ingest", *sources.stages(), pipeline.labels):
        m = store.read_manifest(seq, name)
        if m is None or m.status != "done":
            return None
    frames_t = store.read_table(seq, pipeline["ingest"].table("frames")).to_pydict()
    frame_ids = dict(zip(frames_t["index"], frames_t["frame_id"], strict=True))
    values = FrameValues.near(store, pipeline, seq, pipeline.labels)
    if values.mapping is not None:
        frames = values.frames()
    else:
        frames = np.flatnonzero(store.arrays(seq, pipeline[pipeline.labels].contract).done()).tolist()
    agreement: dict[tuple[int, int], float] = {}
    if sources.instances is not None:
        t = store.read_table(seq, sources.instance_table).to_pydict()
        cols = [sources.instance_table.role(r) for r in ("item", "id", sources.instance_role)]
        agreement = {(v, i): a for v, i, a in zip(*(t[c] for c in cols), strict=True)}
    links: dict[int, list[float]] = {}
    if sources.links is not None:
        table = sources.links[1]
        t = store.read_table(seq, table).to_pydict()
        for fr, iou in zip(*(t[table.role(r)] for r in LINK_ROLES), strict=True):
            for f in fr:
                links.setdefault(int(f), []).append(math.nan if iou is None else float(iou))
    probs_a = None if sources.probs is None else store.arrays(seq, pipeline[sources.probs].contract)
    inst_a = None if sources.instances is None else store.arrays(seq, pipeline[sources.instances].contract)
    inst_frames = inst_a is not None and inst_a.contract.item == "frame"
    rows = []
    class_points = np.zeros(0, np.int64)
    class_sum = np.zeros(0, np.float64)
    for f in frames:
        n = 0
        probs = np.zeros(0, np.float64)
        if probs_a is not None:
            model = values.frame(probs_a, f, ["sem", "probs"])
            if model is None:
                continue
            probs = dequantise_probs(model["probs"]).max(axis=1)
            sem = model["sem"].astype(np.int64)
            if class_points.size < model["probs"].shape[1]:
                class_points = np.zeros(model["probs"].shape[1], np.int64)
                class_sum = np.zeros(model["probs"].shape[1], np.float64)
            class_points += np.bincount(sem, minlength=class_points.size)[: class_points.size]
            class_sum += np.bincount(sem, weights=probs, minlength=class_sum.size)[: class_sum.size]
            n = int(sem.shape[0])
        ids = counts = agree = np.zeros(0)
        if inst_a is not None:
            found = values.frame(inst_a, f, ["inst"])
            if found is None:
                continue
            inst = found["inst"]
            n = int(inst.shape[0])
            item = f if inst_frames else values.owner[f]
            ids, counts = np.unique(inst[inst > 0], return_counts=True)
            agree = np.array([agreement.get((item, int(i)), math.nan) for i in ids], dtype=np.float64)
        ok = np.isfinite(agree)
        c = frame_confidence(probs, counts[ok], agree[ok], np.asarray(links.get(f, []), np.float64))
        rows.append(
            {
                "sequence": seq,
                "index": int(f),
                "frame_id": str(frame_ids.get(f, f)),
                **{k: float(getattr(c, k)) for k in ("semantic", "agreement", "size", "stitch", "score")},
                "n_instances": c.n_instances,
                "n_points": n,
            }
        )
    return rows, (class_points, class_sum)


def model_stage(pipeline: Pipeline) -> str | None:
    """The stage whose plan names the labels' model checkpoint: the semantic source, else the
    instance source (by declaration, :func:`confidence_sources`)."""
    sources = confidence_sources(pipeline)
    return sources.probs or sources.instances

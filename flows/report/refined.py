"""Refinement judged against ground truth: the temporal stage's labels (what ``refine`` read) scored
like the score stage scores the refined ones, so every number has a before and an after.

The score stage scores the method's final labels — the refined ones when ``refine`` ran. Here the
same scorer (the score stage's recorded config, the same frames) runs over the labels of the stage
refine read, per sequence; sequence-, class- and run-level numbers come from merged accumulators,
as in :mod:`flows.report.merge`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from dsnet_core.labels import LabelMap
from dsnet_core.metrics.scoring import Scorer
from storage.run import RunStore
from tasks.base import labels_contract
from tasks.pipeline import Pipeline
from tasks.refine import RefineStage
from tasks.run_config import RunConfig
from tasks.score import ScoreConfig, ScoreStage, make_evaluator

SCORE = ScoreStage.name


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def before_evaluators(
    store: RunStore,
    pipeline: Pipeline,
    run: RunConfig,
    sequences: list[str],
    gt_map: LabelMap,
    model_map: LabelMap | None,
) -> dict[str, Scorer]:
    """Per scored sequence whose final labels are a finished refine stage's, a scorer of the labels
    refine read, over the frames the score stage scored (empty when refine is not the labels stage).
    """
    stage = pipeline[pipeline.labels]
    if not isinstance(stage, RefineStage) or SCORE not in pipeline:
        return {}
    reader = None
    out = {}
    for seq in sequences:
        score, refine = store.read_manifest(seq, SCORE), store.read_manifest(seq, stage.name)
        if score is None or score.status != "done" or not score.n_items:
            continue
        if refine is None or refine.status != "done":
            continue
        reader = reader or run.open_log()
        refs = reader.frames(seq)
        ev = make_evaluator(ScoreConfig.model_validate(score.config), gt_map, model_map)
        arrays = store.arrays(seq, labels_contract(stage.labels))
        for index, fid in zip(score.plan["frames"], score.plan["frame_ids"], strict=True):
            pred = np.asarray(arrays.read_item(index, ["label"])["label"], np.uint32)
            ev.add(reader.labels(refs[index]), pred, frame=fid, sequence=seq)
        out[seq] = ev
    return out


def refine_score_rows(
    before: dict[str, Scorer],
    seq_rows: list[dict[str, Any]],
    class_rows: list[dict[str, Any]],
    run_row: dict[str, Any],
) -> list[dict[str, Any]]:
    """``refine_scores`` rows: run, then per sequence, then per class, before (``before``) and after
    (the score report's rows of the refined labels)."""
    if not before:
        return []
    after_seq = {r["sequence"]: r for r in seq_rows}
    rows = []
    results = {seq: ev.result() for seq, ev in before.items()}  # before merging: merge mutates
    total: Scorer | None = None
    for ev in before.values():
        total = ev if total is None else total.merge(ev)
    res = total.result()
    rows.append(_row("run", "", -1, res, run_row))
    for seq, r in results.items():
        rows.append(_row("sequence", seq, -1, r, after_seq.get(seq, {})))
    for c in class_rows:
        pc = res.panoptic.per_class[c["class"]]
        rows.append(
            {
                "scope": "class",
                "sequence": "",
                "class_id": int(c["class_id"]),
                "class": c["class"],
                "pq_before": _finite(pc.pq),
                "pq_after": c["pq"],
                "iou_before": _finite(pc.iou),
                "iou_after": c["iou"],
                "lstq_before": None,
                "lstq_after": None,
            }
        )
    return rows


def _row(scope: str, seq: str, class_id: int, res, after: dict[str, Any]) -> dict[str, Any]:
    return {
        "scope": scope,
        "sequence": seq,
        "class_id": class_id,
        "class": "",
        "pq_before": _finite(res.panoptic.pq),
        "pq_after": after.get("pq"),
        "iou_before": _finite(res.panoptic.miou),
        "iou_after": after.get("miou"),
        "lstq_before": _finite(res.lstq.lstq),
        "lstq_after": after.get("lstq"),
    }

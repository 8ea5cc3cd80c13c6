"""The labelling report of any run, with or without ground truth: what was labelled, how sure the
model was, the tracks, what refinement changed, the stage timings and the review queue.

:func:`write_label_report` reads the manifests, ingest's frame table, the final labels, the model's
probabilities (where the method has them) and refine's tables, and writes the tables of
:data:`flows.report.label_tables.LABEL_TABLES` plus ``frame_confidence``, ``stage_timings`` and
``review_queue`` (not ``class_legend``: :func:`flows.report.merge.write_report` writes it with the
ground truth's classes where scored). Safe to call again at any time: it rewrites the tables whole.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from dsnet_core.labels import LabelMap, label_map_from_class_map
from flows.report.confidence import confidence_pass
from flows.report.facts import config_hash, model_plan, timing_rows
from flows.report.labelled import LabelSummary, summarise
from flows.report.pictures import confidence_bev_rows
from flows.report.review import review_queue
from flows.report.tables import REPORT_TABLES
from storage.run import RunStore
from tasks.base import CLASS_MAP
from tasks.pipeline import Pipeline
from tasks.run_config import RunConfig


@dataclass
class LabelReport:
    """What :func:`write_label_report` computed.

    Attributes:
        label_map: the model's label map (None when no model stage ran yet).
        model: the model stage's plan facts (:func:`flows.report.facts.model_plan`).
        summary: the per-sequence rows.
        tables: table name -> where it was written.
    """

    label_map: LabelMap | None
    model: dict
    summary: LabelSummary
    tables: dict[str, str] = field(default_factory=dict)


def write_label_report(
    store: RunStore, pipeline: Pipeline, run: RunConfig, bev_frames: int = 6, review_rows: int = 30
) -> LabelReport:
    """Write the labelling report's tables of every sequence whose labels are done.

    Args:
        bev_frames: pictures of this many least confident frames.
        review_rows: instances in the review queue.
    """
    sequences = sorted(store.sequences())
    model = model_plan(store, pipeline, sequences)
    label_map = label_map_from_class_map(model[CLASS_MAP]) if CLASS_MAP in model else None
    conf = confidence_pass(store, pipeline, sequences)
    summary = (
        summarise(store, pipeline, sequences, label_map, conf) if label_map is not None else LabelSummary()
    )
    labelled = {r["sequence"] for r in summary.sequences if r["labelled"]}
    run_row = {
        "run_id": run.run_id or "",
        "root": store.uri,
        "method": pipeline.name,
        "labels_stage": pipeline.labels,
        "model_card": str(model.get("model_card", "")),
        "config_hash": config_hash(run),
        "created": time.time(),
    }
    out = LabelReport(label_map, model, summary)
    bev = [r for r in conf.rows if r["sequence"] in labelled]
    for name, rows in (
        ("label_run", [run_row]),
        ("label_sequences", summary.sequences),
        ("label_classes", summary.classes),
        ("label_frames", summary.frames),
        ("label_tracks", summary.tracks),
        (
            "label_bev",
            confidence_bev_rows(store, pipeline, run, bev, label_map, bev_frames)
            if label_map is not None
            else [],
        ),
        ("refine_transitions", summary.transitions),
        ("frame_confidence", conf.rows),
        ("stage_timings", timing_rows(store, pipeline, sequences)),
        ("review_queue", review_queue(store, pipeline, sequences, label_map, review_rows)),
    ):
        out.tables[name] = store.write_run_table(REPORT_TABLES[name], rows)
    return out

"""The review export: a run's least confident frames as a SemanticKITTI-layout folder with the
predicted labels, for a person to correct and ``dsnet train dsnet DIR --init-from CKPT`` to learn from."""

from __future__ import annotations

from pathlib import Path

from dsnet_core.errors import ConfigError
from dsnet_core.review.folder import ReviewFrame, write_review_folder
from flows.report.confidence import frame_confidence_rows
from storage.run import RunStore
from tasks.base import labels_contract
from tasks.confidence import model_stage
from tasks.ingest import IngestStage
from tasks.pipeline import Pipeline
from tasks.run_config import read_run

TERMS = ("score", "semantic", "agreement", "size", "stitch", "n_instances")


def _frames_if_no_points(store: RunStore, pipeline: Pipeline) -> int | None:
    """The run's frame count when its labels stage is done in every sequence and no frame holds a
    point (ingest's frame table); None otherwise."""
    ingest = next(s for s in pipeline if isinstance(s, IngestStage))
    n = 0
    for seq in store.sequences():
        m = store.read_manifest(seq, pipeline.labels)
        if m is None or m.status != "done":
            return None
        points = store.read_table(seq, ingest.table("frames"))["n_points"].to_pylist()
        if any(points):
            return None
        n += len(points)
    return n or None


def export_review(root: str, out: str | Path, top: int, storage_options: dict | None = None) -> list[dict]:
    """Write the ``top`` least confident frames of run ``root`` into ``out``; their confidence rows.

    Raises:
        ConfigError: ``top`` < 1, the run has no labelled frame, or ``out`` already holds frames.
    """
    if top < 1:
        raise ConfigError(f"--top must be at least 1, got {top}")
    store = RunStore(root, storage_options)
    run = read_run(store)
    pipeline = run.pipeline()
    rows = frame_confidence_rows(store, pipeline, store.sequences())[:top]
    if not rows:
        n_frames = _frames_if_no_points(store, pipeline)
        if n_frames is not None:
            raise ConfigError(
                f"{store.uri}: the run has no points (its {n_frames} frames are empty): nothing to review"
            )
        raise ConfigError(f"{store.uri}: no labelled frames to review (has `dsnet label` finished?)")
    reader = run.open_log()
    labels = labels_contract(pipeline.labels)
    frames = []
    for r in rows:
        ref = reader.frames(r["sequence"])[r["index"]]
        label = store.arrays(r["sequence"], labels).read_item(r["index"], ["label"])["label"]
        frames.append(
            ReviewFrame(r["sequence"], ref.frame_id, reader.scan(ref), label, {k: r[k] for k in TERMS})
        )
    model = model_stage(pipeline)
    infer = None if model is None else store.read_manifest(rows[0]["sequence"], model)
    source = {
        "run": store.uri,
        "data": run.data,
        "checkpoint": None if infer is None else infer.plan.get("checkpoint"),
        "ranked_by": "frame confidence score (lowest first)",
    }
    write_review_folder(out, frames, source)
    return rows

"""The labelling report's tables: what a run labelled, how sure it was, its tracks and what
refinement changed — written for every run, with or without ground truth.

One file each, not partitioned (``tables/<name>/part-0.parquet``), rewritten whole on every report.
Class ids are the model's train ids; class names and colours come from :data:`CLASS_LEGEND`.
"""

from __future__ import annotations

import pyarrow as pa

from storage.contract import TableSpec

LABEL_RUN = TableSpec(
    "label_run",
    pa.schema(
        [
            ("run_id", pa.string()),
            ("root", pa.string()),
            ("method", pa.string()),
            ("labels_stage", pa.string()),  # the stage holding the final labels (refine, stitch, track)
            ("model_card", pa.string()),  # ``<checkpoint folder>@<weights sha256[:12]>`` ("" unknown)
            ("config_hash", pa.string()),
            ("created", pa.float64()),  # unix seconds
        ]
    ),
    partition=(),
)
LABEL_SEQUENCES = TableSpec(
    "label_sequences",
    pa.schema(
        [
            ("sequence", pa.string()),
            ("frames", pa.int64()),  # frames of the ingest table
            ("labelled", pa.int64()),  # frames with final labels
            ("quarantined", pa.int64()),
            ("points", pa.int64()),  # points of the labelled frames
            ("truth_frames", pa.int64()),  # frames with ground truth in the log
            ("scored", pa.bool_()),  # the score stage scored at least one frame
            ("tracks", pa.int64()),  # distinct instance ids of the final labels
            ("refined", pa.bool_()),
            ("changed", pa.int64()),  # points refinement changed (null: not refined)
            ("class_changed", pa.int64()),
            ("tracks_before", pa.int64()),  # the temporal stage's tracks (null: not refined)
            ("tracks_joined", pa.int64()),
            ("tracks_dissolved", pa.int64()),
            ("confidence_points", pa.int64()),  # points with a model probability (0: none)
            ("confidence", pa.float64()),  # their mean winning-class probability (null: none)
            ("labels_fingerprint", pa.string()),  # the labels stage's, when this row was made
        ]
    ),
    partition=(),
)
LABEL_CLASSES = TableSpec(
    "label_classes",
    pa.schema(
        [
            ("sequence", pa.string()),
            ("class_id", pa.int32()),
            ("points", pa.int64()),  # points of the final labels
            ("points_before", pa.int64()),  # the same before refinement (null: not refined)
            ("frames", pa.int64()),  # frames with at least one point of the class
            ("tracks", pa.int64()),  # instance ids whose points are mostly of the class
            ("confidence_points", pa.int64()),  # points the model predicted as the class
            ("confidence_sum", pa.float64()),  # sum of their winning-class probability
        ]
    ),
    partition=(),
)
LABEL_FRAMES = TableSpec(
    "label_frames",
    pa.schema(
        [
            ("sequence", pa.string()),
            ("index", pa.int32()),
            ("frame_id", pa.string()),
            ("status", pa.string()),  # ingest's: ok | quarantined
            ("labelled", pa.bool_()),
            ("n_points", pa.int64()),
            ("class_points", pa.list_(pa.int64())),  # points per class id (empty: not labelled)
            ("instances", pa.int32()),  # instance ids present
            ("changed", pa.int64()),  # points refinement changed (null: not refined)
            ("semantic", pa.float64()),  # mean winning-class probability (null: no confidences)
            ("score", pa.float64()),  # frame confidence (:mod:`flows.report.confidence`; null: none)
        ]
    ),
    partition=(),
)
LABEL_TRACKS = TableSpec(
    "label_tracks",
    pa.schema(
        [
            ("sequence", pa.string()),
            ("id", pa.int64()),
            ("generation", pa.int32()),  # which hand-out of the id (0 unless the labels reused ids)
            ("class_id", pa.int32()),  # the class of most of its points
            ("first_frame", pa.int32()),
            ("last_frame", pa.int32()),
            ("n_frames", pa.int32()),  # frames it has points in
            ("n_points", pa.int64()),
        ]
    ),
    partition=(),
)
CLASS_LEGEND = TableSpec(
    "class_legend",
    pa.schema(
        [
            ("map", pa.string()),  # model (the final labels') | truth (the scored pictures')
            ("class_id", pa.int32()),
            ("class", pa.string()),
            ("kind", pa.string()),  # thing | stuff | ignored
            ("colour", pa.string()),  # #rrggbb in the class pictures
            ("colour_dim", pa.string()),  # #rrggbb of stuff in the instance pictures
        ]
    ),
    partition=(),
)
LABEL_BEV = TableSpec(
    "label_bev",
    pa.schema(
        [
            ("rank", pa.int32()),  # 0 = least confident frame
            ("sequence", pa.string()),
            ("index", pa.int32()),
            ("frame_id", pa.string()),
            ("score", pa.float64()),
            ("n_points", pa.int64()),
            ("extent_m", pa.float64()),  # half width of the square picture, metres
            ("png_class", pa.binary()),  # final labels coloured by class (the legend's colours)
            ("png_instance", pa.binary()),  # things by instance, stuff by class (dimmed)
        ]
    ),
    partition=(),
)
REFINE_TRANSITIONS = TableSpec(
    "refine_transitions",
    pa.schema(
        [
            ("sequence", pa.string()),
            ("from_id", pa.int32()),  # class before refinement
            ("to_id", pa.int32()),  # class after
            ("points", pa.int64()),
        ]
    ),
    partition=(),
)
REFINE_SCORES = TableSpec(
    "refine_scores",
    pa.schema(
        [
            ("scope", pa.string()),  # run | sequence | class
            ("sequence", pa.string()),  # "" for run and class rows
            ("class_id", pa.int32()),  # the ground truth's train id; -1 for run and sequence rows
            ("class", pa.string()),  # its name ("" for run and sequence rows)
            ("pq_before", pa.float64()),  # the temporal stage's labels
            ("pq_after", pa.float64()),  # the refined labels (the score stage's)
            ("iou_before", pa.float64()),  # class rows: IoU; run and sequence rows: mIoU
            ("iou_after", pa.float64()),
            ("lstq_before", pa.float64()),  # null for class rows
            ("lstq_after", pa.float64()),
        ]
    ),
    partition=(),
)

LABEL_TABLES: dict[str, TableSpec] = {
    spec.name: spec
    for spec in (
        LABEL_RUN,
        LABEL_SEQUENCES,
        LABEL_CLASSES,
        LABEL_FRAMES,
        LABEL_TRACKS,
        CLASS_LEGEND,
        LABEL_BEV,
        REFINE_TRANSITIONS,
        REFINE_SCORES,
    )
}

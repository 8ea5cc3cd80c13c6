"""The report tables: dataset-level numbers merged from every scored sequence's accumulators.

One file each, not partitioned (``tables/<name>/part-0.parquet``), rewritten whole on every report.
"""

from __future__ import annotations

import pyarrow as pa

from flows.report.label_tables import LABEL_TABLES
from storage.contract import TableSpec

_HEADLINE = [
    ("pq", pa.float64()),
    ("sq", pa.float64()),
    ("rq", pa.float64()),
    ("pq_dagger", pa.float64()),
    ("pq_things", pa.float64()),
    ("sq_things", pa.float64()),
    ("rq_things", pa.float64()),
    ("pq_stuff", pa.float64()),
    ("sq_stuff", pa.float64()),
    ("rq_stuff", pa.float64()),
    ("miou", pa.float64()),
    ("lstq", pa.float64()),
    ("s_assoc", pa.float64()),
    ("s_cls", pa.float64()),
    ("iou_things", pa.float64()),
    ("iou_stuff", pa.float64()),
]
HEADLINE_KEYS = tuple(name for name, _ in _HEADLINE)
# how the run was scored, and the numbers only some benchmarks have (null where they do not):
# Panoptic nuScenes tracking metrics, and every headline number again over the classes the
# model's classes can express (the class mapping's; the rest ignored like class 0)
_SCORING = [
    ("scoring", pa.string()),  # the metric family: the ground truth's label map name
    ("class_mapping", pa.string()),  # the mapping file from the model's classes ("": none)
    ("pat", pa.float64()),
    ("tq", pa.float64()),
    ("ptq", pa.float64()),
    ("sptq", pa.float64()),
    ("pq_expressible", pa.float64()),
    ("sq_expressible", pa.float64()),
    ("rq_expressible", pa.float64()),
    ("miou_expressible", pa.float64()),
    ("lstq_expressible", pa.float64()),
    ("pat_expressible", pa.float64()),
]
SCORING_KEYS = tuple(name for name, _ in _SCORING)

SCORE_RUN = TableSpec(
    "score_run",
    pa.schema(
        [
            ("run_id", pa.string()),
            ("root", pa.string()),
            ("mode", pa.string()),  # official | corrected
            ("model_card", pa.string()),  # model card id ("" when unknown)
            ("config_hash", pa.string()),  # sha256[:16] of the run's stage configs
            ("min_points", pa.int64()),
            ("sequences", pa.int64()),
            ("frames", pa.int64()),
            ("points", pa.int64()),
            *_HEADLINE,
            *_SCORING,
            ("created", pa.float64()),  # unix seconds
        ]
    ),
    partition=(),
)
SCORE_SEQUENCES = TableSpec(
    "score_sequences",
    pa.schema(
        [
            ("sequence", pa.string()),
            ("frames", pa.int64()),
            ("points", pa.int64()),
            *_HEADLINE,
            *_SCORING,
            ("tp", pa.int64()),
            ("fp", pa.int64()),
            ("fn", pa.int64()),
        ]
    ),
    partition=(),
)
SCORE_CLASSES = TableSpec(
    "score_classes",
    pa.schema(
        [
            ("class_id", pa.int32()),  # train id
            ("class", pa.string()),
            ("kind", pa.string()),  # thing | stuff
            ("expressible", pa.bool_()),  # the model's classes reach it (always, without a mapping)
            ("pq", pa.float64()),
            ("sq", pa.float64()),
            ("rq", pa.float64()),
            ("iou", pa.float64()),
            ("tp", pa.int64()),
            ("fp", pa.int64()),
            ("fn", pa.int64()),
        ]
    ),
    partition=(),
)
STAGE_TIMINGS = TableSpec(
    "stage_timings",
    pa.schema(
        [
            ("sequence", pa.string()),
            ("stage", pa.string()),
            ("items", pa.int64()),
            ("points", pa.int64()),
            ("wall_s", pa.float64()),  # manifest: started -> finished of the last fresh run
            ("block_s", pa.float64()),  # sum of block task times
            ("items_per_s", pa.float64()),  # items / block_s
            ("points_per_s", pa.float64()),
            ("fingerprint", pa.string()),
        ]
    ),
    partition=(),
)
SCORE_BEV = TableSpec(
    "score_bev",
    pa.schema(
        [
            ("rank", pa.int32()),  # 0 = worst frame
            ("sequence", pa.string()),
            ("index", pa.int32()),
            ("frame_id", pa.string()),
            ("pq", pa.float64()),
            ("n_points", pa.int64()),
            ("extent_m", pa.float64()),  # half width of the square picture, metres
            ("png_pred", pa.binary()),  # prediction, coloured by instance (stuff: class)
            ("png_gt", pa.binary()),  # ground truth, same colouring
        ]
    ),
    partition=(),
)
REVIEW_QUEUE = TableSpec(
    "review_queue",
    pa.schema(
        [
            ("rank", pa.int32()),  # 0 = least confident
            ("source", pa.string()),  # stage/table the instance came from
            ("sequence", pa.string()),
            ("item", pa.int32()),  # volume (fuse) or first frame (stitch) index, if known
            ("instance", pa.int64()),
            ("class", pa.string()),
            ("points", pa.int64()),
            ("confidence", pa.float64()),
        ]
    ),
    partition=(),
)

FRAME_CONFIDENCE = TableSpec(
    "frame_confidence",
    pa.schema(
        [
            ("sequence", pa.string()),
            ("index", pa.int32()),  # frame index (the ingest frame table's)
            ("frame_id", pa.string()),
            ("semantic", pa.float64()),  # mean winning-class probability of the frame's points
            ("agreement", pa.float64()),  # point-weighted instance agreement with the fused class
            ("size", pa.float64()),  # 1 - share of instances under 30 points
            ("stitch", pa.float64()),  # mean weakest link IoU of the frame's tracks (1: none)
            ("score", pa.float64()),  # product of the four; lowest first
            ("n_instances", pa.int32()),
            ("n_points", pa.int64()),
        ]
    ),
    partition=(),
)

REPORT_TABLES: dict[str, TableSpec] = {
    spec.name: spec
    for spec in (
        SCORE_RUN,
        SCORE_SEQUENCES,
        SCORE_CLASSES,
        STAGE_TIMINGS,
        SCORE_BEV,
        REVIEW_QUEUE,
        FRAME_CONFIDENCE,
    )
} | LABEL_TABLES

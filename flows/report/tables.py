"""The report tables: dataset-level numbers merged from every scored sequence's accumulators.

One file each, not partitioned (``tables/<name>/part-0.parquet``), rewritten whole on every report.
The score tables (``score_run``, ``score_sequences``, ``score_classes``) carry one column per
registered metric value (:mod:`dsnet_core.metrics.registry`), so a new metric needs no edit here.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping

import pyarrow as pa

from dsnet_core.metrics.registry import columns
from flows.report.label_tables import LABEL_TABLES
from storage.contract import TableSpec
from tasks.score import column_type

_SCORING = [
    ("scoring", pa.string()),  # the metric family: the ground truth's label map name
    ("class_mapping", pa.string()),  # the mapping file from the model's classes ("": none)
]


def metric_fields(level: str = "run") -> list[tuple[str, pa.DataType]]:
    """Every registered metric's columns of ``level`` (``run`` or ``class``) as table fields, null
    where the run's scorer has no such metric (the nuScenes tracking numbers on SemanticKITTI)."""
    return [(c.key, column_type(c.kind)) for c in columns(level)]


def headline_keys() -> tuple[str, ...]:
    """The run- and sequence-level value keys of the registered metrics, in registry order."""
    return tuple(c.key for c in columns("run"))


def score_run_spec() -> TableSpec:
    return TableSpec(
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
                *_SCORING,
                *metric_fields(),
                ("created", pa.float64()),  # unix seconds
            ]
        ),
        partition=(),
    )


def score_sequences_spec() -> TableSpec:
    return TableSpec(
        "score_sequences",
        pa.schema(
            [
                ("sequence", pa.string()),
                ("frames", pa.int64()),
                ("points", pa.int64()),
                *_SCORING,
                *metric_fields(),
                ("tp", pa.int64()),
                ("fp", pa.int64()),
                ("fn", pa.int64()),
            ]
        ),
        partition=(),
    )


def score_classes_spec() -> TableSpec:
    fixed = [
        ("class_id", pa.int32()),  # train id
        ("class", pa.string()),
        ("kind", pa.string()),  # thing | stuff
        ("expressible", pa.bool_()),  # the model's classes reach it (always, without a mapping)
    ]
    return TableSpec("score_classes", pa.schema([*fixed, *metric_fields("class")]), partition=())


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
            ("frames", pa.string()),  # the frame numbers: a volume's "3–4", a frame's "3"
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

_METRIC_TABLES: dict[str, Callable[[], TableSpec]] = {
    "score_run": score_run_spec,
    "score_sequences": score_sequences_spec,
    "score_classes": score_classes_spec,
}


class _ReportTables(Mapping[str, TableSpec]):
    """Name -> table spec; the score tables' columns come from the metric registry as it is when
    asked (a metric registered after import has its columns)."""

    def __init__(self, fixed: dict[str, TableSpec]) -> None:
        self._fixed = fixed

    def __getitem__(self, name: str) -> TableSpec:
        if name in _METRIC_TABLES:
            return _METRIC_TABLES[name]()
        return self._fixed[name]

    def __iter__(self) -> Iterator[str]:
        return iter([*_METRIC_TABLES, *self._fixed])

    def __len__(self) -> int:
        return len(_METRIC_TABLES) + len(self._fixed)


REPORT_TABLES: Mapping[str, TableSpec] = _ReportTables(
    {spec.name: spec for spec in (STAGE_TIMINGS, SCORE_BEV, REVIEW_QUEUE, FRAME_CONFIDENCE)} | LABEL_TABLES
)

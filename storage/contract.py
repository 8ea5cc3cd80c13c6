"""Data contracts: the arrays and tables of every stage, declared once.

Per-point arrays live in one zarr group per (sequence, stage), padded to ``(items, max_points, ...)``
with one chunk per item (a frame or a volume); every group also has ``n_points`` (int32 ``(items,)``,
the valid prefix of each padded row) and ``done`` (uint8 ``(items,)``, written last). Tables are
parquet, hive-partitioned by string columns (``sequence=07``), one file per partition.

A new stage adds its :class:`StageContract` to :data:`CONTRACTS`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa


@dataclass(frozen=True)
class ArraySpec:
    """One array of a stage.

    Attributes:
        name: zarr array name.
        dtype: numpy dtype string.
        per_point: True for ``(items, max_points, *trailing)`` padded rows, False for ``(items, *trailing)``.
        trailing: trailing shape.
        optional: may be absent (e.g. labels of a log without ground truth).
        doc: meaning and units.
    """

    name: str
    dtype: str
    per_point: bool = True
    trailing: tuple[int, ...] = ()
    optional: bool = False
    doc: str = ""

    def item_shape(self, n_points: int) -> tuple[int, ...]:
        """Shape of one item's valid data."""
        return ((n_points,) if self.per_point else ()) + self.trailing

    def check(self, value: np.ndarray, n_points: int) -> np.ndarray:
        """Return ``value`` as the declared dtype; raise ValueError on a wrong shape."""
        value = np.asarray(value)
        want = self.item_shape(n_points)
        if value.shape != want:
            raise ValueError(f"array {self.name!r}: shape {value.shape}, contract says {want}")
        return value.astype(self.dtype, copy=False)


@dataclass(frozen=True)
class TableSpec:
    """A parquet table: data columns plus string hive partition columns."""

    name: str
    schema: pa.Schema
    partition: tuple[str, ...] = ("sequence",)

    @property
    def partition_schema(self) -> pa.Schema:
        return pa.schema([(p, pa.string()) for p in self.partition])


@dataclass(frozen=True)
class StageContract:
    """What a stage writes. ``item`` names the unit of its arrays (``frame`` or ``volume``)."""

    stage: str
    item: str
    arrays: tuple[ArraySpec, ...] = ()
    tables: tuple[TableSpec, ...] = ()

    def array(self, name: str) -> ArraySpec:
        for spec in self.arrays:
            if spec.name == name:
                return spec
        raise KeyError(f"stage {self.stage!r} declares no array {name!r}")

    def table(self, name: str) -> TableSpec:
        for spec in self.tables:
            if spec.name == name:
                return spec
        raise KeyError(f"stage {self.stage!r} declares no table {name!r}")


FRAMES = TableSpec(
    "frames",
    pa.schema(
        [
            ("index", pa.int32()),
            ("frame_id", pa.string()),
            ("source_path", pa.string()),
            ("label_path", pa.string()),
            ("n_points", pa.int64()),
            ("pose", pa.list_(pa.float64(), 16)),  # LiDAR-frame 4×4 sensor→world, row-major
            ("pose_source", pa.string()),  # "log" | "estimated" (ingest --estimate-poses) | None
            ("timestamp", pa.float64()),
            ("checksum", pa.string()),  # blake2b of scan bytes + label bytes
            ("has_labels", pa.bool_()),
            ("status", pa.string()),  # "ok" | "quarantined"
            ("reason", pa.string()),
        ]
    ),
)

VOLUMES = TableSpec(
    "volumes",
    pa.schema(
        [
            ("index", pa.int32()),
            ("ref_frame", pa.int32()),  # frame index whose sensor frame the volume is expressed in
            ("frames", pa.list_(pa.int32())),  # frame indices in the volume, in order
            ("n_points", pa.int64()),
        ]
    ),
)

N_CLASSES = 20  # SemanticKITTI train ids 0..19 (the probs row width of ``infer``)
INS_DIM = 32  # instance feature width of ``infer``

INSTANCES = TableSpec(
    "instances",
    pa.schema(
        [
            ("index", pa.int32()),  # volume index
            ("id", pa.int32()),  # raw (volume-local) instance id, as in fuse's ``inst``
            ("class_id", pa.int32()),  # winning thing class (train id)
            ("n_points", pa.int64()),
            ("agreement", pa.float32()),  # fraction of the instance's points predicted as class_id
            ("confidence", pa.float32()),  # mean predicted probability of class_id over its points
            ("centroid", pa.list_(pa.float32(), 3)),  # metres, volume (reference sensor) frame
            ("box_min", pa.list_(pa.float32(), 3)),  # axis-aligned box, metres
            ("box_max", pa.list_(pa.float32(), 3)),
        ]
    ),
)

TRACKS = TableSpec(
    "tracks",
    pa.schema(
        [
            ("id", pa.int32()),  # sequence-wide instance id (upper 16 bits of the label)
            ("class_id", pa.int32()),  # majority train id over the track's points
            ("raw_class", pa.int32()),  # the same through learning_map_inv
            ("first_frame", pa.int32()),  # frame indices (the ingest frame table's ``index``)
            ("last_frame", pa.int32()),
            ("n_points", pa.int64()),
            ("n_frames", pa.int32()),
            ("confidence", pa.float64()),  # point-weighted mean of fuse's instance confidence
            ("min_link_iou", pa.float64()),  # lowest IoU that carried the id across volumes (NaN: none)
            ("frames", pa.list_(pa.int32())),  # frames the track has points in
            ("frame_points", pa.list_(pa.int64())),  # its points in each of those frames
        ]
    ),
)

CONTRACTS: dict[str, StageContract] = {
    "ingest": StageContract("ingest", item="frame", tables=(FRAMES,)),
    "align": StageContract(
        "align",
        item="volume",
        arrays=(
            ArraySpec(
                "points", "float32", trailing=(4,), doc="x, y, z (m, reference sensor frame), remission"
            ),
            ArraySpec("source_frame", "int32", doc="frame index (in the sequence) each point came from"),
            ArraySpec("source_index", "int32", doc="point index in its source scan"),
            ArraySpec("labels", "uint32", optional=True, doc="raw semantic | instance << 16 (ground truth)"),
        ),
        tables=(VOLUMES,),
    ),
    "infer": StageContract(
        "infer",
        item="volume",
        arrays=(
            ArraySpec("sem", "uint8", doc="predicted train id (argmax over 1..19)"),
            ArraySpec(
                "probs",
                "uint8",
                trailing=(N_CLASSES,),
                doc="softmax probabilities quantised to uint8: p = q / 255 (abs error <= 1/510)",
            ),
            ArraySpec("offsets", "float32", trailing=(3,), doc="point -> instance centre, metres"),
            ArraySpec("features", "float16", trailing=(INS_DIM,), doc="instance features for shifting"),
        ),
    ),
    "shift": StageContract(
        "shift",
        item="volume",
        arrays=(
            ArraySpec("instance", "int32", doc="raw instance id 1..K on thing points, 0 elsewhere"),
            ArraySpec(
                "seed_position",
                "float32",
                trailing=(3,),
                optional=True,
                doc="converged position (metres) at the points chosen as shifting seeds, NaN elsewhere",
            ),
        ),
    ),
    "fuse": StageContract(
        "fuse",
        item="volume",
        arrays=(
            ArraySpec("sem", "uint8", doc="train id after the instances' majority vote"),
            ArraySpec("inst", "int32", doc="raw (volume-local) instance id, 0 for stuff"),
        ),
        tables=(INSTANCES,),
    ),
    "stitch": StageContract(
        "stitch",
        item="frame",
        arrays=(
            ArraySpec(
                "label",
                "uint32",
                doc="raw semantic | sequence-wide instance id << 16, in the frame's original point order",
            ),
        ),
        tables=(TRACKS,),
    ),
}

# -- score (issue 8): per-frame metrics from the score stage; dataset-level report tables -------------
FRAME_METRICS = TableSpec(
    "frame_metrics",
    pa.schema(
        [
            ("index", pa.int32()),  # frame index in the sequence (ingest's)
            ("frame_id", pa.string()),
            ("n_points", pa.int64()),  # points of the scan
            ("n_valid", pa.int64()),  # points whose ground truth is not ignored
            ("pq", pa.float64()),  # mean over the classes seen in this frame (NaN: none)
            ("sq", pa.float64()),
            ("rq", pa.float64()),
            ("miou", pa.float64()),  # mean over classes with a non-zero union in this frame
            ("tp", pa.int64()),  # matched segments, all classes
            ("fp", pa.int64()),
            ("fn", pa.int64()),
        ]
    ),
)
CONTRACTS["score"] = StageContract("score", item="frame", tables=(FRAME_METRICS,))

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

# Written by tasks.score_report from the merged accumulators of every scored sequence; one file
# each, not partitioned (``tables/<name>/part-0.parquet``), rewritten whole on every report.
REPORT_TABLES: dict[str, TableSpec] = {
    spec.name: spec
    for spec in (
        TableSpec(
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
                    ("created", pa.float64()),  # unix seconds
                ]
            ),
            partition=(),
        ),
        TableSpec(
            "score_sequences",
            pa.schema(
                [
                    ("sequence", pa.string()),
                    ("frames", pa.int64()),
                    ("points", pa.int64()),
                    *_HEADLINE,
                    ("tp", pa.int64()),
                    ("fp", pa.int64()),
                    ("fn", pa.int64()),
                ]
            ),
            partition=(),
        ),
        TableSpec(
            "score_classes",
            pa.schema(
                [
                    ("class_id", pa.int32()),  # train id
                    ("class", pa.string()),
                    ("kind", pa.string()),  # thing | stuff
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
        ),
        TableSpec(
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
        ),
        TableSpec(
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
        ),
        TableSpec(
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
        ),
    )
}

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
}

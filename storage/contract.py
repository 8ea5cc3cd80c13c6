"""The generic shape of a stage's outputs: arrays and tables, declared by each stage.

Nothing here names a stage or a dataset: every stage declares its own :class:`ArraySpec` and
:class:`TableSpec` values (``tasks/<stage>.py``), and the store turns such a declaration into zarr
groups and parquet tables.

Per-point arrays live in one zarr group per (sequence, stage), padded to ``(items, max_points, ...)``
with one chunk per item (a frame or a volume); every group also has ``n_points`` (int32 ``(items,)``,
the valid prefix of each padded row) and ``done`` (uint8 ``(items,)``, written last). Tables are
parquet, hive-partitioned by string columns (``sequence=07``), one file per partition.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pyarrow as pa

Dim = int | str
"""A trailing dimension: a fixed size, or a name resolved per run from the plan (``"classes"``)."""

CODECS = ("zstd", "shuffle-lz4")
"""The chunk codecs an array may declare (:attr:`ArraySpec.codec`)."""


@dataclass(frozen=True)
class ArraySpec:
    """One array of a stage.

    Attributes:
        name: zarr array name.
        dtype: numpy dtype string.
        per_point: True for ``(items, max_points, *trailing)`` padded rows, False for ``(items, *trailing)``.
        trailing: trailing shape; a string entry is a named size the stage's plan fixes per run
            (e.g. ``"classes"``: the model's number of classes), so no dataset fact is baked in.
        optional: may be absent (e.g. labels of a log without ground truth).
        doc: meaning and units.
        codec: how its chunks are compressed (:data:`CODECS`): ``"zstd"``, or ``"shuffle-lz4"``
            (byte shuffle then LZ4, blosc) for dense multi-byte values such as coordinates and
            point indices, where it is both smaller and 3-8x faster than zstd.
    """

    name: str
    dtype: str
    per_point: bool = True
    trailing: tuple[Dim, ...] = ()
    optional: bool = False
    doc: str = ""
    codec: str = "zstd"

    def __post_init__(self) -> None:
        if self.codec not in CODECS:
            raise ValueError(f"array {self.name!r}: codec {self.codec!r} is not one of {CODECS}")

    def resolve(self, dims: Mapping[str, int]) -> tuple[int, ...]:
        """The trailing shape with named sizes filled from ``dims``.

        Raises:
            KeyError: a named size is not in ``dims``.
        """
        out = []
        for d in self.trailing:
            if isinstance(d, str):
                if d not in dims:
                    raise KeyError(f"array {self.name!r} needs the size {d!r}; the plan gives {dict(dims)}")
                out.append(int(dims[d]))
            else:
                out.append(int(d))
        return tuple(out)

    def check(self, value: np.ndarray, n_points: int, trailing: tuple[int, ...]) -> np.ndarray:
        """Return ``value`` as the declared dtype; raise ValueError on a wrong shape.

        Args:
            value: one item's data.
            n_points: the item's valid rows (per-point arrays).
            trailing: the resolved trailing shape (as created in the store).
        """
        value = np.asarray(value)
        want = ((n_points,) if self.per_point else ()) + tuple(trailing)
        if value.shape != want:
            raise ValueError(f"array {self.name!r}: shape {value.shape}, contract says {want}")
        return value.astype(self.dtype, copy=False)


@dataclass(frozen=True)
class TableSpec:
    """A parquet table: data columns plus string hive partition columns.

    Attributes:
        name: the table's folder under ``tables/`` (unique within a run store).
        schema: the data columns.
        partition: partition columns (strings); ``()`` for one file.
        roles: what some columns mean to generic readers (``{"confidence": "confidence",
            "id": "id", "class_id": "class_id", "points": "n_points", "item": "index"}``): the
            review queue reads instance tables through these names, never by guessing.
    """

    name: str
    schema: pa.Schema
    partition: tuple[str, ...] = ("sequence",)
    roles: tuple[tuple[str, str], ...] = ()

    @property
    def partition_schema(self) -> pa.Schema:
        return pa.schema([(p, pa.string()) for p in self.partition])

    def role(self, role: str) -> str | None:
        """The column playing ``role``, or None."""
        return dict(self.roles).get(role)


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

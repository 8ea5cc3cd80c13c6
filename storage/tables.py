"""Parquet tables, hive-partitioned by string columns, one file per partition.

``tables/<name>/sequence=07/part-0.parquet``. A partition file is written under a hidden temporary
name (``.part-0.parquet.<id>.tmp``: pyarrow's dataset discovery skips names starting with ``.``, and
it does not end in ``.parquet``) and renamed into place, so a reader never sees a partial file.
"""

from __future__ import annotations

import io
import posixpath

import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from storage.contract import TableSpec
from storage.errors import ContractError, StoreError
from storage.fs import RootFS
from storage.names import check_plain_name

PART = "part-0.parquet"


def partition_rel(spec: TableSpec, partition: dict[str, str]) -> str:
    """Relative folder of one partition (``tables/frames/sequence=07``)."""
    if set(partition) != set(spec.partition):
        raise ContractError(spec.name, f"partition keys {sorted(partition)} != {list(spec.partition)}")
    for value in partition.values():
        check_plain_name(value, "partition value")
    parts = [f"{key}={partition[key]}" for key in spec.partition]
    return posixpath.join("tables", spec.name, *parts)


def to_table(spec: TableSpec, rows: list[dict]) -> pa.Table:
    """Rows (dicts) -> a table with exactly the contract's columns and types."""
    try:
        return pa.Table.from_pylist(rows, schema=spec.schema)
    except (pa.ArrowInvalid, pa.ArrowTypeError, KeyError) as exc:
        raise ContractError(spec.name, f"rows do not match the table contract: {exc}") from exc


def write_partition(root: RootFS, spec: TableSpec, partition: dict[str, str], table: pa.Table) -> str:
    """Write one partition file atomically. Returns its relative path."""
    if not table.schema.equals(spec.schema):
        raise ContractError(spec.name, f"schema {table.schema} != contract {spec.schema}")
    rel = posixpath.join(partition_rel(spec, partition), PART)
    buf = io.BytesIO()
    pq.write_table(table, buf, compression="zstd")
    tmp = root.temp_name(rel)
    root.write_bytes(tmp, buf.getvalue())
    try:
        root.rename(tmp, rel)
    finally:
        root.remove(tmp)
    return rel


def read_partition(root: RootFS, spec: TableSpec, partition: dict[str, str]) -> pa.Table:
    """One partition's data columns (partition columns are not added)."""
    rel = posixpath.join(partition_rel(spec, partition), PART)
    data = root.read_bytes(rel)
    if data is None:
        raise StoreError(root.url(rel), f"table {spec.name!r} has no partition {partition}")
    table = pq.read_table(pa.BufferReader(data))
    return table.select(spec.schema.names)


def read_table(root: RootFS, spec: TableSpec) -> pa.Table:
    """The whole table with its partition columns as strings."""
    base = posixpath.join("tables", spec.name)
    part = ds.partitioning(spec.partition_schema, flavor="hive")
    if root.local:
        dataset = ds.dataset(root.path(base), format="parquet", partitioning=part)
    else:
        dataset = ds.dataset(root.path(base), format="parquet", partitioning=part, filesystem=root.fs)
    return dataset.to_table()


def remove_partition(root: RootFS, spec: TableSpec, partition: dict[str, str]) -> None:
    root.remove(partition_rel(spec, partition), recursive=True)

"""Parquet tables, hive-partitioned by string columns, one file per partition.

``tables/<name>/sequence=07/part-0.parquet``. A partition file is written under a hidden temporary
name (``.part-0.parquet.<id>.tmp``: pyarrow's dataset discovery skips names starting with ``.``, and
it does not end in ``.parquet``) and renamed into place, so a reader never sees a partial file.

Files are written with parquet page checksums (CRC32), verified on read; a partition that cannot
be read (truncated: no footer, a page that fails its checksum or does not decode) is a
:class:`~storage.errors.DamagedStoreError` naming the file, never a pyarrow traceback.
"""

from __future__ import annotations

import io
import posixpath

import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from storage.contract import TableSpec
from storage.errors import ContractError, DamagedStoreError, StoreError
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


def encode(spec: TableSpec, table: pa.Table) -> bytes:
    """A table's parquet file bytes (zstd, page checksums)."""
    if not table.schema.equals(spec.schema):
        raise ContractError(spec.name, f"schema {table.schema} != contract {spec.schema}")
    buf = io.BytesIO()
    pq.write_table(table, buf, compression="zstd", write_page_checksum=True)
    return buf.getvalue()


def put_file(root: RootFS, rel: str, data: bytes) -> None:
    """Put a parquet file in place atomically (a hidden temporary name, then a rename)."""
    tmp = root.temp_name(rel)
    root.write_bytes(tmp, data)
    try:
        root.rename(tmp, rel)
    finally:
        root.remove(tmp)


def read_partition(root: RootFS, spec: TableSpec, partition: dict[str, str]) -> pa.Table:
    """One partition's data columns (partition columns are not added)."""
    rel = posixpath.join(partition_rel(spec, partition), PART)
    data = root.read_bytes(rel)
    if data is None:
        raise StoreError(root.url(rel), f"table {spec.name!r} has no partition {partition}")
    table = decode(root.url(rel), data)
    return table.select(spec.schema.names)


def decode(where: str, data: bytes) -> pa.Table:
    """A parquet file's table; a file that does not parse is a DamagedStoreError naming ``where``."""
    try:
        return pq.read_table(pa.BufferReader(data), page_checksum_verification=True)
    except (pa.ArrowException, OSError, ValueError) as exc:
        raise DamagedStoreError(where, f"parquet file cannot be read ({len(data)} bytes: {exc})") from exc


def footer_ok(data: bytes) -> bool:
    """Whether a parquet file's footer parses (cheap: no data page is decoded)."""
    try:
        pq.read_metadata(pa.BufferReader(data))
        return True
    except (pa.ArrowException, OSError, ValueError):
        return False


def read_table(root: RootFS, spec: TableSpec) -> pa.Table:
    """The whole table with its partition columns as strings."""
    base = posixpath.join("tables", spec.name)
    part = ds.partitioning(spec.partition_schema, flavor="hive")
    fs = None if root.local else root.fs
    # page checksums are verified (a flipped bit in a data page is an error, not another value)
    fmt = ds.ParquetFileFormat(
        default_fragment_scan_options=ds.ParquetFragmentScanOptions(page_checksum_verification=True)
    )
    try:
        dataset = ds.dataset(root.path(base), format=fmt, partitioning=part, filesystem=fs)
        if not dataset.files:  # every partition removed (a run whose sequences all failed)
            return _empty(spec)
        return dataset.to_table()
    except (pa.ArrowException, OSError) as exc:
        problem = f"a parquet file of table {spec.name!r} cannot be read ({exc})"
        raise DamagedStoreError(root.url(base), problem) from exc


def _empty(spec: TableSpec) -> pa.Table:
    """No rows, with the contract's columns and the partition columns (strings), as a read of a
    table with rows has them."""
    fields = [*spec.schema, *(f for f in spec.partition_schema if f.name not in spec.schema.names)]
    return pa.schema(fields).empty_table()


def remove_partition(root: RootFS, spec: TableSpec, partition: dict[str, str]) -> None:
    root.remove(partition_rel(spec, partition), recursive=True)

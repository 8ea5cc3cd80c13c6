"""Padded per-item zarr v3 arrays of one (sequence, stage), one chunk per item, ``done`` flag last.

Layout of the group: for each per-point :class:`~storage.contract.ArraySpec` an array
``(items, max_points, *trailing)`` chunked ``(1, max_points, *trailing)`` (named trailing sizes
resolved from the plan's ``dims`` at creation, and kept in the group's attributes); ``n_points`` int32
``(items,)`` and ``done`` uint8 ``(items,)`` chunked per item. No shards: one writer per chunk,
which is what keeps concurrent block writers correct (sharded writes by several writers corrupt data).

Integrity: zarr reads a missing chunk as fill values (zeros) without a word, so the arrays cannot
tell a lost chunk from a zero one by themselves. When an item is written, :meth:`StageArrays.write_item`
returns its **item record**: ``n_points`` and, per array, the stored chunk's size (None when zarr
stored nothing: an all-fill chunk) and the CRC-32 of the item's padded row as read back (4x faster
than blake2b and still catching a truncated, swapped or overwritten chunk: these checks guard
against accidents, not against an adversary).
The runner keeps it in the item's record and its block's fragment. :meth:`StageArrays.read_item`
checks what it reads against that record and raises :class:`~storage.errors.DamagedStoreError`
naming the chunk file when a chunk is missing, cannot be decoded (truncated) or has other content.
The record is written before the ``done`` flag, so in store format 1 every written item has one: an
item whose flag is set but whose record is missing (or lists no chunks) is damage too, never read
unchecked.

Per-item I/O bypasses zarr's machinery (:class:`_ChunkCodec`): an item is exactly one chunk of each
array, so reading or writing it is one file read or atomic write and one zstd (or blosc) call,
with the same chunk keys and bytes zarr reads and writes (zarr's own per-call overhead was ~0.4 ms a read and
~1.4 ms a write of CPU, 10-20 calls per item of a stage). Arrays whose codecs are anything but
``bytes`` + ``zstd`` or ``blosc`` go through zarr.
"""

from __future__ import annotations

import hashlib
import posixpath
import zlib
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np
import zarr
from zarr.codecs import BloscCodec, ZstdCodec

from storage.contract import StageContract
from storage.errors import ContractError, DamagedStoreError, StoreError
from storage.fs import RootFS

ZSTD_LEVEL = 1
"""zstd level of new per-point arrays: level 1 encodes 25-45 % faster than 3 on infer's arrays and
their chunks are within 1 % of the size (probabilities, features, offsets of an hdl64 frame)."""
WRITE_CONFIG = {"write_empty_chunks": True}
_ZSTD_MAGIC = 0xFD2FB528


def digest(data: bytes | np.ndarray) -> str:
    """blake2b-128 (32 hex digits) of bytes, or of an array's C-order bytes."""
    if isinstance(data, np.ndarray):
        data = np.ascontiguousarray(data).tobytes()
    return hashlib.blake2b(data, digest_size=16).hexdigest()


def row_crc32(row: np.ndarray) -> str:
    """CRC-32 (8 hex digits) of an array's C-order bytes."""
    return f"{zlib.crc32(memoryview(np.ascontiguousarray(row)).cast('B')):08x}"


def _row_matches(row: np.ndarray, chunk: dict[str, Any]) -> bool:
    """Whether a chunk's decoded row matches its record's CRC-32."""
    return row_crc32(row) == chunk.get("crc32")


def _compressor(codec: str, itemsize: int):
    """The zarr compressor of an :attr:`~storage.contract.ArraySpec.codec`."""
    if codec == "shuffle-lz4":
        return BloscCodec(cname="lz4", clevel=5, shuffle="shuffle", typesize=itemsize, blocksize=0)
    return ZstdCodec(level=ZSTD_LEVEL)


def _frame_content_size(data: bytes) -> int | None:
    """The decompressed size a zstd frame's header declares, or None where it declares none (or the
    bytes are no zstd frame: decoding then fails on its own)."""
    if len(data) < 6 or int.from_bytes(data[:4], "little") != _ZSTD_MAGIC:
        return None
    fhd = data[4]
    fcs_flag, single, dict_flag = fhd >> 6, (fhd >> 5) & 1, fhd & 3
    pos = 5 + (0 if single else 1) + (0, 1, 2, 4)[dict_flag]
    size = (1 if single else 0, 2, 4, 8)[fcs_flag]
    if size == 0 or len(data) < pos + size:
        return None
    value = int.from_bytes(data[pos : pos + size], "little")
    return value + 256 if size == 2 else value


def _blosc_size(data: bytes) -> int | None:
    """The decompressed size a blosc frame's 16-byte header declares (bytes 4-7), or None."""
    return int.from_bytes(data[4:8], "little") if len(data) >= 16 else None


class _ChunkCodec:
    """Reads and writes whole chunks of one item of a zarr v3 array coded ``bytes`` (little endian)
    then ``zstd`` or ``blosc``, chunked one item per chunk, as zarr does (same keys, same bytes),
    without zarr.

    Args:
        arr: the zarr array.
        write_empty: store a chunk equal to the fill value (zarr's ``write_empty_chunks``); else
            such a chunk is removed, as zarr does.
    """

    def __init__(self, arr: zarr.Array, write_empty: bool) -> None:
        codec = arr.metadata.codecs[1]
        if isinstance(codec, BloscCodec):
            import numcodecs.blosc

            # blosc spreads one call over threads when called from the main thread (zarr calls it
            # from its own pool, where it does not): one thread here too
            numcodecs.blosc.use_threads = False
            shuffle = {"noshuffle": 0, "shuffle": 1, "bitshuffle": 2}[codec.shuffle.value]
            self.codec = numcodecs.blosc.Blosc(
                cname=codec.cname.value,
                clevel=codec.clevel,
                shuffle=shuffle,
                blocksize=codec.blocksize,
                typesize=codec.typesize,
            )  # as zarr's BloscCodec configures it
            self.sized = False  # blosc frames carry their size in their own header
        else:
            from numcodecs.zstd import Zstd

            self.codec = Zstd(level=codec.level, checksum=codec.checksum)
            self.sized = True
        self.dtype = np.dtype(arr.dtype).newbyteorder("<")
        self.row_shape = tuple(arr.shape[1:])
        self.nbytes = int(np.prod(self.row_shape, dtype=np.int64)) * self.dtype.itemsize
        self.write_empty = write_empty

    @staticmethod
    def supports(arr: zarr.Array) -> bool:
        """Whether ``arr`` is one this class reads and writes exactly as zarr."""
        from zarr.codecs import BytesCodec
        from zarr.core.chunk_key_encodings import DefaultChunkKeyEncoding
        from zarr.core.metadata.v3 import ArrayV3Metadata

        md = arr.metadata
        if not isinstance(md, ArrayV3Metadata) or len(md.codecs) != 2:
            return False
        by, zstd = md.codecs
        endian = getattr(getattr(by, "endian", None), "value", None)
        return (
            isinstance(by, BytesCodec)
            and endian in (None, "little")
            and isinstance(zstd, ZstdCodec | BloscCodec)
            and isinstance(md.chunk_key_encoding, DefaultChunkKeyEncoding)
            and md.chunk_key_encoding.separator == "/"
            and tuple(md.chunk_grid.chunk_shape) == (1, *arr.shape[1:])
            and np.dtype(arr.dtype).kind in "biuf"
            and md.fill_value == 0
            and not md.storage_transformers
        )

    def decode(self, data: bytes | None) -> np.ndarray:
        """A chunk's bytes (None: no chunk, i.e. the fill value 0) -> the item's row.

        Raises:
            ValueError, RuntimeError: not a chunk of this array (another size, not zstd).
        """
        out = np.zeros(self.row_shape, self.dtype) if data is None else np.empty(self.row_shape, self.dtype)
        if data is None:
            return out
        size = _frame_content_size(data) if self.sized else _blosc_size(data)
        if size is None:  # a frame without its size: decode, then check
            raw = self.codec.decode(data)
            size = len(raw)
            if size == self.nbytes:
                return np.frombuffer(raw, self.dtype).reshape(self.row_shape).copy()
        if size != self.nbytes:
            raise ValueError(f"it decodes to {size} bytes, not the {self.nbytes} of an item")
        self.codec.decode(data, out=out)
        return out

    def encode(self, row: np.ndarray) -> bytes | None:
        """An item's row -> its chunk's bytes, or None where zarr would store no chunk."""
        if not self.write_empty and not row.any():
            return None
        return self.codec.encode(np.ascontiguousarray(row, dtype=self.dtype))


def _zarr_store(root: RootFS, rel: str, read_only: bool = False):
    if root.local:
        return zarr.storage.LocalStore(root.path(rel), read_only=read_only)
    return zarr.storage.FsspecStore.from_url(
        root.url(rel), storage_options=root.storage_options, read_only=read_only
    )


class StageArrays:
    """The zarr group of one (sequence, stage).

    Args:
        group: an open zarr group.
        contract: the stage's contract (array names and dtypes).
        where: URL for error messages.
        root, rel: the store root and the group's folder (to find chunk files).
        records: an item's record (see the module doc), or None; given by the run store.
    """

    def __init__(
        self,
        group: zarr.Group,
        contract: StageContract,
        where: str,
        root: RootFS | None = None,
        rel: str | None = None,
        records: Callable[[int], dict[str, Any] | None] | None = None,
    ) -> None:
        self.group = group
        self.contract = contract
        self.where = where
        self.root = root
        self.rel = rel
        self.records = records
        self.names = [s.name for s in contract.arrays if s.name in group.array_keys()]
        # zarr skips storing a chunk equal to the fill value, which costs a full comparison on every
        # write (6 ms of 14 for a frame's 124k x 32 float16 features); per-item rows are rarely all
        # zero, so they are stored whatever they hold
        self._arrays = {name: group[name].with_config(WRITE_CONFIG) for name in self.names}
        self._arrays.update({name: group[name] for name in ("n_points", "done")})
        self._direct = {
            name: _ChunkCodec(arr, write_empty=name in self.names)
            for name, arr in self._arrays.items()
            if root is not None and rel is not None and _ChunkCodec.supports(arr)
        }

    @classmethod
    def create(
        cls,
        root: RootFS,
        rel: str,
        contract: StageContract,
        n_items: int,
        max_points: int,
        omit: Iterable[str] = (),
        dims: Mapping[str, int] | None = None,
        records: Callable[[int], dict[str, Any] | None] | None = None,
    ) -> StageArrays:
        """Create (overwrite) the group with every non-omitted array of the contract.

        Args:
            dims: sizes of the named trailing dimensions (``{"classes": 20}``).
        """
        omit = set(omit)
        bad = {name for name in omit if not contract.array(name).optional}
        if bad:
            raise ContractError(root.url(rel), f"arrays {sorted(bad)} are required by the contract")
        dims = dict(dims or {})
        try:
            trailing = {s.name: s.resolve(dims) for s in contract.arrays if s.name not in omit}
        except KeyError as exc:
            raise ContractError(root.url(rel), str(exc.args[0])) from None
        group = zarr.open_group(_zarr_store(root, rel), mode="w", zarr_format=3)
        group.attrs.update(
            {"stage": contract.stage, "item": contract.item, "max_points": max_points, "dims": dims}
        )
        for spec in contract.arrays:
            if spec.name in omit:
                continue
            lead = (n_items, max(max_points, 1)) if spec.per_point else (n_items,)
            shape = lead + trailing[spec.name]
            group.create_array(
                spec.name,
                shape=shape,
                chunks=(1, *shape[1:]),
                dtype=spec.dtype,
                compressors=_compressor(spec.codec, np.dtype(spec.dtype).itemsize),
                fill_value=0,
                attributes={"doc": spec.doc},
            )
        for name, dtype in (("n_points", "int32"), ("done", "uint8")):
            group.create_array(name, shape=(n_items,), chunks=(1,), dtype=dtype, fill_value=0)
        return cls(group, contract, root.url(rel), root, rel, records)

    @classmethod
    def open(
        cls,
        root: RootFS,
        rel: str,
        contract: StageContract,
        read_only: bool = True,
        records: Callable[[int], dict[str, Any] | None] | None = None,
    ) -> StageArrays:
        try:
            group = zarr.open_group(_zarr_store(root, rel, read_only), mode="r" if read_only else "r+")
            return cls(group, contract, root.url(rel), root, rel, records)
        except (FileNotFoundError, zarr.errors.GroupNotFoundError) as exc:
            raise StoreError(root.url(rel), f"no arrays of stage {contract.stage!r}") from exc
        except (KeyError, ValueError, zarr.errors.BaseZarrError) as exc:  # an array's zarr.json lost or bad
            raise DamagedStoreError(
                root.url(rel), f"the arrays of stage {contract.stage!r} cannot be opened ({exc!r})"
            ) from exc

    @property
    def n_items(self) -> int:
        return self._arrays["done"].shape[0]

    @property
    def max_points(self) -> int:
        return int(self.group.attrs["max_points"])

    # -- chunk files -------------------------------------------------------------------------------
    def chunk_rel(self, name: str, index: int) -> str:
        """The chunk key of item ``index`` of array ``name``, relative to the group (``label/c/1/0``)."""
        arr = self._arrays[name]
        return posixpath.join(name, arr.metadata.encode_chunk_key((index,) + (0,) * (arr.ndim - 1)))

    def chunk_url(self, name: str, index: int) -> str:
        """Where the chunk file of item ``index`` of array ``name`` lives (for messages)."""
        return f"{self.where.rstrip('/')}/{self.chunk_rel(name, index)}"

    def _chunk_size(self, name: str, index: int) -> int | None:
        if self.root is None or self.rel is None:
            return None
        return self.root.size(posixpath.join(self.rel, self.chunk_rel(name, index)))

    def _get(self, name: str, index: int) -> np.ndarray:
        """One item's chunk, decoded; a chunk that cannot be decoded is a DamagedStoreError."""
        try:
            codec = self._direct.get(name)
            if codec is None:
                return self._arrays[name][index]
            return codec.decode(self.root.read_bytes(posixpath.join(self.rel, self.chunk_rel(name, index))))
        except Exception as exc:  # zstd/bytes codec errors: a truncated or overwritten chunk
            size = self._chunk_size(name, index)
            raise DamagedStoreError(
                self.chunk_url(name, index),
                f"chunk of item {index} cannot be decoded ({size} bytes: {exc})",
            ) from exc

    def check_done_flag(self, index: int) -> str | None:
        """What is wrong with an item's ``done`` flag (None: it decodes to 1). The cheap check sees
        only sizes; a flipped bit in this 1-byte chunk keeps its size, and every reader of the item
        then refuses it."""
        try:
            flag = self._get("done", index)
        except DamagedStoreError as exc:
            return exc.problem
        return None if int(flag) == 1 else f"done flag of item {index} reads {int(flag)}, not 1"

    def _damaged(self, name: str, index: int, recorded: dict[str, Any] | None) -> DamagedStoreError:
        size = self._chunk_size(name, index)
        if size is None and (recorded or {}).get("size") is not None:
            problem = f"chunk of item {index} is missing (recorded {recorded['size']} bytes)"
        else:
            problem = f"chunk of item {index} does not match the checksum recorded when it was written"
        return DamagedStoreError(self.chunk_url(name, index), problem)

    def _set(self, name: str, index: int, row: np.ndarray) -> int | None:
        """Store one item's row of ``name``; the stored chunk's size (None: no chunk stored)."""
        codec = self._direct.get(name)
        if codec is None:
            self._arrays[name][index] = row
            return self._chunk_size(name, index)
        rel = posixpath.join(self.rel, self.chunk_rel(name, index))
        data = codec.encode(row)
        if data is None:
            self.root.remove(rel)
            return None
        self.root.write_bytes(rel, data)
        return len(data)

    # -- items -------------------------------------------------------------------------------------
    def write_item(
        self,
        index: int,
        values: dict[str, np.ndarray],
        n_points: int,
        before_done: Callable[[dict[str, Any]], None] | None = None,
    ) -> dict[str, Any]:
        """Write one item's arrays (valid prefix of ``n_points`` rows), then ``n_points``, then
        ``before_done(record)``, then ``done``.

        Returns:
            the item's record: ``{"n_points": n, "chunks": {name: {"size": bytes or None, "crc32": hex}}}``.
        """
        missing = set(self.names) - set(values)
        extra = set(values) - set(self.names)
        if missing or extra:
            raise ContractError(
                self.where, f"item {index}: missing arrays {missing or '{}'}, unknown {extra or '{}'}"
            )
        if n_points > self.max_points:
            raise ContractError(
                self.where, f"item {index} has {n_points} points > max_points {self.max_points}"
            )
        chunks = {}
        for name in self.names:
            spec = self.contract.array(name)
            arr = self._arrays[name]
            value = spec.check(values[name], n_points, arr.shape[2:] if spec.per_point else arr.shape[1:])
            if spec.per_point:
                row = np.zeros(arr.shape[1:], dtype=arr.dtype)
                row[:n_points] = value
            else:
                row = np.broadcast_to(np.asarray(value, dtype=arr.dtype), arr.shape[1:])
            chunks[name] = {"size": self._set(name, index, row), "crc32": row_crc32(row)}
        self._set("n_points", index, np.asarray(n_points, np.int32))
        record = {"n_points": int(n_points), "chunks": chunks}
        if before_done is not None:
            before_done(record)
        self._set("done", index, np.asarray(1, np.uint8))
        return record

    def read_item(self, index: int, names: Iterable[str] | None = None) -> dict[str, np.ndarray]:
        """The valid data of one item, checked against its record.

        Raises:
            DamagedStoreError: a chunk is missing, cannot be decoded, or differs from its record; the
                item is done but its record is missing or lists no chunks.
            StoreError: the item is not done.
        """
        record = self.records(index) if self.records is not None else None
        chunks = (record or {}).get("chunks")
        if not self._get("done", index):
            if chunks is not None and self._chunk_size("done", index) is None:
                raise DamagedStoreError(
                    self.chunk_url("done", index), f"done flag of item {index} is missing (item was written)"
                )
            raise StoreError(self.where, f"item {index} is not done")
        if chunks is None and self.records is not None:
            raise self.record_missing(index, record)
        n = int(self._get("n_points", index))
        if chunks is not None and n != record.get("n_points", n):
            raise self._damaged("n_points", index, None)
        out = {}
        for name in self.names if names is None else names:
            spec = self.contract.array(name)
            value = self._get(name, index)
            if chunks is not None and (name not in chunks or not _row_matches(value, chunks[name])):
                raise self._damaged(name, index, chunks.get(name))
            out[name] = value[:n] if spec.per_point else value
        return out

    def record_missing(self, index: int, record: dict[str, Any] | None) -> DamagedStoreError:
        """The error of a done item without a chunk record (written before its done flag, so the
        item's files are not what the run wrote)."""
        what = "lists no chunks" if record is not None else "is missing"
        return DamagedStoreError(self.chunk_url("done", index), f"item {index} is done but its record {what}")

    def files_intact(self, index: int, record: dict[str, Any]) -> bool:
        """Whether an item's chunk files have the sizes its record says (False for a record that
        lists no chunks: nothing says what was written)."""
        chunks = record.get("chunks")
        return chunks is not None and all(
            c.get("size") is None or self._chunk_size(name, index) == c["size"] for name, c in chunks.items()
        )

    def check_not_done(self, index: int) -> None:
        """For an item whose ``done`` flag reads 0 in a finished stage: raise DamagedStoreError if
        the item was written (its record lists chunks) but its ``done`` chunk is gone."""
        record = self.records(index) if self.records is not None else None
        written = record is not None and record.get("chunks") is not None
        if written and self._chunk_size("done", index) is None:
            raise DamagedStoreError(
                self.chunk_url("done", index), f"done flag of item {index} is missing (item was written)"
            )

    def done(self) -> np.ndarray:
        """bool ``(items,)``."""
        try:
            return self._arrays["done"][:].astype(bool)
        except Exception as exc:
            raise self._undecodable("done", exc) from exc

    def n_points(self) -> np.ndarray:
        try:
            return self._arrays["n_points"][:]
        except Exception as exc:
            raise self._undecodable("n_points", exc) from exc

    def _undecodable(self, name: str, exc: BaseException) -> DamagedStoreError:
        """A whole-array read failed: find the chunk that does not decode, to name it."""
        for i in range(self.n_items):
            try:
                self._arrays[name][i]
            except Exception:
                problem = f"chunk of item {i} cannot be decoded ({exc})"
                return DamagedStoreError(self.chunk_url(name, i), problem)
        return DamagedStoreError(f"{self.where.rstrip('/')}/{name}", f"array cannot be read ({exc})")

"""The run store: fingerprints, atomic writes, parquet partitions, padded arrays, locks."""

import json
import os
import subprocess
import sys
import threading
import time

import numpy as np
import pyarrow as pa
import pytest

from storage.contract import ArraySpec, StageContract, TableSpec
from storage.errors import ContractError, DamagedStoreError, LockHeldError, LockLostError, StoreError
from storage.fs import RootFS
from storage.locks import LockSet, Owner
from storage.manifest import BlockFragment, Manifest, fingerprint
from storage.run import RunStore
from storage.tables import read_partition, read_table, to_table

# the store knows no stage: these tests declare their own arrays and tables, as a stage does
FRAMES = TableSpec(
    "frames", pa.schema([("index", pa.int32()), ("frame_id", pa.string()), ("n_points", pa.int64())])
)
VOLUME = StageContract(
    "align",
    item="volume",
    arrays=(
        ArraySpec("points", "float32", trailing=(4,)),
        ArraySpec("source_frame", "int32"),
        ArraySpec("source_index", "int32"),
        ArraySpec("labels", "uint32", optional=True),
        ArraySpec("probs", "uint8", trailing=("classes",), optional=True),
    ),
)


def test_fingerprint_chains_every_input():
    base = dict(stage="align", code_version="1", config={"scans": 2}, upstream={"ingest": "aa"}, inputs="")
    fp = fingerprint(**base)
    assert fp == fingerprint(**base) and len(fp) == 16
    changed = [
        {**base, "stage": "ingest"},
        {**base, "code_version": "2"},
        {**base, "config": {"scans": 3}},
        {**base, "upstream": {"ingest": "ab"}},
        {**base, "inputs": "x"},
    ]
    assert len({fp, *(fingerprint(**c) for c in changed)}) == 6
    # key order of the config does not matter
    cfg = {"a": 1, "b": 2}
    assert fingerprint(**{**base, "config": cfg}) == fingerprint(
        **{**base, "config": dict(reversed(cfg.items()))}
    )


def test_manifest_writes_are_atomic(tmp_path):
    store = RunStore(tmp_path)
    big = {f"k{i}": "x" * 1000 for i in range(200)}
    stop = threading.Event()
    seen: list[str] = []

    def writer():
        i = 0
        while not stop.is_set():
            m = Manifest(
                stage="align", sequence="00", fingerprint=f"{i:016d}", status="running",
                code_version="1", config=big, upstream={}, inputs="", run_id="r",
            )  # fmt: skip
            store.write_manifest(m)
            i += 1

    t = threading.Thread(target=writer)
    t.start()
    deadline = time.monotonic() + 0.5
    while time.monotonic() < deadline:
        m = store.read_manifest("00", "align")  # never a partial file: always parses whole
        if m is not None:
            seen.append(m.fingerprint)
    stop.set()
    t.join()
    assert len(seen) > 10
    assert os.listdir(tmp_path / "sequences" / "00" / "align") == ["manifest.json"]  # no temp files left


def test_parquet_partition_is_string_and_atomic(tmp_path):
    root = RootFS(tmp_path)
    eye = [float(v) for v in np.eye(4).ravel()]
    rows = [
        {"index": 0, "frame_id": "000000", "source_path": "a.bin", "label_path": None, "n_points": 5,
         "pose": eye, "timestamp": 0.0, "checksum": "c", "has_labels": False, "status": "ok", "reason": None},
    ]  # fmt: skip
    table = to_table(FRAMES, rows)
    RunStore(tmp_path).write_table("07", FRAMES, rows)
    RunStore(tmp_path).write_table("10", FRAMES, rows)
    # a crashed writer's temporary file is not taken for data
    (tmp_path / "tables/frames/sequence=07/.part-0.parquet.dead.tmp").write_bytes(b"garbage")
    whole = read_table(root, FRAMES)
    assert whole.schema.field("sequence").type == pa.string()
    assert sorted(whole["sequence"].to_pylist()) == ["07", "10"]  # not the integer 7
    assert read_partition(root, FRAMES, {"sequence": "07"}).equals(table)
    names = sorted(os.listdir(tmp_path / "tables/frames/sequence=10"))
    assert names == ["part-0.parquet"]
    with pytest.raises(ContractError, match="rows do not match"):
        to_table(FRAMES, [{"index": "zero"}])
    with pytest.raises(StoreError, match="has no partition"):
        read_partition(root, FRAMES, {"sequence": "99"})


def _put(store: RunStore, arrays, index: int, vals: dict, n: int, sequence: str = "00") -> dict:
    """Write one item as the runner does: its record (with the chunk record) before its done flag."""

    def before_done(chunks):
        store.write_item_record(sequence, arrays.contract.stage, index, {"fingerprint": "f", **chunks})

    return arrays.write_item(index, vals, n, before_done)


def test_padded_arrays_round_trip_and_done_last(tmp_path):
    store = RunStore(tmp_path)
    arrays = store.create_arrays("00", VOLUME, n_items=3, max_points=10, omit=("probs",))
    assert arrays.names == ["points", "source_frame", "source_index", "labels"]
    pts = np.arange(24, dtype=np.float32).reshape(6, 4)
    vals = {"points": pts, "source_frame": np.zeros(6), "source_index": np.arange(6), "labels": np.ones(6)}
    _put(store, arrays, 1, vals, 6)
    back = store.arrays("00", VOLUME)
    assert back.done().tolist() == [False, True, False]
    got = back.read_item(1)
    assert np.array_equal(got["points"], pts) and got["source_index"].dtype == np.int32
    assert back.group["points"].chunks == (1, 10, 4)
    with pytest.raises(StoreError, match="item 0 is not done"):
        back.read_item(0)
    with pytest.raises(ContractError, match="11 points > max_points 10"):
        arrays.write_item(0, {k: np.zeros((11, 4) if k == "points" else 11) for k in vals}, 11)
    with pytest.raises(ValueError, match=r"'points': shape \(6, 3\)"):
        arrays.write_item(0, {**vals, "points": pts[:, :3]}, 6)
    with pytest.raises(ContractError, match="required by the contract"):
        store.create_arrays("00", VOLUME, 1, 1, omit=("points",))
    assert VOLUME.array("labels").optional


def test_item_chunks_are_zarrs_both_ways(tmp_path):
    """Per-item reads and writes bypass zarr (storage.arrays._ChunkCodec) with zarr's keys and bytes:
    zarr reads what they write and they read what zarr writes, an empty item stores no n_points
    chunk as zarr does not, and a chunk of another size is damage, never reshaped or padded."""
    import zarr

    from storage.arrays import ZSTD_LEVEL

    store = RunStore(tmp_path)
    arrays = store.create_arrays("00", VOLUME, 3, 5, omit=("labels",), dims={"classes": 3})
    assert set(arrays._direct) == {"points", "source_frame", "source_index", "probs", "n_points", "done"}
    rng = np.random.default_rng(0)
    vals = {"points": rng.normal(size=(4, 4)), "source_frame": np.arange(4), "source_index": -np.arange(4),
            "probs": rng.integers(0, 256, (4, 3))}  # fmt: skip
    _put(store, arrays, 0, vals, 4)
    _put(store, arrays, 1, {k: v[:0] for k, v in vals.items()}, 0)
    base = tmp_path / "sequences/00/align/arrays.zarr"
    group = zarr.open_group(base, mode="r")
    assert group["points"].metadata.codecs[1].level == ZSTD_LEVEL
    assert np.array_equal(group["points"][0, :4], vals["points"].astype(np.float32))
    assert np.array_equal(group["probs"][0, :4], vals["probs"]) and not group["probs"][0, 4:].any()
    assert group["n_points"][:].tolist() == [4, 0, 0] and group["done"][:].tolist() == [1, 1, 0]
    assert not (base / "n_points/c/1").exists()  # zarr stores no chunk equal to the fill value
    assert (base / "points/c/1/0/0").exists()  # the stage's arrays are stored whatever they hold

    # an item zarr wrote (another zstd level) reads back the same through the direct path
    zgroup = zarr.open_group(base, mode="r+")
    zgroup["source_index"][2] = np.arange(5, dtype=np.int32) * 7
    direct = store.arrays("00", VOLUME)._get("source_index", 2)
    assert direct.tolist() == [0, 7, 14, 21, 28] and direct.flags.writeable

    # arrays coded otherwise go through zarr
    from zarr.codecs import BytesCodec, GzipCodec

    from storage.arrays import _ChunkCodec

    other = zarr.open_group(tmp_path / "other.zarr", mode="w")
    gz = other.create_array("gz", shape=(2, 3), chunks=(1, 3), dtype="int32", compressors=GzipCodec())
    big = other.create_array(
        "be", shape=(2, 3), chunks=(1, 3), dtype="int32", serializer=BytesCodec(endian="big")
    )
    two = other.create_array("two", shape=(2, 4), chunks=(1, 2), dtype="int32")
    assert not any(_ChunkCodec.supports(a) for a in (gz, big, two))

    # a chunk of another item's size decodes but is refused
    small = store.create_arrays("01", VOLUME, 1, 2, omit=("labels", "probs"))
    _put(store, small, 0, {k: v[:2] for k, v in vals.items() if k != "probs"}, 2, "01")
    other = tmp_path / "sequences/01/align/arrays.zarr/source_frame/c/0/0"
    (base / "source_frame/c/0/0").write_bytes(other.read_bytes())
    with pytest.raises(
        DamagedStoreError, match=r"source_frame/c/0/0: chunk of item 0 cannot be decoded .*8 bytes, not"
    ):
        store.arrays("00", VOLUME).read_item(0)


def test_shuffled_lz4_arrays_are_zarrs_both_ways_and_smaller(tmp_path):
    """An array declared ``codec="shuffle-lz4"`` is stored with zarr's blosc codec: the direct item
    path and zarr read each other's chunks; a point index takes almost no bytes (zstd: 64 %)."""
    import zarr

    shuffled = StageContract(
        "align",
        item="volume",
        arrays=(
            ArraySpec("points", "float32", trailing=(4,), codec="shuffle-lz4"),
            ArraySpec("source_index", "int32", codec="shuffle-lz4"),
        ),
    )
    with pytest.raises(ValueError, match="codec 'gzip' is not one of"):
        ArraySpec("x", "float32", codec="gzip")
    store = RunStore(tmp_path)
    n = 5000
    arrays = store.create_arrays("00", shuffled, 2, n)
    assert {"points", "source_index"} <= set(arrays._direct)
    rng = np.random.default_rng(0)
    pts = (rng.normal(size=(n, 4)) * 20).astype(np.float32)
    record = arrays.write_item(0, {"points": pts, "source_index": np.arange(n)}, n)
    chunks = record["chunks"]
    assert chunks["source_index"]["size"] < 0.05 * 4 * n  # an arange shuffles to almost nothing
    group = zarr.open_group(tmp_path / "sequences/00/align/arrays.zarr", mode="r+")
    assert group["points"].metadata.codecs[1].to_dict()["name"] == "blosc"
    assert np.array_equal(group["points"][0], pts) and np.array_equal(group["source_index"][0], np.arange(n))
    group["points"][1] = pts[::-1]
    assert np.array_equal(store.arrays("00", shuffled)._get("points", 1), pts[::-1])


def test_named_trailing_sizes_come_from_the_plan(tmp_path):
    store = RunStore(tmp_path)
    with pytest.raises(ContractError, match="needs the size 'classes'"):
        store.create_arrays("00", VOLUME, 1, 5)
    arrays = store.create_arrays("00", VOLUME, 2, 5, omit=("labels",), dims={"classes": 7})
    assert arrays.group["probs"].shape == (2, 5, 7) and arrays.group.attrs["dims"] == {"classes": 7}
    vals = {"points": np.zeros((3, 4)), "source_frame": np.zeros(3), "source_index": np.zeros(3)}
    _put(store, arrays, 0, {**vals, "probs": np.ones((3, 7))}, 3)
    assert store.arrays("00", VOLUME).read_item(0, ["probs"])["probs"].shape == (3, 7)
    with pytest.raises(ValueError, match=r"'probs': shape \(3, 6\)"):
        arrays.write_item(1, {**vals, "probs": np.ones((3, 6))}, 3)


def test_lock_names_holder_and_waits(tmp_path):
    root = RootFS(tmp_path)
    a = LockSet(root, Owner("run-a"), heartbeat_s=0.1)
    a.acquire("s/lock.json")
    b = LockSet(root, Owner("run-b"), wait_s=0.3, poll_s=0.05)
    with pytest.raises(
        LockHeldError, match=rf"locked by another run \(host .*, pid {os.getpid()}, run run-a"
    ):
        b.acquire("s/lock.json")
    threading.Timer(0.3, a.release_all).start()
    b.wait_s = 5.0
    b.acquire("s/lock.json")  # waited for a's release
    assert json.loads((tmp_path / "s/lock.json").read_text())["run_id"] == "run-b"
    b.check("s/lock.json")
    b.release_all()
    assert not (tmp_path / "s/lock.json").exists()


def test_stale_locks_are_taken_over(tmp_path):
    root = RootFS(tmp_path)
    # a dead owner on this host
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    holder = {
        "host": Owner("x").host,
        "pid": dead.pid,
        "run_id": "dead",
        "acquired": 0,
        "heartbeat": time.time(),
    }
    root.write_json("s/lock.json", holder)
    live = LockSet(root, Owner("run-c"))
    live.acquire("s/lock.json")
    assert root.read_json("s/lock.json")["run_id"] == "run-c"
    # a silent owner on another host: its heartbeat ages out
    root.write_json("t/lock.json", {**holder, "host": "elsewhere", "pid": 1, "heartbeat": time.time() - 120})
    live.acquire("t/lock.json")
    assert root.read_json("t/lock.json")["run_id"] == "run-c"
    # the run whose lock was taken over finds out before writing
    root.write_json("t/lock.json", {**holder, "host": "elsewhere", "run_id": "thief"})
    with pytest.raises(LockLostError, match="taken over"):
        live.check("t/lock.json")
    live.release_all()
    assert root.read_json("t/lock.json")["run_id"] == "thief"  # not ours: not removed


def _finished_stage(store: RunStore, n_items: int = 4) -> tuple[StageContract, Manifest]:
    """A finished 'align' stage of sequence 00 written as the runner writes one: each item's
    record before its done flag, one block fragment with the records, the table, the manifest.
    The last item is all zeros (zarr stores no chunk for it)."""
    arrays = store.create_arrays("00", VOLUME, n_items=n_items, max_points=10, omit=("probs",))
    records = {}
    for i in range(n_items):
        v = 0 if i == n_items - 1 else i + 1
        vals = {"points": np.full((6, 4), v), "labels": np.full(6, v)}
        vals.update(source_frame=np.full(6, v), source_index=np.arange(6) * min(v, 1))

        def before_done(chunks, i=i):
            record = {"fingerprint": "f", "rows": {}, "counts": {}, **chunks}
            store.write_item_record("00", "align", i, record)

        records[i] = arrays.write_item(i, vals, 6, before_done)
    items = list(range(n_items))
    store.write_fragment(
        "00", "align", BlockFragment(fingerprint="f", block=0, items=items, seconds=0, records=records)
    )
    m = Manifest(stage="align", sequence="00", fingerprint="f", status="done", code_version="1",
                 config={}, upstream={}, inputs="", run_id="r", n_items=n_items, blocks=[items])  # fmt: skip
    rows = [{"index": i, "frame_id": f"{i:06d}", "n_points": 6} for i in items]
    m.tables["frames"] = store.write_table("00", FRAMES, rows)
    store.write_manifest(m)
    return StageContract("align", "volume", VOLUME.arrays, (FRAMES,)), m


def test_missing_truncated_and_changed_chunks_are_named_never_zeros(tmp_path):
    store = RunStore(tmp_path)
    contract, m = _finished_stage(store)
    assert store.check_stage("00", contract, m, full=True) == []  # the all-zero item is not damage
    assert np.array_equal(store.arrays("00", VOLUME).read_item(3)["points"], np.zeros((6, 4)))
    base = tmp_path / "sequences/00/align/arrays.zarr"
    assert (base / "points/c/3/0/0").exists()  # stored although all zero (arrays.WRITE_CONFIG)
    # stores written with zarr's default skip an all-zero chunk and record its size as None
    (base / "points/c/3/0/0").unlink()
    (frag,) = store.fragments("00", "align", "f").values()
    frag.records[3]["chunks"]["points"]["size"] = None
    store.write_fragment("00", "align", frag)
    record = store.read_item_record("00", "align", 3)
    record["chunks"]["points"]["size"] = None
    store.write_item_record("00", "align", 3, record)
    assert store.check_stage("00", contract, m, full=True) == []
    assert np.array_equal(store.arrays("00", VOLUME).read_item(3)["points"], np.zeros((6, 4)))

    (base / "points/c/1/0/0").unlink()
    with pytest.raises(
        DamagedStoreError, match=r"points/c/1/0/0: chunk of item 1 is missing.*rerun `dsnet label`"
    ):
        store.arrays("00", VOLUME).read_item(1)
    chunk = base / "source_index/c/2/0"
    chunk.write_bytes(chunk.read_bytes()[:-3])
    with pytest.raises(DamagedStoreError, match=r"source_index/c/2/0: chunk of item 2 cannot be decoded"):
        store.arrays("00", VOLUME).read_item(2)
    # same size, other content: the size check passes, the digest does not
    (base / "points/c/0/0/0").write_bytes((base / "points/c/2/0/0").read_bytes())
    with pytest.raises(DamagedStoreError, match="does not match the checksum"):
        store.arrays("00", VOLUME).read_item(0)
    (base / "done/c/3").unlink()
    with pytest.raises(DamagedStoreError, match=r"done/c/3: done flag of item 3 is missing"):
        store.arrays("00", VOLUME).check_not_done(3)

    cheap = store.check_stage("00", contract, m)
    assert [(d.item, d.where.split("arrays.zarr/")[1]) for d in cheap] == [
        (1, "points/c/1/0/0"), (2, "source_index/c/2/0"), (3, "done/c/3")
    ]  # fmt: skip
    assert [d.item for d in store.check_stage("00", contract, m, full=True)] == [0, 1, 2, 3]


def test_an_item_record_without_its_crc32_is_damage_not_a_pass(tmp_path):
    """Store format 1 records a CRC-32 per chunk; a record without one (a pre-release store's
    blake2b) does not verify, so nothing unverified is read back as complete."""
    store = RunStore(tmp_path)
    _finished_stage(store)
    record = store.read_item_record("00", "align", 1)
    assert set(record["chunks"]["points"]) == {"size", "crc32"}
    for chunk in record["chunks"].values():
        chunk["blake2b"] = chunk.pop("crc32")
    store.write_item_record("00", "align", 1, record)
    with pytest.raises(DamagedStoreError, match="does not match the checksum"):
        store.arrays("00", VOLUME).read_item(1)


def test_truncated_table_partition_is_a_typed_error(tmp_path):
    store = RunStore(tmp_path)
    contract, m = _finished_stage(store)
    part = tmp_path / "tables/frames/sequence=00/part-0.parquet"
    part.write_bytes(part.read_bytes()[:-50])
    with pytest.raises(DamagedStoreError, match=r"part-0.parquet: parquet file cannot be read"):
        store.read_table("00", FRAMES)
    with pytest.raises(DamagedStoreError, match="table 'frames' cannot be read"):
        store.read_all(FRAMES)
    (damage,) = store.check_stage("00", contract, m)
    assert (
        damage.table == "frames"
        and damage.where == str(part)
        and "bytes when written" not in damage.problem[:5]
    )
    m.tables = {}  # a finished stage's manifest records every table it wrote: without one, damage
    (damage,) = store.check_stage("00", contract, m)
    assert damage.table == "frames" and damage.problem == "table partition has no record in the manifest"


def test_a_done_item_without_its_record_is_damage_never_read_unchecked(tmp_path):
    """Store format 1 writes every item's record before its done flag: a done item whose record is
    lost, or whose record lists no chunks, or which its fragment does not record, is damaged (a
    read refuses it naming the item; the cheap check lists it for a rerun to recompute), never
    read back as complete."""
    store = RunStore(tmp_path)
    contract, m = _finished_stage(store)
    arrays = store.arrays("00", VOLUME)
    store.remove_item_record("00", "align", 1)
    with pytest.raises(
        DamagedStoreError, match=r"done/c/1: item 1 is done but its record is missing; .*rerun"
    ):
        arrays.read_item(1)
    record = store.read_item_record("00", "align", 2)
    del record["chunks"]
    store.write_item_record("00", "align", 2, record)
    with pytest.raises(DamagedStoreError, match="item 2 is done but its record lists no chunks"):
        arrays.read_item(2)
    assert not arrays.files_intact(2, record)  # a resume recomputes it
    (frag,) = store.fragments("00", "align", "f").values()
    del frag.records[0]
    frag.records[3].pop("chunks")
    store.write_fragment("00", "align", frag)
    cheap = store.check_stage("00", contract, m)
    assert [(d.item, d.problem) for d in cheap] == [
        (0, "item 0 is done but not recorded"),
        (1, "record of item 1 is missing"),
        (3, "item 3 is done but its record lists no chunks"),
    ]
    assert cheap[1].where.endswith("sequences/00/align/items/000001.json")
    assert {d.item for d in store.check_stage("00", contract, m, full=True)} == {0, 1, 2, 3}
    # an item the block did not write (quarantined: no record, no done chunk) is no damage
    (tmp_path / "sequences/00/align/arrays.zarr/done/c/0").unlink()
    assert [d.item for d in store.check_stage("00", contract, m)] == [1, 3]


def test_block_outputs_are_checked_against_their_records(tmp_path):
    store = RunStore(tmp_path)
    contract, m = _finished_stage(store)
    store.write_block_bytes("00", "align", "acc-000000.npz", b"accumulators" * 10)
    assert store.read_block_bytes("00", "align", "acc-000000.npz") == b"accumulators" * 10
    assert store.check_stage("00", contract, m) == []
    out = tmp_path / "sequences/00/align/blocks/acc-000000.npz"
    out.write_bytes(b"accum")
    with pytest.raises(DamagedStoreError, match=r"acc-000000.npz: block output \(5 bytes\) does not match"):
        store.read_block_bytes("00", "align", "acc-000000.npz")
    (damage,) = store.check_stage("00", contract, m)
    assert damage.whole and damage.where == str(out) and "has 5 bytes, 120 when written" in damage.problem
    out.unlink()
    with pytest.raises(DamagedStoreError, match="block output is missing"):
        store.read_block_bytes("00", "align", "acc-000000.npz")
    out.write_bytes(b"accumulators" * 10)
    (tmp_path / "sequences/00/align/blocks/acc-000000.npz.b2").unlink()
    with pytest.raises(DamagedStoreError, match=r"acc-000000.npz: block output has no record"):
        store.read_block_bytes("00", "align", "acc-000000.npz")


def test_json_that_is_not_utf8_is_a_typed_error_naming_the_file(tmp_path):
    """A flipped bit can leave a manifest or record that is not UTF-8: json.loads raised
    UnicodeDecodeError (a bare ``error: 'utf-8' codec can't decode ...`` line naming no file)."""
    (tmp_path / "s").mkdir()
    (tmp_path / "s/manifest.json").write_bytes(b'{"stage": "\xf5align"}')
    with pytest.raises(StoreError, match=r"s/manifest.json: not valid JSON"):
        RootFS(str(tmp_path)).read_json("s/manifest.json")


def _flip_silently(data: bytes, spec: TableSpec, table: pa.Table) -> bytes:
    """``data`` with one bit of a data page flipped such that a reader that does not verify page
    checksums reads other values without an error."""
    import pyarrow.parquet as pq

    col = pq.read_metadata(pa.BufferReader(data)).row_group(0).column(2)
    for off in range(col.data_page_offset + 20, col.data_page_offset + col.total_compressed_size):
        flipped = bytearray(data)
        flipped[off] ^= 4
        try:
            if not pq.read_table(pa.BufferReader(bytes(flipped))).equals(table):
                return bytes(flipped)
        except (pa.ArrowException, OSError):
            continue
    raise AssertionError("no silently flippable bit found")


def test_whole_table_reads_verify_page_checksums(tmp_path):
    """``read_all`` (the dashboard's and the report's reader) scanned the dataset without page
    checksum verification: a flipped bit in a data page read back as another number."""
    store = RunStore(tmp_path)
    rows = [{"index": i, "frame_id": f"{i:06d}", "n_points": 1000 + i} for i in range(200)]
    record = store.write_table("00", FRAMES, rows)
    part = tmp_path / record["path"]
    part.write_bytes(_flip_silently(part.read_bytes(), FRAMES, to_table(FRAMES, rows)))
    with pytest.raises(DamagedStoreError, match="table 'frames' cannot be read"):
        store.read_all(FRAMES)


def test_report_tables_have_a_record_checked_by_status_and_readers(tmp_path):
    """Report tables (rewritten whole by every run) had no size or digest record: ``dsnet status``
    could not see a truncated, changed or lost one, and a reader took a changed one as data."""
    store = RunStore(tmp_path)
    report = TableSpec("score_run", FRAMES.schema, partition=())
    rows = [{"index": i, "frame_id": f"{i:06d}", "n_points": 1000 + i} for i in range(200)]
    store.write_run_table(report, rows)
    part = tmp_path / "tables/score_run/part-0.parquet"
    good = part.read_bytes()
    assert store.check_run_table(report) == [] and store.check_run_table(report, full=True) == []
    assert [p.name for p in part.parent.iterdir() if not p.name.startswith(".")] == ["part-0.parquet"]
    assert store.read_all(report).equals(to_table(report, rows))

    part.write_bytes(good[:-60])
    (damage,) = store.check_run_table(report)
    assert damage.where == str(part) and f"{len(good)} when written" in damage.problem

    part.write_bytes(_flip_silently(good, report, to_table(report, rows)))
    assert store.check_run_table(report) == []  # same size: the cheap check compares sizes only
    (damage,) = store.check_run_table(report, full=True)
    assert damage.where == str(part) and "checksum" in damage.problem
    with pytest.raises(DamagedStoreError, match=r"score_run/part-0.parquet: file does not match"):
        store.read_all(report)

    part.unlink()
    (damage,) = store.check_run_table(report)
    assert damage.problem == "file is missing"
    store.write_run_table(report, rows)  # the next run rewrites it whole, with its record
    assert store.check_run_table(report, full=True) == []

    # a run stopped between the file and its record: damage (the next run rewrites it), not a pass
    (tmp_path / "tables/score_run/.part-0.parquet.b2").unlink()
    (damage,) = store.check_run_table(report)
    assert damage.problem == "record of the table is missing" and damage.table == "score_run"
    with pytest.raises(DamagedStoreError, match=r"score_run/part-0.parquet: record of the table is missing"):
        store.read_all(report)


def test_a_store_of_another_format_is_refused_in_one_line_that_says_to_relabel(tmp_path):
    from storage.errors import NoRunConfigError, StoreFormatError
    from storage.run import STORE_FORMAT

    store = RunStore(tmp_path)
    with pytest.raises(NoRunConfigError, match="no run config here"):
        store.read_run_config()
    store.write_run_config("r1", {"data": "log"})
    assert store.read_run_config()["store_format"] == STORE_FORMAT == 1
    (tmp_path / "run.json").write_text('{"run_id": "r0", "data": "log"}')  # before format 1
    with pytest.raises(
        StoreFormatError, match="run store of format before 1, this dsnet reads format 1: relabel"
    ):
        store.read_run_config()


def test_a_fragments_rows_live_beside_it_and_a_missing_rows_file_unfinishes_its_block(tmp_path):
    store = RunStore(tmp_path)
    contract, m = _finished_stage(store)
    rows = {"frames": [{"index": i, "frame_id": f"{i:06d}", "n_points": 6} for i in range(4)]}
    (frag,) = store.fragments("00", "align", "f").values()
    store.write_fragment("00", "align", frag.model_copy(update={"rows": rows}))
    blocks = tmp_path / "sequences/00/align/blocks"
    head = json.loads((blocks / "00000.json").read_text())
    assert head["rows"] == {} and head["rows_bytes"] == (blocks / "00000.rows").stat().st_size
    assert store.fragments("00", "align", "f")[0].rows == {}  # status and resume: no rows parsed
    assert store.fragments("00", "align", "f", rows=True)[0].rows == rows  # gathering the tables
    assert store.check_stage("00", contract, m) == []

    (blocks / "00000.rows").write_bytes(b'{"rows": {}}')  # another size: not what the block wrote
    assert store.fragments("00", "align", "f", rows=True) == {}  # the block runs again
    (damage,) = store.check_stage("00", contract, m)
    assert damage.block == 0 and damage.where.endswith("blocks/00000.rows")
    assert damage.problem.startswith("block rows file has 12 bytes, ")
    (blocks / "00000.rows").unlink()
    (damage,) = store.check_stage("00", contract, m)
    assert damage.problem.startswith("block rows file is missing, ")


def test_a_flipped_bit_in_a_done_flag_is_damage_a_run_sees_before_it_skips(tmp_path):
    store = RunStore(tmp_path)
    contract, m = _finished_stage(store)
    chunk = tmp_path / "sequences/00/align/arrays.zarr/done/c/2"
    data = bytearray(chunk.read_bytes())
    data[3] ^= 4  # the size stays: the cheap check (dsnet status) cannot see it
    chunk.write_bytes(bytes(data))
    assert store.check_stage("00", contract, m) == []
    (damage,) = store.check_stage("00", contract, m, flags=True)
    assert damage.item == 2 and damage.where.endswith("align/arrays.zarr/done/c/2")
    assert damage.problem.startswith("chunk of item 2 cannot be decoded")


def test_a_partitioned_table_without_partitions_reads_empty_with_its_columns(tmp_path):
    root = RootFS(str(tmp_path))
    RunStore(tmp_path).write_table("00", FRAMES, [{"index": 0}])
    (tmp_path / "tables" / FRAMES.name / "sequence=00" / "part-0.parquet").unlink()
    table = read_table(root, FRAMES)  # every sequence of the run failed: no partition left
    assert table.num_rows == 0
    assert table.column_names == [*FRAMES.schema.names, "sequence"]

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
from storage.errors import ContractError, LockHeldError, LockLostError, StoreError
from storage.fs import RootFS
from storage.locks import LockSet, Owner
from storage.manifest import Manifest, fingerprint
from storage.run import RunStore
from storage.tables import read_partition, read_table, to_table, write_partition

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
    write_partition(root, FRAMES, {"sequence": "07"}, table)
    write_partition(root, FRAMES, {"sequence": "10"}, table)
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


def test_padded_arrays_round_trip_and_done_last(tmp_path):
    store = RunStore(tmp_path)
    arrays = store.create_arrays("00", VOLUME, n_items=3, max_points=10, omit=("probs",))
    assert arrays.names == ["points", "source_frame", "source_index", "labels"]
    pts = np.arange(24, dtype=np.float32).reshape(6, 4)
    vals = {"points": pts, "source_frame": np.zeros(6), "source_index": np.arange(6), "labels": np.ones(6)}
    arrays.write_item(1, vals, 6)
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


def test_named_trailing_sizes_come_from_the_plan(tmp_path):
    store = RunStore(tmp_path)
    with pytest.raises(ContractError, match="needs the size 'classes'"):
        store.create_arrays("00", VOLUME, 1, 5)
    arrays = store.create_arrays("00", VOLUME, 2, 5, omit=("labels",), dims={"classes": 7})
    assert arrays.group["probs"].shape == (2, 5, 7) and arrays.group.attrs["dims"] == {"classes": 7}
    vals = {"points": np.zeros((3, 4)), "source_frame": np.zeros(3), "source_index": np.zeros(3)}
    arrays.write_item(0, {**vals, "probs": np.ones((3, 7))}, 3)
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

"""Stages ingest and align through the plain runner: values, quarantine, resume, reprocessing."""

import os

import numpy as np
import pytest

from dsnet_core.errors import ScanFormatError
from dsnet_core.io import kitti
from dsnet_core.io.semantickitti import SemanticKittiReader
from storage.run import RunStore
from tasks.methods import get_pipeline
from tests.helpers.plain_runner import finalize_stage, prepare_stage, run_block, run_stage_plain, stage_state
from tests.logs import NOISE, make_log, pose

P = get_pipeline()  # the DS-Net stages


@pytest.fixture
def log(tmp_path):
    return make_log(tmp_path / "log", ("00",), n_frames=7)


def _run(log, **align):
    return {"data": str(log), "stages": {"align": align}, "options": {"block_size": 2}}


def _all(store, run, run_id="r1", force=False):
    return [run_stage_plain(store, P, "00", s, run, run_id, force) for s in ("ingest", "align")]


def test_ingest_frame_table(log, tmp_path):
    store = RunStore(tmp_path / "run")
    run = _run(log)
    store.write_run_config("r1", run)
    m = run_stage_plain(store, P, "00", "ingest", run, "r1")
    assert m.status == "done" and m.n_items == 7 and len(m.blocks) == 4 and m.counts["frames"] == 7
    t = store.read_table("00", P["ingest"].table("frames")).to_pydict()
    reader = SemanticKittiReader(log)
    refs = reader.frames("00")
    assert t["frame_id"] == [f"{i:06d}" for i in range(7)]
    assert t["n_points"] == [reader.scan(r).shape[0] for r in refs]
    np.testing.assert_allclose(np.reshape(t["pose"][3], (4, 4)), pose(3), atol=1e-9)
    assert t["timestamp"][5] == pytest.approx(0.5) and set(t["status"]) == {"ok"} and all(t["has_labels"])
    assert t["intensity_convention"] == ["unit"] * 7 and t["outside_grid"] == [None] * 7  # no grid given


def test_ingest_counts_points_outside_the_model_grid(log, tmp_path):
    """With the model's grid in ingest's config, each frame counts its points beyond the bounds
    (a 10 m box around a synthetic log: ρ < 3 m or > 10 m, z beyond [-3, 1.5] m)."""
    from dsnet_core.model.bounds import outside_grid

    store = RunStore(tmp_path / "run")
    grid = {"min_bound": [3.0, -np.pi, -3.0], "max_bound": [10.0, np.pi, 1.5]}
    run = {"data": str(log), "stages": {"ingest": {"grid": grid}}, "options": {"block_size": 3}}
    store.write_run_config("r1", run)
    m = run_stage_plain(store, P, "00", "ingest", run, "r1")
    t = store.read_table("00", P["ingest"].table("frames")).to_pydict()
    reader = SemanticKittiReader(log)
    want = []
    for r in reader.frames("00"):
        xyz = reader.scan(r)[:, :3].astype(np.float64)
        rho = np.hypot(xyz[:, 0], xyz[:, 1])
        want.append(int(((rho < 3) | (rho > 10) | (xyz[:, 2] < -3) | (xyz[:, 2] > 1.5)).sum()))
    assert t["outside_grid"] == want and 0 < sum(want) < sum(t["n_points"])
    assert m.counts["outside_grid"] == sum(want)
    assert want[0] == int(outside_grid(reader.scan(reader.frames("00")[0]), *grid.values()).sum())


def test_align_volumes_split_back_and_keep_labels(log, tmp_path):
    store = RunStore(tmp_path / "run")
    run = _run(log, scans=3)
    store.write_run_config("r1", run)
    _, m = _all(store, run)
    assert m.plan["windows"] == [[0, 1, 2], [2, 3, 4], [4, 5, 6]]
    arrays = store.arrays("00", P["align"].contract)
    reader = SemanticKittiReader(log)
    refs = reader.frames("00")
    vol = arrays.read_item(1)
    car = vol["labels"] & 0xFFFF == 10
    ref_car = vol["points"][car & (vol["source_frame"] == 4), :3]
    for f in (2, 3):  # the parked car's points coincide in the reference frame
        err = np.linalg.norm(vol["points"][car & (vol["source_frame"] == f), :3] - ref_car, axis=1)
        assert err.max() < 8 * NOISE
    for f in (2, 3, 4):  # source indices split the volume back into the original scans exactly
        sel = vol["source_frame"] == f
        scan, label = reader.scan(refs[f]), reader.labels(refs[f])
        order = vol["source_index"][sel]
        assert np.array_equal(np.sort(order), np.arange(len(scan)))
        assert np.array_equal(vol["labels"][sel], label[order])
        assert np.array_equal(vol["points"][sel, 3], scan[order, 3])
    vols = store.read_table("00", P["align"].table("volumes")).to_pydict()
    assert vols["ref_frame"] == [2, 4, 6] and vols["n_points"] == arrays.n_points().tolist()


def test_a_sequence_with_one_label_file_missing_aligns_without_ground_truth(log, tmp_path):
    (log / "sequences/00/labels/000003.label").unlink()
    store = RunStore(tmp_path / "run")
    run = _run(log, scans=2)
    store.write_run_config("r1", run)
    ingest, align = _all(store, run)  # was "frame changed since ingest" on every labelled frame
    assert ingest.status == align.status == "done"
    t = store.read_table("00", P["ingest"].table("frames")).to_pydict()
    assert t["has_labels"] == [True, True, True, False, True, True, True]
    assert align.plan["labels"] is False
    assert "labels" not in store.arrays("00", P["align"].contract).read_item(0)


def test_points_at_1e30_quarantine_their_frame_with_skip(log, tmp_path):
    scan = log / "sequences/00/velodyne/000002.bin"
    pts = np.fromfile(scan, np.float32).reshape(-1, 4)
    pts[7, 1] = 1e30
    pts.tofile(scan)
    store = RunStore(tmp_path / "run")
    run = _run(log, scans=1)
    run["options"]["on_error"] = "skip"
    store.write_run_config("r1", run)
    _all(store, run)
    t = store.read_table("00", P["ingest"].table("frames")).to_pydict()
    assert t["status"][2] == "quarantined" and t["status"].count("ok") == 6
    assert "000002.bin" in t["reason"][2] and "beyond 10000 m" in t["reason"][2]


def test_a_frame_over_the_point_limit_is_refused_or_quarantined(log, tmp_path):
    reader = SemanticKittiReader(log)
    sizes = [reader.scan(r).shape[0] for r in reader.frames("00")]
    limit = sorted(sizes)[-2]  # the largest frame is one point or more over it
    big = int(np.argmax(sizes))
    store = RunStore(tmp_path / "run")
    run = {"data": str(log), "stages": {"ingest": {"max_points": limit}}, "options": {"block_size": 2}}
    store.write_run_config("r1", run)
    with pytest.raises(ScanFormatError, match=rf"{big:06d}\.bin: {sizes[big]} points exceed the limit"):
        run_stage_plain(store, P, "00", "ingest", run, "r1")
    run["options"]["on_error"] = "skip"
    store.write_run_config("r2", run)
    run_stage_plain(store, P, "00", "ingest", run, "r2")
    t = store.read_table("00", P["ingest"].table("frames")).to_pydict()
    assert [i for i, s in enumerate(t["status"]) if s == "quarantined"] == [big]
    assert "--max-points" in t["reason"][big]


def test_quarantine_with_skip_and_clear_error_by_default(log, tmp_path):
    bad = log / "sequences/00/velodyne/000003.bin"
    bad.write_bytes(bad.read_bytes()[:-6])
    store = RunStore(tmp_path / "run")
    run = _run(log, scans=2)
    store.write_run_config("r1", run)
    with pytest.raises(ScanFormatError, match=r"000003\.bin: size \d+ bytes is not a multiple of 16"):
        run_stage_plain(store, P, "00", "ingest", run, "r1")
    run["options"]["on_error"] = "skip"
    store.write_run_config("r2", run)
    _, m = _all(store, run, "r2")
    t = store.read_table("00", P["ingest"].table("frames")).to_pydict()
    assert t["status"][3] == "quarantined" and "not a multiple of 16" in t["reason"][3]
    assert all(3 not in w for w in m.plan["windows"])  # quarantined frames are left out of every window
    assert sorted({f for w in m.plan["windows"] for f in w}) == [0, 1, 2, 4, 5, 6]


def test_resume_reprocess_and_force(log, tmp_path):
    store = RunStore(tmp_path / "run")
    run = _run(log, scans=2)
    store.write_run_config("r1", run)
    ingest, align = _all(store, run)
    ref = [store.arrays("00", P["align"].contract).read_item(i) for i in range(align.n_items)]
    # rerun: nothing to do
    assert prepare_stage(store, P, "00", "align", run, "r1").action == "skip"
    # an interrupted align: one block's fragment lost, manifest still running
    os.remove(tmp_path / "run/sequences/00/align/blocks/00001.json")
    m = store.read_manifest("00", "align")
    m.status = "running"
    store.write_manifest(m)
    assert stage_state(store, P, "00", "align", run)[0] == "partial"
    arrays = store.arrays("00", P["align"].contract, read_only=False)
    arrays.group["done"][3] = 0  # killed inside block 1 (items 2, 3): item 2 finished, item 3 did not
    d = prepare_stage(store, P, "00", "align", run, "r1")
    assert d.action == "resume" and [j.block for j in d.jobs] == [1] and d.jobs[0].items == (2, 3)
    out = run_block(d.jobs[0], store)
    assert out["items_resumed"] == 1 and out["volumes"] == 2  # item 2 came from its done flag and record
    m2 = finalize_stage(store, P, "00", "align", d.fingerprint)
    assert m2.fingerprint == align.fingerprint and m2.status == "done" and m2.counts == align.counts
    assert store.read_table("00", P["align"].table("volumes")).num_rows == align.n_items
    for i, r in enumerate(ref):
        got = store.arrays("00", P["align"].contract).read_item(i)
        assert all(np.array_equal(got[k], r[k]) for k in r)
    # a changed align config reprocesses align only
    run3 = _run(log, scans=3)
    assert stage_state(store, P, "00", "align", run3)[0] == "stale"
    assert prepare_stage(store, P, "00", "ingest", run3, "r3").action == "skip"
    assert prepare_stage(store, P, "00", "align", run3, "r3").action == "fresh"
    # a changed source file: ingest reruns and clears align (downstream) at once
    scan = kitti.read_scan(log / "sequences/00/velodyne/000002.bin")
    kitti.write_scan(log / "sequences/00/velodyne/000002.bin", scan * 1.01)
    store.write_run_config("r4", run3)
    d = prepare_stage(store, P, "00", "ingest", run3, "r4")
    assert d.action == "fresh" and store.read_manifest("00", "align") is None
    assert stage_state(store, P, "00", "align", run3)[0] == "missing"
    new_ingest, _ = _all(store, run3, "r4")
    assert new_ingest.fingerprint != ingest.fingerprint
    # force recomputes a finished stage
    assert prepare_stage(store, P, "00", "ingest", run3, "r5", force=True).action == "fresh"


def test_methods_import_without_torch():
    """`dsnet status` and the CLI's planning import every stage: torch loads only when a model runs."""
    import subprocess
    import sys
    from pathlib import Path

    code = "import sys, tasks.methods, flows.request; print('torch' in sys.modules)"
    root = Path(__file__).resolve().parents[2]
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"

"""Ingest with ``estimate_poses`` on a synthetic log whose poses are withheld: KISS-ICP poses in the
frame table, their drift against the generator's trajectory, and 4D volumes that coincide with the
true-pose ones. Plain runner, real zarr/parquet store."""

import shutil

import numpy as np
import pytest

from dsnet_core.errors import PoseFormatError
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.synth import generate_log
from dsnet_core.temporal.odometry import trajectory_drift
from storage.run import RunStore
from tasks.methods import get_pipeline
from tests.helpers.plain_runner import run_stage_plain

P = get_pipeline()  # the DS-Net stages


N_FRAMES = 20
CAR_RAW = 10  # parked cars


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """(log with poses, the same log without poses.txt and calib.txt, true LiDAR poses)."""
    base = tmp_path_factory.mktemp("poses")
    # HDL-64 (KITTI's sensor). Over 20 frames: 0.3-0.6 % end-point drift for seeds 0-2; the 10-frame
    # worlds of this generator give KISS-ICP too little structure (5-10 % for seeds 1-7, ground rings
    # pull it towards zero motion), VLP-32 there: 0.9-2.1 %.
    generate_log(base / "full", sequences=1, frames=N_FRAMES, seed=2, sensor="hdl64")
    shutil.copytree(base / "full", base / "withheld")
    for name in ("poses.txt", "calib.txt"):
        (base / "withheld" / "sequences" / "00" / name).unlink()
    reader = SemanticKittiReader(base / "full")
    truth = np.stack([reader.pose(f) for f in reader.frames("00")])
    return base / "full", base / "withheld", truth


def _run(log, estimate, scans=2, **options):
    stages = {"align": {"scans": scans}}
    if estimate is not None:
        stages["ingest"] = {"estimate_poses": estimate}
    return {"data": str(log), "stages": stages, "options": {"block_size": 3, **options}}


def _label(store, run, run_id, stages=("ingest", "align")):
    store.write_run_config(run_id, run)
    return [run_stage_plain(store, P, "00", s, run, run_id) for s in stages]


def _poses(table) -> np.ndarray:
    return np.stack([np.reshape(p, (4, 4)) for p in table["pose"]])


def _sorted_volume(store, item):
    vol = store.arrays("00", P["align"].contract).read_item(item)
    order = np.lexsort((vol["source_index"], vol["source_frame"]))
    return {k: v[order] for k, v in vol.items()}


def test_estimated_poses_drift_and_aligned_parked_cars(logs, tmp_path):
    full, withheld, truth = logs
    est_store, true_store = RunStore(tmp_path / "est"), RunStore(tmp_path / "true")
    ingest, align = _label(est_store, _run(withheld, True), "r1")
    assert len(ingest.blocks) == 1 and ingest.plan["pose_source"] == "estimated"  # odometry: one block
    t = est_store.read_table("00", P["ingest"].table("frames")).to_pydict()
    assert t["pose_source"] == ["estimated"] * N_FRAMES and set(t["status"]) == {"ok"}
    est = _poses(t)
    np.testing.assert_allclose(est[0], np.eye(4), atol=1e-12)  # LiDAR frame, Tr = identity

    drift = trajectory_drift(est, truth)
    assert drift["path_m"] > 9
    # measured: 0.26 % end-point, 0.003 deg/m, 0.16 m worst position, 3.6 % frame-to-frame; a failed
    # registration (ICP locked at zero motion) drifts by tens of per cent
    assert drift["end_translation_pct"] < 2.0
    assert drift["end_rotation_deg_per_m"] < 0.05
    assert drift["max_position_error_m"] < 0.02 * drift["path_m"]

    # the flag on a log with poses changes nothing: the log's poses win, blocks stay as configured
    t_ingest, t_align = _label(true_store, _run(full, True), "r1")
    assert len(t_ingest.blocks) == -(-N_FRAMES // 3) and t_ingest.plan["pose_source"] == "log"
    tt = true_store.read_table("00", P["ingest"].table("frames")).to_pydict()
    assert tt["pose_source"] == ["log"] * N_FRAMES
    np.testing.assert_allclose(_poses(tt), truth, atol=1e-9)

    # 4D volumes: parked cars' points in the reference frame coincide with the true-pose volumes
    assert align.plan["windows"] == t_align.plan["windows"]
    worst, n = 0.0, 0
    for item in range(align.n_items):
        a, b = _sorted_volume(est_store, item), _sorted_volume(true_store, item)
        assert np.array_equal(a["source_frame"], b["source_frame"])
        assert np.array_equal(a["source_index"], b["source_index"])
        moved = a["source_frame"] != align.plan["windows"][item][-1]  # the reference scan is not moved
        near = np.linalg.norm(b["points"][:, :2], axis=1) < 40.0  # heading error grows with range
        car = ((a["labels"] & 0xFFFF) == CAR_RAW) & moved & near
        n += int(car.sum())
        worst = max(worst, float(np.linalg.norm(a["points"][car, :3] - b["points"][car, :3], axis=1).max()))
    # measured 0.16 m (seeds 0, 1: 0.14, 0.13); a registration locked at zero motion: ~1 m
    assert n > 1000 and worst < 0.2


def test_without_the_flag_align_names_it_and_switching_it_reruns_ingest(logs, tmp_path):
    _, withheld, _ = logs
    store = RunStore(tmp_path / "run")
    (plain,) = _label(store, _run(withheld, None), "r1", stages=("ingest",))
    t = store.read_table("00", P["ingest"].table("frames")).to_pydict()
    assert t["pose"] == [None] * N_FRAMES and t["pose_source"] == [None] * N_FRAMES
    assert plain.plan["pose_source"] is None
    with pytest.raises(PoseFormatError, match=r"needs poses; the log has none .*--estimate-poses"):
        _label(store, _run(withheld, None), "r2", stages=("align",))
    ingest, align = _label(store, _run(withheld, True), "r3")
    assert ingest.fingerprint != plain.fingerprint and align.status == "done"
    assert (
        store.read_table("00", P["ingest"].table("frames"))["pose_source"].to_pylist()
        == ["estimated"] * N_FRAMES
    )


def test_quarantined_frame_is_skipped_by_odometry(logs, tmp_path):
    _, withheld, truth = logs
    log = tmp_path / "log"
    shutil.copytree(withheld, log)
    bad = log / "sequences/00/velodyne/000004.bin"
    bad.write_bytes(bad.read_bytes()[:-6])
    store = RunStore(tmp_path / "run")
    ingest, align = _label(store, _run(log, True, on_error="skip"), "r1")
    assert ingest.counts["quarantined"] == 1 and len(ingest.blocks) == 1
    t = store.read_table("00", P["ingest"].table("frames")).to_pydict()
    assert t["status"][4] == "quarantined" and t["pose"][4] is None and t["pose_source"][4] is None
    ok = [i for i in range(N_FRAMES) if i != 4]
    assert [t["pose_source"][i] for i in ok] == ["estimated"] * len(ok)
    drift = trajectory_drift(_poses({"pose": [t["pose"][i] for i in ok]}), truth[ok])
    # the odometry's prediction is one frame short after the gap; measured 0.31 % end-point drift, 0.16 m
    assert drift["end_translation_pct"] < 2.0 and drift["max_position_error_m"] < 0.02 * drift["path_m"]
    assert all(4 not in w for w in align.plan["windows"]) and align.n_items == len(ok) - 1

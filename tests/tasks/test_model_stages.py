"""Stages infer, shift, fuse, stitch through the plain runner on a synthetic vlp32 log (k = 2),
with a random-weight tiny checkpoint: values against direct dsnet_core calls, invariants, resume."""

import numpy as np
import pytest
from pydantic import TypeAdapter

from dsnet_core.instance.clustering import ClustererConfig, get_clusterer
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.model.bundle import load_shift_weights
from dsnet_core.model.inference import Predictor
from storage.run import RunStore
from tasks.infer import dequantise_probs
from tasks.methods import get_pipeline
from tests.helpers.plain_runner import prepare_stage, run_stage_plain
from tests.model_helpers import KILL_STITCH_AT_THIRD_VOLUME, make_checkpoint

P = get_pipeline(refine=False)  # the DS-Net stages

LM = load_label_map("semantic-kitti")
STAGES = ("ingest", "align", "infer", "shift", "fuse", "stitch")
SHIFT_4D = {"kind": "dynamic_shift", "n_seeds": 300, "bandwidths": [0.2, 1.8, 3.4]}


def run_config(log, ckpt, scans=2, clusterer=None):
    return {
        **P.record(),  # the DS-Net stages without refine, as the runs of these tests use
        "data": str(log),
        "stages": {
            "align": {"scans": scans},
            "infer": {"checkpoint": str(ckpt)},
            "shift": {"clusterer": clusterer or SHIFT_4D},
        },
        "options": {"block_size": 2},
    }


@pytest.fixture(scope="module")
def labelled(synth_log, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("stages")
    ckpt = make_checkpoint(tmp / "ckpt", seed=0)
    store = RunStore(tmp / "run")
    run = run_config(synth_log, ckpt)
    store.write_run_config("r1", run)
    manifests = {s: run_stage_plain(store, P, "00", s, run, "r1") for s in STAGES}
    return store, run, ckpt, manifests


def test_infer_matches_the_predictor(labelled):
    store, _, ckpt, m = labelled
    assert m["infer"].n_items == m["align"].n_items == 5 and m["infer"].status == "done"
    pts = store.arrays("00", P["align"].contract).read_item(3)["points"]
    got = store.arrays("00", P["infer"].contract).read_item(3)
    want = Predictor.from_checkpoint(ckpt).predict(pts)
    assert np.array_equal(got["sem"], want.sem) and got["sem"].dtype == np.uint8
    assert np.abs(dequantise_probs(got["probs"]) - want.probs.astype(np.float32)).max() <= 1 / 510 + 1e-3
    thing = LM.is_thing()[want.sem]  # offsets and features: thing points only (what shift reads)
    assert 0 < thing.sum() < thing.size
    assert np.array_equal(got["offsets"][thing], want.offsets[thing]) and not got["offsets"][~thing].any()
    assert np.array_equal(got["features"][thing], want.features[thing]) and not got["features"][~thing].any()
    assert m["infer"].counts["points"] == m["align"].counts["points"]
    # config batch > 1 runs several volumes per forward pass: no cross-talk between them
    both = Predictor.from_checkpoint(ckpt).predict_batch(
        [store.arrays("00", P["align"].contract).read_item(i)["points"] for i in (2, 3)]
    )
    assert np.array_equal(both[1].sem, got["sem"])
    assert np.allclose(both[1].offsets[thing], got["offsets"][thing], atol=1e-5)
    assert m["infer"].counts["thing_points"] > 0  # random weights still predict some thing classes


def test_shift_ids_equal_the_clusterer(labelled):
    store, _, ckpt, _ = labelled
    xyz = store.arrays("00", P["align"].contract).read_item(1)["points"][:, :3]
    inf = store.arrays("00", P["infer"].contract).read_item(1)
    got = store.arrays("00", P["shift"].contract).read_item(1)
    thing = LM.is_thing()[inf["sem"]]
    assert (got["instance"][~thing] == 0).all() and (got["instance"][thing] > 0).all()
    cfg = TypeAdapter(ClustererConfig).validate_python(SHIFT_4D)
    clusterer = get_clusterer(cfg, load_shift_weights(ckpt))
    want = clusterer.cluster(
        xyz[thing], (xyz[thing] + inf["offsets"][thing]).astype(np.float32), inf["features"][thing]
    )
    assert np.array_equal(got["instance"][thing], want)
    seeds = ~np.isnan(got["seed_position"][:, 0])
    assert seeds.sum() == min(300, thing.sum()) and not seeds[~thing].any()


def test_fuse_one_class_per_instance_and_stuff_untouched(labelled):
    store, _, _, m = labelled
    rows = store.read_table("00", P["fuse"].table("instances")).to_pydict()
    assert len(rows["id"]) == m["fuse"].counts["instances"] > 0
    for v in range(m["fuse"].n_items):
        inf = store.arrays("00", P["infer"].contract).read_item(v, ["sem"])["sem"]
        out = store.arrays("00", P["fuse"].contract).read_item(v)
        stuff = ~LM.is_thing()[inf]
        assert (out["inst"][stuff] == 0).all() and np.array_equal(out["sem"][stuff], inf[stuff])
        ids = np.unique(out["inst"][out["inst"] > 0])
        mine = [i for i, idx in enumerate(rows["index"]) if idx == v]
        assert sorted(rows["id"][i] for i in mine) == ids.tolist()
        for i in mine:
            sel = out["inst"] == rows["id"][i]
            assert set(out["sem"][sel].tolist()) == {rows["class_id"][i]} and sel.sum() == rows["n_points"][i]
            assert 0 < rows["confidence"][i] <= 1 and 0 < rows["agreement"][i] <= 1


def test_stitch_labels_split_back_to_frames_by_ownership(labelled, synth_log):
    store, _, _, m = labelled
    reader = SemanticKittiReader(synth_log)
    refs = reader.frames("00")
    windows = m["align"].plan["windows"]
    assert windows == [[0, 1], [1, 2], [2, 3], [3, 4], [4, 5]]
    stitch = store.arrays("00", P["stitch"].contract)
    assert stitch.done().all() and m["stitch"].counts["frames"] == 6 and len(m["stitch"].blocks) == 1
    seen_ids = {}
    labels = [stitch.read_item(f)["label"] for f in range(6)]
    for f in range(6):
        label = labels[f]
        assert label.shape == (reader.scan(refs[f]).shape[0],)
        owner = next(v for v, w in enumerate(windows) if f in w)  # the first volume holding the frame
        src = store.arrays("00", P["align"].contract).read_item(owner)
        fused = store.arrays("00", P["fuse"].contract).read_item(owner)
        sel = src["source_frame"] == f
        assert np.array_equal(np.sort(src["source_index"][sel]), np.arange(label.size))  # once each
        want_sem = LM.to_raw(fused["sem"][sel].astype(np.int64))
        assert np.array_equal(label[src["source_index"][sel]] & 0xFFFF, want_sem)
        inst = label >> 16
        assert ((inst > 0) == LM.is_thing()[LM.to_train(label & 0xFFFF)]).all()
        for tid in np.unique(inst[inst > 0]).tolist():
            seen_ids.setdefault(tid, []).append(f)
    tracks = store.read_table("00", P["stitch"].table("tracks")).to_pydict()
    assert tracks["id"] == sorted(seen_ids) and m["stitch"].counts["tracks"] == len(tracks["id"])
    for k, tid in enumerate(tracks["id"]):
        assert tracks["frames"][k] == seen_ids[tid]
        assert tracks["first_frame"][k] == seen_ids[tid][0] and tracks["last_frame"][k] == seen_ids[tid][-1]
        total = sum(int(((labels[f] >> 16) == tid).sum()) for f in seen_ids[tid])
        assert tracks["n_points"][k] == total == sum(tracks["frame_points"][k])
    assert all(0 < c <= 1 for c in tracks["confidence"])


def test_clusterer_change_and_new_checkpoint_reprocess_only_downstream(labelled, synth_log, tmp_path):
    store, run, _, m = labelled
    assert all(prepare_stage(store, P, "00", s, run, "r1").action == "skip" for s in STAGES)
    dbscan = run_config(synth_log, run["stages"]["infer"]["checkpoint"], clusterer={"kind": "dbscan"})
    assert prepare_stage(store, P, "00", "infer", dbscan, "r2").action == "skip"
    other = make_checkpoint(tmp_path / "other", seed=1)
    new_model = run_config(synth_log, other)
    assert prepare_stage(store, P, "00", "align", new_model, "r3").action == "skip"
    from tests.helpers.plain_runner import make_context, stage_fingerprint

    assert stage_fingerprint(store, P, "00", "infer", run) == m["infer"].fingerprint
    assert stage_fingerprint(store, P, "00", "infer", new_model) != m["infer"].fingerprint
    # the same weights under another path with other shifting weights: still a new model
    make_checkpoint(tmp_path / "noshift", seed=0, shift_weights=False)
    noshift = make_context(store, P, "00", "infer", run_config(synth_log, tmp_path / "noshift"))
    assert P["infer"].inputs(noshift) != P["infer"].inputs(make_context(store, P, "00", "infer", run))


def test_tta_in_the_infer_stage_equals_the_predictors_and_reprocesses_infer_onward(labelled, tmp_path):
    import shutil

    from dsnet_core.errors import ConfigError
    from dsnet_core.model.tta import TTAConfig
    from tests.helpers.plain_runner import stage_fingerprint

    shared, run, ckpt, m = labelled
    shutil.copytree(shared.root.path(""), tmp_path / "run")
    store = RunStore(tmp_path / "run")  # a copy: infer is recomputed here
    plain = {**run, "stages": {**run["stages"], "infer": {**run["stages"]["infer"], "tta": 1}}}
    assert (
        stage_fingerprint(store, P, "00", "infer", plain) == m["infer"].fingerprint
    )  # N = 1: the plain path
    tta = {
        **run,
        "stages": {**run["stages"], "infer": {**run["stages"]["infer"], "tta": 4, "tta_flip": True}},
    }
    store.write_run_config("r-tta", tta)
    assert prepare_stage(store, P, "00", "align", tta, "r-tta").action == "skip"
    assert prepare_stage(store, P, "00", "infer", tta, "r-tta").action == "fresh"
    got = run_stage_plain(store, P, "00", "infer", tta, "r-tta")
    pts = store.arrays("00", P["align"].contract).read_item(1)["points"]
    want = Predictor.from_checkpoint(ckpt, tta=TTAConfig(rotations=4, flip=True)).predict(pts)
    item = store.arrays("00", P["infer"].contract).read_item(1)
    assert got.status == "done" and np.array_equal(item["sem"], want.sem)
    thing = LM.is_thing()[want.sem]
    assert np.allclose(item["offsets"][thing], want.offsets[thing], atol=1e-6)
    assert not item["offsets"][~thing].any()
    cuda = {**run, "stages": {**run["stages"], "infer": {**run["stages"]["infer"], "device": "cuda:7"}}}
    import torch

    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match="no CUDA device"):
            prepare_stage(store, P, "00", "infer", cuda, "r-cuda")
    eq = {**run, "stages": {**run["stages"], "infer": {**run["stages"]["infer"], "equivariant": 4}}}
    with pytest.raises(ConfigError, match="was trained with --equivariant 1"):
        prepare_stage(store, P, "00", "infer", eq, "r-eq")


KILL_AT_THIRD_VOLUME = (
    KILL_STITCH_AT_THIRD_VOLUME
    + """
from storage.run import RunStore
from tasks.methods import get_pipeline
from tasks.run_config import read_run
from tasks.runner import run_stage_plain
store = RunStore(sys.argv[1])
p = get_pipeline(refine=False)
run_stage_plain(store, p, "00", "stitch", read_run(store, "r1"), "r1", force=True)
"""
)


def test_stitch_killed_mid_sequence_resumes_from_its_state(labelled, tmp_path, caplog):
    import logging
    import os
    import shutil
    import signal
    import subprocess
    import sys
    from pathlib import Path

    store, run, _, m = labelled
    repo = Path(__file__).resolve().parents[2]
    reference = [store.arrays("00", P["stitch"].contract).read_item(f)["label"] for f in range(6)]
    for keep_state in (True, False):  # resume from the saved stitcher state, or replay from volume 0
        root = tmp_path / f"run-{keep_state}"
        shutil.copytree(store.uri, root)
        res = subprocess.run(
            [sys.executable, "-c", KILL_AT_THIRD_VOLUME, str(root)],
            cwd=repo,
            env={**os.environ, "PYTHONPATH": str(repo)},
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert res.returncode == -signal.SIGKILL, res.stderr
        copy = RunStore(root)
        assert copy.arrays("00", P["stitch"].contract).done().tolist() == [True] * 3 + [False] * 3
        assert copy.read_manifest("00", "stitch").status == "running"
        # written after volume 0, then again once the time since outweighs its cost (base.STATE_SHARE)
        saved = copy.root.read_json("sequences/00/stitch/state.json")["volume"]
        assert saved in (0, 1)
        if not keep_state:
            copy.root.remove("sequences/00/stitch/state.json")
        d = prepare_stage(copy, P, "00", "stitch", run, "r1")
        assert d.action == "resume" and len(d.jobs) == 1
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="tasks.stitch"):
            resumed = run_stage_plain(copy, P, "00", "stitch", run, "r1")
        assert (f"resumes after volume {saved}" in caplog.text) == keep_state
        assert resumed.fingerprint == m["stitch"].fingerprint and resumed.counts == m["stitch"].counts
        for f in range(6):
            assert np.array_equal(copy.arrays("00", P["stitch"].contract).read_item(f)["label"], reference[f])
        assert copy.read_table("00", P["stitch"].table("tracks")).equals(
            store.read_table("00", P["stitch"].table("tracks"))
        )
        assert not copy.root.exists("sequences/00/stitch/state.json")


def test_quarantined_frame_gets_no_label_and_the_rest_stitch(tmp_path):
    from flows.export import export_semantickitti
    from tests.logs import make_log

    log = make_log(tmp_path / "log", ("00",), n_frames=6)
    bad = log / "sequences/00/velodyne/000002.bin"
    bad.write_bytes(bad.read_bytes()[:-6])
    store = RunStore(tmp_path / "run")
    run = run_config(log, make_checkpoint(tmp_path / "ckpt"), scans=2)
    run["options"]["on_error"] = "skip"
    store.write_run_config("r1", run)
    m = {s: run_stage_plain(store, P, "00", s, run, "r1") for s in STAGES}
    assert m["align"].plan["windows"] == [[0, 1], [1, 3], [3, 4], [4, 5]]  # frame 2 left out
    arrays = store.arrays("00", P["stitch"].contract)
    assert (
        arrays.done().tolist() == [True, True, False, True, True, True] and m["stitch"].counts["frames"] == 5
    )
    reader = SemanticKittiReader(log)
    for f in (0, 1, 3, 4, 5):
        assert arrays.read_item(f)["label"].shape == (reader.scan(reader.frames("00")[f]).shape[0],)
    tracks = store.read_table("00", P["stitch"].table("tracks")).to_pydict()
    assert all(2 not in frames for frames in tracks["frames"])
    summary = export_semantickitti(store.uri, tmp_path / "out")
    assert summary.frames == {"00": 5} and summary.missing == {"00": ["000002"]}
    assert not (tmp_path / "out/sequences/00/predictions/000002.label").exists()


def test_stitch_state_writes_take_at_most_their_share_of_the_time():
    from tasks.base import StateThrottle

    now = [0.0]
    throttle = StateThrottle(0.05, clock=lambda: now[0])
    assert throttle.due()  # nothing written yet
    with throttle:
        now[0] += 0.5  # a write of 0.5 s
    now[0] += 9.0
    assert not throttle.due()  # 9 s of work: 0.45 s < 0.5 s
    now[0] += 1.0
    assert throttle.due()

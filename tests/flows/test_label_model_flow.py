"""The whole label flow (ingest → … → stitch) through a real Prefect server on the 2-sequence
vlp32 synth log with a random-weight tiny checkpoint: 3D and 4D, reruns, reprocessing, export +
``dsnet eval``, and a 4D run SIGKILLed during stitch that resumes to identical labels."""

import json
import shutil
import signal
import subprocess

import numpy as np
import pytest

from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from storage.run import RunStore
from tasks.methods import get_pipeline
from tests.flows.conftest import REPO
from tests.helpers.label_request import req
from tests.model_helpers import KILL_STITCH_AT_THIRD_VOLUME, make_checkpoint

P = get_pipeline()  # the DS-Net stages

LM = load_label_map("semantic-kitti")
MODEL = ("infer", "shift", "fuse", "stitch", "refine")  # refine: on by default
ALL = ("ingest", "align", *MODEL, "score")
SEQS = ("00", "01")
FAST_SHIFT = {"kind": "dynamic_shift", "n_seeds": 300, "bandwidths": [0.2, 1.8, 3.4]}


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    return make_checkpoint(tmp_path_factory.mktemp("ckpt") / "tiny", seed=0)


def stages(ckpt, scans, clusterer=FAST_SHIFT):
    return {"align": {"scans": scans}, "infer": {"checkpoint": str(ckpt)}, "shift": {"clusterer": clusterer}}


def actions(summary):
    return {(r["sequence"], r["stage"]): r["action"] for r in summary}


def frame_labels(store, seq):
    arrays = store.arrays(seq, P["stitch"].contract)
    return [arrays.read_item(i)["label"] for i in range(arrays.n_items)]


def check_split_back(store, log, seq):
    """Every original point of every frame is labelled exactly once, in the scan's order."""
    reader = SemanticKittiReader(log)
    labels = frame_labels(store, seq)
    refs = reader.frames(seq)
    assert len(labels) == len(refs) and store.arrays(seq, P["stitch"].contract).done().all()
    covered = {}
    for v in range(store.arrays(seq, P["align"].contract).n_items):
        src = store.arrays(seq, P["align"].contract).read_item(v, ["source_frame", "source_index"])
        for f in np.unique(src["source_frame"]).tolist():
            covered.setdefault(f, np.sort(src["source_index"][src["source_frame"] == f]))
    for f, ref in enumerate(refs):
        n = reader.scan(ref).shape[0]
        assert labels[f].shape == (n,) and np.array_equal(covered[f], np.arange(n))
        assert set(np.unique(labels[f] & 0xFFFF).tolist()) <= set(LM.learning_map_inv.values())
    return labels


@pytest.fixture(scope="module")
def run4d(prefect_api_url, synth_log, ckpt, tmp_path_factory):
    """One uninterrupted 4D run (k = 2) of both sequences; tests work on copies of its store."""
    from flows.label import label_dataset

    root = tmp_path_factory.mktemp("run4d") / "run"
    summary = label_dataset(req(str(synth_log), str(root), None, stages(ckpt, 2), {"block_size": 3}))
    store = RunStore(root)
    return root, summary, {s: frame_labels(store, s) for s in SEQS}


@pytest.mark.slow
def test_label_4d_reruns_and_reprocesses_only_what_changed(run4d, synth_log, ckpt, tmp_path):
    from flows.label import label_dataset

    src, first, labels = run4d
    assert actions(first) == {(s, st): "fresh" for s in SEQS for st in ALL}
    root = tmp_path / "run"
    shutil.copytree(src, root)
    store = RunStore(root)
    for s in SEQS:
        assert (
            check_split_back(store, synth_log, s) and store.read_manifest(s, "stitch").counts["frames"] == 6
        )
        assert len(store.read_manifest(s, "stitch").blocks) == 1  # stitching is sequential

    again = label_dataset(req(str(synth_log), str(root), None, stages(ckpt, 2), {"block_size": 3}))
    assert set(actions(again).values()) == {"skip"} and all(r["blocks_run"] == 0 for r in again)

    dbscan = label_dataset(req(str(synth_log), str(root), ["00"], stages(ckpt, 2, {"kind": "dbscan"}), {}))
    acts = actions(dbscan)
    assert [acts[("00", st)] for st in ALL] == ["skip"] * 3 + ["fresh"] * 5
    assert not all(np.array_equal(a, b) for a, b in zip(frame_labels(store, "00"), labels["00"], strict=True))
    fp01 = RunStore(src).read_manifest("01", "shift").fingerprint
    assert store.read_manifest("01", "shift").fingerprint == fp01  # the other sequence is untouched
    assert store.read_manifest("00", "shift").config["clusterer"]["kind"] == "dbscan"

    other = make_checkpoint(tmp_path / "other", seed=1)
    new_model = label_dataset(
        req(str(synth_log), str(root), ["00"], stages(other, 2, {"kind": "dbscan"}), {})
    )
    acts = actions(new_model)
    assert [acts[("00", st)] for st in ALL] == ["skip"] * 2 + ["fresh"] * 6


def test_label_3d_ids_from_one_counter_export_and_eval(prefect_api_url, synth_log, ckpt, tmp_path):
    from typer.testing import CliRunner

    from flows.cli import app
    from flows.export import export_semantickitti
    from flows.label import label_dataset

    root = str(tmp_path / "run")
    stitched = {"method_options": {"temporal": "stitch", "refine": False}}  # k = 1 tracks by default
    summary = label_dataset(req(str(synth_log), root, None, stages(ckpt, 1), {"block_size": 4}, **stitched))
    assert actions(summary) == {(s, st): "fresh" for s in SEQS for st in ALL if st != "refine"}
    store = RunStore(root)
    for s in SEQS:
        labels = check_split_back(store, synth_log, s)
        per_frame = [set(np.unique(lab >> 16).tolist()) - {0} for lab in labels]
        every = sorted(i for ids in per_frame for i in ids)
        assert every == list(range(1, len(every) + 1))  # k = 1: fresh ids, one counter, never reused
        tracks = store.read_table(s, P["stitch"].table("tracks")).to_pydict()
        assert tracks["id"] == every and all(n == 1 for n in tracks["n_frames"])

    out = tmp_path / "export"
    exported = export_semantickitti(root, out)
    assert exported.frames == {"00": 6, "01": 6} and exported.missing == {"00": [], "01": []}
    ref = SemanticKittiReader(synth_log).frames("01")[4]
    written = np.fromfile(out / "sequences/01/predictions" / f"{ref.frame_id}.label", dtype=np.uint32)
    assert np.array_equal(written, store.arrays("01", P["stitch"].contract).read_item(4)["label"])

    runner = CliRunner()
    res = runner.invoke(
        app, ["export", root, "--format", "semantickitti", "--out", str(tmp_path / "cli-export")]
    )
    assert res.exit_code == 0, res.output
    assert "sequence 00: 6 label files" in res.stdout and "sequence 01: 6 label files" in res.stdout
    scores = tmp_path / "scores.json"
    pred = str(tmp_path / "cli-export")
    res = runner.invoke(
        app, ["eval", "--gt", str(synth_log), "--pred", pred, "--sequences", "00,01", "--json", str(scores)]
    )
    assert res.exit_code == 0, res.output
    data = json.loads(scores.read_text())
    assert data["frames"] == 12
    for key in ("pq", "pq_dagger", "pq_things", "pq_stuff", "miou", "lstq", "s_assoc", "s_cls", "per_class"):
        assert key in data
    assert 0 <= data["miou"] <= 1 and 0 <= data["lstq"] <= 1 and set(data["per_class"]) >= {"car", "road"}


KILL_AT_THIRD_VOLUME = (
    KILL_STITCH_AT_THIRD_VOLUME
    + """
sys.argv = ["dsnet", *sys.argv[1:]]
from flows.cli import main
main()
"""
)


@pytest.mark.slow
def test_4d_run_killed_during_stitch_resumes_to_identical_labels(run4d, synth_log, ckpt, tmp_path, cli_env):
    import sys

    from flows.label import label_dataset

    src, _, labels = run4d
    root = tmp_path / "run"
    shutil.copytree(src, root)
    argv = ["label", str(synth_log), "--run", str(root), "--sequences", "00", "--scans", "2"]
    argv += ["--checkpoint", str(ckpt), "--clusterer", json.dumps(FAST_SHIFT), "--from-stage", "stitch"]
    res = subprocess.run(
        [sys.executable, "-c", KILL_AT_THIRD_VOLUME, *argv],
        cwd=REPO,
        env=cli_env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == -signal.SIGKILL, res.stderr
    store = RunStore(root)
    assert store.read_manifest("00", "stitch").status == "running"
    # volumes 0 and 1 (frames 0, 1, 2) were written and their state saved before the kill
    assert store.arrays("00", P["stitch"].contract).done().tolist() == [True] * 3 + [False] * 3
    # the resume state is throttled (tasks.base.StateThrottle): the last one saved is volume 0 or 1
    assert store.root.read_json("sequences/00/stitch/state.json")["volume"] in (0, 1)

    resumed = label_dataset(req(str(synth_log), str(root), ["00"], stages(ckpt, 2), {}))
    acts = actions(resumed)
    before = ("ingest", "align", "infer", "shift", "fuse")
    assert acts[("00", "stitch")] == "resume" and all(acts[("00", s)] == "skip" for s in before)
    m = store.read_manifest("00", "stitch")
    assert m.status == "done" and m.counts == RunStore(src).read_manifest("00", "stitch").counts
    assert not store.root.exists("sequences/00/stitch/state.json")
    for a, b in zip(check_split_back(store, synth_log, "00"), labels["00"], strict=True):
        assert np.array_equal(a, b)  # identical to the uninterrupted run
    tracks = RunStore(src).read_table("00", P["stitch"].table("tracks"))
    assert store.read_table("00", P["stitch"].table("tracks")).equals(tracks)

"""Stage ``refine`` through the real runner and store: after a perturbed-ground-truth labels stage
(better scores, what changed), blocks and a SIGKILL mid-block (identical labels), and after the
DS-Net stages with a random-weight checkpoint at k = 2 (probabilities read per frame)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dsnet_core.io.semantickitti import SemanticKittiReader
from storage.run import RunStore
from tasks.methods import get_pipeline
from tasks.pipeline import Pipeline
from tasks.refine import CHANGES, TRACKS, FrameLoader, RefineStage
from tasks.score import ScoreStage
from tests.helpers.plain_runner import make_context, prepare_stage, run_stage_plain
from tests.tasks.oracle_stitch import LM
from tests.tasks.refine_pipelines import ORACLE_PLAIN, ORACLE_PROBS_REFINE, ORACLE_REFINE

REPO = Path(__file__).resolve().parents[2]


def _run(log, block_size: int, noise: float = 0.1) -> dict:
    return {
        "data": str(log),
        **ORACLE_REFINE.record(),
        "stages": {"oracle": {"noise": noise}},
        "options": {"block_size": block_size},
    }


def _label_all(store: RunStore, pipeline: Pipeline, run: dict, sequences=("00", "01")) -> None:
    store.write_run_config("r1", run)
    for seq in sequences:
        for stage in pipeline.names():
            run_stage_plain(store, pipeline, seq, stage, run, "r1")


def _labels(store: RunStore, seq: str = "00") -> list[np.ndarray]:
    arrays = store.arrays(seq, ORACLE_REFINE["refine"].contract)
    return [arrays.read_item(f)["label"] for f in range(arrays.n_items)]


@pytest.fixture(scope="module")
def refined(synth_log, tmp_path_factory):
    root = tmp_path_factory.mktemp("refine")
    store = RunStore(root / "refine")
    _label_all(store, ORACLE_REFINE, _run(synth_log, block_size=6))
    plain = RunStore(root / "plain")
    _label_all(plain, ORACLE_PLAIN, {**_run(synth_log, 6), **ORACLE_PLAIN.record()})
    return store, plain


def test_refine_repairs_the_perturbed_labels_and_says_what_it_changed(refined):
    store, plain = refined
    for seq in ("00", "01"):
        after = store.read_table(seq, ORACLE_REFINE["score"].table("frame_metrics")).to_pydict()
        before = plain.read_table(seq, ORACLE_PLAIN["score"].table("frame_metrics")).to_pydict()
        assert np.mean(after["miou"]) > np.mean(before["miou"]) + 0.02
        assert np.mean(after["pq"]) > np.mean(before["pq"])
        changes = store.read_table(seq, CHANGES).to_pydict()
        assert changes["index"] == list(range(6))
        assert all(c == t + s + g for c, t, s, g in zip(changes["changed"], changes["by_track"],
                   changes["by_static"], changes["by_ground"], strict=True))  # fmt: skip
        for i, frm, to, n in zip(changes["index"], changes["from_class"], changes["to_class"],
                                 changes["transitions"], strict=True):  # fmt: skip
            assert sum(n) == changes["class_changed"][i]
            assert not n or (set(to) <= set(range(1, 20)) and 9 in frm)  # the noise was "-> road"
        m = store.read_manifest(seq, "refine")
        assert m.counts["changed"] == sum(changes["changed"]) > 0
        tracks = store.read_table(seq, TRACKS).to_pydict()
        assert len(tracks["id"]) == m.plan["tracks"] - m.plan["joins"] - m.plan["dissolved"]
        assert m.plan["probs"] is None  # the oracle has hard labels only


def test_blocks_and_a_sigkill_mid_block_give_identical_labels(refined, synth_log, tmp_path):
    store, _ = refined
    reference = _labels(store)
    small = RunStore(tmp_path / "small")
    run = _run(synth_log, block_size=2)
    small.write_run_config("r1", run)
    for stage in ("ingest", "oracle"):
        run_stage_plain(small, ORACLE_REFINE, "00", stage, run, "r1")
    script = (
        "import os, signal, sys\n"
        "import dsnet_core.refine.sequence as s\n"
        "orig, calls = s._finish, [0]\n"
        "def finish(*a, **k):\n"
        "    calls[0] += 1\n"
        "    if calls[0] == 4:\n"
        "        os.kill(os.getpid(), signal.SIGKILL)\n"
        "    return orig(*a, **k)\n"
        "s._finish = finish\n"
        "from storage.run import RunStore\n"
        "from tasks.run_config import read_run\n"
        "from tasks.runner import run_stage_plain\n"
        "from tests.tasks.refine_pipelines import ORACLE_REFINE\n"
        "store = RunStore(sys.argv[1])\n"
        "run_stage_plain(store, ORACLE_REFINE, '00', 'refine', read_run(store, 'r1'), 'r1')\n"
    )
    res = subprocess.run(
        [sys.executable, "-c", script, str(small.uri)],
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == -signal.SIGKILL, res.stderr
    done = small.arrays("00", ORACLE_REFINE["refine"].contract).done().tolist()
    assert done == [True] * 3 + [False] * 3  # killed inside the second block of two frames
    d = prepare_stage(small, ORACLE_REFINE, "00", "refine", run, "r1")
    assert d.action == "resume" and [j.items for j in d.jobs] == [(2, 3), (4, 5)]
    resumed = run_stage_plain(small, ORACLE_REFINE, "00", "refine", run, "r1")
    assert resumed.status == "done"
    for got, want in zip(_labels(small), reference, strict=True):
        np.testing.assert_array_equal(got, want)
    for spec in (CHANGES, TRACKS):
        assert small.read_table("00", spec).equals(store.read_table("00", spec))
    assert resumed.counts == store.read_manifest("00", "refine").counts


def test_refine_refuses_an_upstream_without_per_frame_labels(synth_log, tmp_path):
    from storage.errors import StoreError
    from tasks.ingest import IngestStage

    pipeline = Pipeline("bad", (IngestStage(), RefineStage(labels="ingest")), labels="refine")
    store = RunStore(tmp_path / "run")
    run = {"data": str(synth_log), "stages": {}, "options": {}}
    store.write_run_config("r1", run)
    run_stage_plain(store, pipeline, "00", "ingest", run, "r1")
    with pytest.raises(StoreError, match="ingest declares no per-frame label"):
        prepare_stage(store, pipeline, "00", "refine", run, "r1")


def test_refine_reads_each_frames_probabilities_from_the_volumes(synth_log, tmp_path):
    pipeline = ORACLE_PROBS_REFINE
    gt_reader = SemanticKittiReader(synth_log)
    refs = gt_reader.frames("00")
    results = {}
    for block_size in (2, 6):
        store = RunStore(tmp_path / f"b{block_size}")
        run = {"data": str(synth_log), **pipeline.record(), "options": {"block_size": block_size},
               "stages": {"align": {"scans": 2}, "oracle": {"noise": 0.15}}}  # fmt: skip
        store.write_run_config("r1", run)
        m = {s: run_stage_plain(store, pipeline, "00", s, run, "r1") for s in pipeline.names()}
        assert m["refine"].plan["probs"] == "oracle_probs" and m["refine"].plan["align"] == "align"
        results[block_size] = [
            store.arrays("00", pipeline["refine"].contract).read_item(f)["label"] for f in range(6)
        ]
    ctx = make_context(store, pipeline, "00", "refine", run, m["refine"].plan)
    load = FrameLoader(ctx, "oracle", "oracle_probs", "align")
    align = store.arrays("00", pipeline["align"].contract)
    probs = store.arrays("00", pipeline["oracle_probs"].contract)
    for f in (0, 3, 5):  # frame 0 is only in volume 0; frames 3 and 5 are owned by volumes 2 and 4
        v = next(i for i, w in enumerate(m["align"].plan["windows"]) if f in w)
        assert v == max(f - 1, 0)
        src = align.read_item(v, ["source_frame", "source_index"])
        sel = src["source_frame"] == f
        frame = load(f)
        want = np.zeros_like(frame.probs)
        want[src["source_index"][sel]] = probs.read_item(v, ["probs"])["probs"][sel]
        np.testing.assert_array_equal(frame.probs, want)
        assert (
            frame.probs.shape == (gt_reader.labels(refs[f]).size, 20) and frame.probs[:, 1:].any(axis=1).all()
        )
    oracle = store.arrays("00", pipeline["oracle"].contract)
    lut = LM.lut(1 << 16, fill=0)
    for f in range(6):
        np.testing.assert_array_equal(results[2][f], results[6][f])  # blocks of 2 = one block
        gt = lut[gt_reader.labels(refs[f]) & 0xFFFF]
        before, after = lut[oracle.read_item(f)["label"] & 0xFFFF], lut[results[6][f] & 0xFFFF]
        wrong = (gt > 0) & (before != gt)
        fixed, broken = (wrong & (after == gt)).sum(), ((gt > 0) & (before == gt) & (after != gt)).sum()
        # measured: 59-67 % fixed (what stays wrong is far, sparsely seen stuff), 1 % broken
        assert fixed > 0.5 * wrong.sum() and broken < 0.02 * wrong.sum(), (f, wrong.sum(), fixed, broken)


@pytest.fixture(scope="module")
def dsnet_refined(synth_log, tmp_path_factory):
    from tests.model_helpers import make_checkpoint

    tmp = tmp_path_factory.mktemp("dsnet-refine")
    ckpt = make_checkpoint(tmp / "ckpt", seed=0)
    base = get_pipeline(refine=False)  # the stages before refine; refine and score added below
    stages = (
        *[s for s in base.stages if s.name != "score"],
        RefineStage(labels="stitch"),
        ScoreStage(labels="refine"),
    )
    pipeline = Pipeline("dsnet-refine", stages, labels="refine")
    run = {
        "data": str(synth_log),
        **pipeline.record(),
        "stages": {
            "align": {"scans": 2},
            "infer": {"checkpoint": str(ckpt)},
            "shift": {"clusterer": {"kind": "dynamic_shift", "n_seeds": 300, "bandwidths": [0.2, 1.8, 3.4]}},
        },
        "options": {"block_size": 2},
    }
    store = RunStore(tmp / "run")
    store.write_run_config("r1", run)
    manifests = {s: run_stage_plain(store, pipeline, "00", s, run, "r1") for s in pipeline.names()}
    return store, pipeline, run, manifests


@pytest.mark.slow
def test_after_the_dsnet_stages_refine_reads_infer_and_score_reads_refine(dsnet_refined):
    store, pipeline, _, m = dsnet_refined
    assert m["refine"].plan["probs"] == "infer" and m["refine"].plan["align"] == "align"
    assert m["refine"].status == m["score"].status == "done" and m["score"].n_items == 6
    assert m["score"].upstream == {"refine": m["refine"].fingerprint}
    for f in range(6):
        stitched = store.arrays("00", pipeline["stitch"].contract).read_item(f)["label"]
        refined = store.arrays("00", pipeline["refine"].contract).read_item(f)["label"]
        assert refined.shape == stitched.shape and refined.dtype == np.uint32

"""Stage ``score`` and the score report on a store whose stitch labels are perturbed ground truth."""

from __future__ import annotations

import math
import os

import duckdb
import numpy as np
import pyarrow as pa
import pyarrow.dataset as ds
import pytest

from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.metrics import PanopticEvaluator
from dsnet_core.review.confidence import MIN_INSTANCE_POINTS
from dsnet_core.viz.png import decode_png
from flows.report import headline_keys, read_report_table, write_report
from storage.run import RunStore
from tasks.methods import get_pipeline
from tests.helpers.plain_runner import prepare_stage, run_stage_plain
from tests.tasks.oracle_stitch import ORACLE, perturb

P = ORACLE  # ingest, the stand-in labels stage "oracle", score

SEQS = ("00", "01")
HIVE = ds.partitioning(pa.schema([("sequence", pa.string())]), flavor="hive")


def _label(store, log, mode="official", run_id="r1"):
    run = {"data": str(log), "stages": {"score": {"mode": mode}}, "options": {"block_size": 4}}
    store.write_run_config(run_id, run)
    for seq in SEQS:
        for stage in ("ingest", "oracle", "score"):
            run_stage_plain(store, P, seq, stage, run, run_id)
    return run


def _one_pass(log, seqs=SEQS, mode="official"):
    """The reference: one evaluator over every frame, in order, from the files themselves."""
    reader = SemanticKittiReader(log)
    ev = PanopticEvaluator(load_label_map("semantic-kitti"), mode=mode)
    for seq in seqs:
        for i, ref in enumerate(reader.frames(seq)):
            gt = reader.labels(ref)
            ev.add(gt, perturb(gt, i, 0.05, 0), frame=ref.frame_id, sequence=seq)
    return ev


def _same(a, b) -> bool:
    return (a is None and (b is None or math.isnan(b))) or a == b


@pytest.fixture
def scored(oracle_stages, synth_log, tmp_path):
    store = RunStore(tmp_path / "run")
    _label(store, synth_log)
    return store, write_report(store, P, bev_frames=3, review_rows=5)


def test_frame_rows_and_merged_numbers_equal_one_pass(scored, synth_log):
    store, _ = scored
    ref = _one_pass(synth_log)
    frames = {
        (r["sequence"], r["frame_id"]): r
        for r in ds.dataset(store.root.path("tables/frame_metrics"), partitioning=HIVE).to_table().to_pylist()
    }
    assert len(frames) == len(ref.rows) == 12
    for row in ref.rows:
        got = frames[(row.sequence, row.frame)]
        for key in ("n_points", "n_valid", "tp", "fp", "fn"):
            assert got[key] == getattr(row, key)
        for key in ("pq", "sq", "rq", "miou"):
            assert _same(got[key], getattr(row, key))
        for key in ("miou_present", "pq_present"):
            assert _same(got[key], row.values[key])
    res = ref.result()
    run = read_report_table(store, "score_run").to_pylist()[0]
    want = res.values  # every registered metric's value; the nuScenes-only ones are absent (null)
    assert want["pq"] == res.panoptic.pq and want["lstq"] == res.lstq.lstq
    for key in headline_keys():  # merged block accumulators == one pass, exactly
        assert _same(run[key], want.get(key)), key
    assert run["miou_present"] >= run["miou"] and run["pat"] is None
    assert 0.3 < run["pq"] < 1 and 0.3 < run["lstq"] < 1
    frame_pq = [r["pq"] for r in frames.values() if r["pq"] is not None]
    assert run["pq"] != pytest.approx(np.mean(frame_pq), abs=1e-9)  # not an average of frames
    assert run["mode"] == "official" and run["frames"] == 12 and run["sequences"] == 2
    assert run["run_id"] == "r1" and len(run["config_hash"]) == 16
    classes = {r["class"]: r for r in read_report_table(store, "score_classes").to_pylist()}
    assert len(classes) == 19 and classes["car"]["kind"] == "thing" and classes["road"]["kind"] == "stuff"
    for name, c in res.panoptic.per_class.items():
        assert classes[name]["pq"] == c.pq and classes[name]["iou"] == c.iou and classes[name]["tp"] == c.tp
    seqs = {r["sequence"]: r for r in read_report_table(store, "score_sequences").to_pylist()}
    for seq in SEQS:
        one = _one_pass(synth_log, (seq,)).result()
        assert _same(seqs[seq]["pq"], one.panoptic.pq) and _same(seqs[seq]["lstq"], one.lstq.lstq)
        assert seqs[seq]["frames"] == 6


def test_timings_pictures_and_review_queue(scored):
    store, _ = scored
    timings = read_report_table(store, "stage_timings").to_pylist()
    assert {(t["sequence"], t["stage"]) for t in timings} == {
        (s, g) for s in SEQS for g in ("ingest", "oracle", "score")
    }
    score = next(t for t in timings if t["stage"] == "score" and t["sequence"] == "00")
    assert (
        score["items"] == 6
        and score["block_s"] > 0
        and score["items_per_s"] == pytest.approx(6 / score["block_s"])
    )
    bev = read_report_table(store, "score_bev").to_pylist()
    frame_pq = sorted(
        r["pq"]
        for r in ds.dataset(store.root.path("tables/frame_metrics"), partitioning=HIVE).to_table().to_pylist()
        if r["pq"] is not None
    )
    assert [b["rank"] for b in bev] == [0, 1, 2] and [b["pq"] for b in bev] == frame_pq[:3]
    pred, gt = decode_png(bev[0]["png_pred"]), decode_png(bev[0]["png_gt"])
    assert pred.shape == gt.shape == (240, 240, 3)
    assert (pred != gt).any(axis=2).sum() > 50  # the perturbation shows
    assert len(np.unique(gt.reshape(-1, 3), axis=0)) > 5  # several instance/class colours
    review = read_report_table(store, "review_queue").to_pylist()
    tracks = ds.dataset(store.root.path("tables/oracle_tracks"), partitioning=HIVE).to_table().to_pylist()
    listed = [t for t in tracks if t["n_points"] >= MIN_INSTANCE_POINTS]  # no fragments, no 1-point ids
    assert len(listed) < len(tracks) and min(r["points"] for r in review) >= MIN_INSTANCE_POINTS
    assert [r["confidence"] for r in review] == sorted(t["confidence"] for t in listed)[:5]
    assert all(r["source"] == "oracle/oracle_tracks" for r in review)
    first = next(
        t for t in tracks if t["confidence"] == review[0]["confidence"] and t["id"] == review[0]["instance"]
    )
    assert review[0]["item"] == first["first_frame"] and review[0]["points"] == first["n_points"]
    assert review[0]["class"] == load_label_map("semantic-kitti").class_names[first["class_id"]]


def test_readme_queries(scored):
    """The two queries documented in the README, verbatim apart from the root."""
    store, _ = scored
    root = store.uri
    con = duckdb.connect()
    worst = con.execute(
        f"""
        SELECT sequence, frame_id, pq, n_points
        FROM read_parquet('{root}/tables/frame_metrics/*/*.parquet', hive_partitioning = true,
                          hive_types = {{'sequence': VARCHAR}})
        WHERE pq IS NOT NULL ORDER BY pq LIMIT 5
        """
    ).fetchall()
    bev = read_report_table(store, "score_bev").to_pylist()
    assert [(w[0], w[1]) for w in worst[:3]] == [(b["sequence"], b["frame_id"]) for b in bev]
    assert isinstance(worst[0][0], str) and worst[0][0] in SEQS
    classes = (
        ds.dataset(f"{root}/tables/score_classes", format="parquet")
        .to_table(filter=ds.field("kind") == "thing", columns=["class", "pq", "sq", "rq", "iou"])
        .to_pylist()
    )
    assert [c["class"] for c in classes] == list(load_label_map("semantic-kitti").class_names[1:9])


def test_resume_after_lost_block_gives_the_same_report(scored, synth_log):
    store, report = scored
    run = store.read_run_config()
    os.remove(store.root.path("sequences/00/score/blocks/00001.json"))
    m = store.read_manifest("00", "score")
    m.status = "running"
    store.write_manifest(m)
    d = prepare_stage(store, P, "00", "score", run, "r1")
    assert d.action == "resume" and [j.block for j in d.jobs] == [1]
    run_stage_plain(store, P, "00", "score", run, "r1")
    again = write_report(store, P, bev_frames=3, review_rows=5)
    for key in headline_keys():
        assert _same(again.run[key], report.run[key])


def test_corrected_mode_is_recorded_and_refingerprints(oracle_stages, synth_log, tmp_path):
    store = RunStore(tmp_path / "run")
    _label(store, synth_log, "official")
    fp = store.read_manifest("00", "score").fingerprint
    _label(store, synth_log, "corrected", "r2")
    assert store.read_manifest("00", "score").fingerprint != fp
    run = write_report(store, P, bev_frames=0).run
    ref = _one_pass(synth_log, mode="corrected").result()
    assert run["mode"] == "corrected" and run["lstq"] == ref.lstq.lstq and run["pq"] == ref.panoptic.pq
    assert read_report_table(store, "score_bev").num_rows == 0


def test_a_log_without_ground_truth_scores_nothing(oracle_stages, tmp_path):
    import shutil

    from tests.logs import make_log

    log = make_log(tmp_path / "log", ("00",), n_frames=3)
    shutil.rmtree(log / "sequences/00/labels")
    store = RunStore(tmp_path / "run")
    run = {"data": str(log), "stages": {}, "options": {"block_size": 2}}
    store.write_run_config("r1", run)
    for stage in ("ingest", "oracle", "score"):
        m = run_stage_plain(store, P, "00", stage, run, "r1")
    assert m.status == "done" and m.n_items == 0
    assert store.read_table("00", P["score"].table("frame_metrics")).num_rows == 0
    assert write_report(store, P) is None


def test_model_card_id_comes_from_the_model_stage_plan(tmp_path):
    from dsnet_core.labels import class_map_of
    from flows.report.merge import model_plan
    from storage.manifest import Manifest
    from tasks.base import CLASS_MAP

    dsnet = get_pipeline("dsnet")
    store = RunStore(tmp_path / "run")
    assert model_plan(store, dsnet, ["00"]) == {}  # no model stage ran
    # infer records the checkpoint it resolved (configured or bundled) and its card's class map
    plan = {"model_card": "tiny-v2@" + "ab" * 6, CLASS_MAP: class_map_of(load_label_map("semantic-kitti"))}
    m = Manifest(
        stage="infer", sequence="00", fingerprint="f", status="done", code_version="1", config={},
        upstream={}, inputs="", run_id="r1", plan=plan,
    )  # fmt: skip
    store.write_manifest(m)
    assert model_plan(store, dsnet, ["00"])["model_card"] == "tiny-v2@" + "ab" * 6


def test_a_block_state_of_another_layout_or_metrics_is_refused_naming_it(oracle_stages, synth_log, tmp_path):
    from dsnet_core.metrics.registry import METRICS, STATE_FORMAT, register
    from dsnet_core.metrics.state import state_from_bytes, state_to_bytes
    from storage.errors import StoreError
    from tasks.score import ScoreStage, block_state_name
    from tests.flows.test_metric_registry import TOY

    assert ScoreStage.version == "2" and STATE_FORMAT == "2"
    store = RunStore(tmp_path / "run")
    _label(store, synth_log)
    name = block_state_name(0)
    state = state_from_bytes(store.read_block_bytes("00", "score", name))
    old = {k: v for k, v in state.items() if k != "format"}  # as a version-1 block left it: no layout
    store.write_block_bytes("00", "score", name, state_to_bytes(old))
    with pytest.raises(
        StoreError, match=rf"00/score/blocks/{name}: scorer state: layout 1, this version reads"
    ):
        write_report(store, P)
    store.write_block_bytes("00", "score", name, state_to_bytes(state))
    assert write_report(store, P) is not None  # the state as written restores
    fp = store.read_manifest("00", "score").fingerprint
    register(TOY)
    try:  # a metric registered since the blocks were scored: refused, until the stage reruns
        with pytest.raises(StoreError, match=r"holds metrics .* the registry now has"):
            write_report(store, P)
        _label(store, synth_log, run_id="r2")  # the registered metrics are an input: it rescores
        assert store.read_manifest("00", "score").fingerprint != fp
        assert 0 < write_report(store, P, bev_frames=0).run["valid_share"] <= 1
    finally:
        METRICS.pop(TOY.name)

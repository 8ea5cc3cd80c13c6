"""Refinement judged where ground truth exists: the report scores the labels refine read (before)
with the score stage's scorer, beside the score stage's numbers of the refined labels (after), and
the page shows both. The oracle labels stage (perturbed ground truth) refined by the real refine
stage, on the synthetic log's two sequences; sequence 01 has its labels removed, so one page holds a
scored and an unscored sequence."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest

from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.metrics import PanopticEvaluator
from flows.dashboard import build_dashboard
from flows.report.merge import write_report
from flows.report.tables import REPORT_TABLES
from storage.run import RunStore
from tasks.base import labels_contract
from tasks.ingest import IngestStage
from tasks.pipeline import Pipeline
from tasks.refine import RefineStage
from tasks.score import ScoreStage
from tests.helpers.plain_runner import run_stage_plain
from tests.tasks.oracle_stitch import OracleStitch

LM = load_label_map("semantic-kitti")
REFINED = Pipeline(
    "oracle-refined",
    (IngestStage(), OracleStitch(), RefineStage(labels="oracle"), ScoreStage(labels="refine")),
    labels="refine",
)


@pytest.fixture(scope="module")
def refined(synth_log, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("refined")
    log = tmp / "log"
    shutil.copytree(synth_log, log)
    shutil.rmtree(log / "sequences" / "01" / "labels")
    store = RunStore(tmp / "run")
    run = {
        "data": str(log),
        **REFINED.record(),
        "stages": {"oracle": {"noise": 0.1}},
        "options": {"block_size": 3},
    }
    store.write_run_config("r1", run)
    for seq in ("00", "01"):
        for stage in REFINED.names():
            run_stage_plain(store, REFINED, seq, stage, run, "r1")
    report = write_report(store, REFINED, bev_frames=2, review_rows=8)
    return store, log, report


def _table(store, name):
    return store.read_all(REPORT_TABLES[name]).to_pylist()


def test_before_and_after_scores(refined):
    store, log, report = refined
    reader = SemanticKittiReader(log)
    before, after = PanopticEvaluator(LM), PanopticEvaluator(LM)
    for i, frame in enumerate(reader.frames("00")):
        gt = reader.labels(frame)
        before.add(
            gt, store.arrays("00", labels_contract("oracle")).read_item(i)["label"], frame.frame_id, "00"
        )
        after.add(
            gt, store.arrays("00", labels_contract("refine")).read_item(i)["label"], frame.frame_id, "00"
        )
    b, a = before.result(), after.result()
    rows = {(r["scope"], r["sequence"], r["class"]): r for r in _table(store, "refine_scores")}
    assert {k[:2] for k in rows} == {("run", ""), ("sequence", "00"), ("class", "")}  # 01: no truth
    for key in (("run", "", ""), ("sequence", "00", "")):
        r = rows[key]
        assert (
            r["pq_before"] == b.panoptic.pq
            and r["iou_before"] == b.panoptic.miou
            and r["lstq_before"] == b.lstq.lstq
        )
        assert r["pq_after"] == a.panoptic.pq == report.run["pq"] and r["lstq_after"] == report.run["lstq"]
    for name in ("car", "road", "vegetation"):
        r = rows[("class", "", name)]
        assert (
            r["pq_before"] == b.panoptic.per_class[name].pq
            and r["iou_after"] == a.panoptic.per_class[name].iou
        )
    assert a.panoptic.miou != b.panoptic.miou  # refinement changed something the scorer sees


def test_one_page_with_scored_and_unscored_sequences(refined):
    store, _, _ = refined
    seqs = {s["sequence"]: s for s in _table(store, "label_sequences")}
    assert (seqs["00"]["scored"], seqs["00"]["truth_frames"]) == (True, 6)
    assert (seqs["01"]["scored"], seqs["01"]["truth_frames"]) == (False, 0)
    assert seqs["00"]["refined"] and seqs["01"]["refined"] and seqs["00"]["confidence"] is None  # no probs
    legend = _table(store, "class_legend")
    assert {r["map"] for r in legend} == {"model", "truth"}
    page = build_dashboard([store.uri], store.root.path("d.html")).read_text()
    for sid in ("s-headline", "s-worst", "s-labelled", "s-confidence", "s-tracks", "s-refine", "s-review"):
        assert f'id="{sid}"' in page, sid
    r = {x["scope"]: x for x in _table(store, "refine_scores") if x["scope"] != "class"}
    assert f'data-k="rs:0:run:::pq_before" data-v="{r["run"]["pq_before"]!r}"' in page
    assert "stores no per-point probabilities" in page  # the oracle has no model probabilities
    score = _table(store, "score_run")[0]
    assert score["sequences"] == 1 and math.isfinite(score["pq"])
    assert np.isclose(
        sum(c["points"] for c in _table(store, "label_classes")), sum(s["points"] for s in seqs.values())
    )

"""End to end: the label flow runs every stage (random-weight tiny checkpoint) and then the score
stage; the report, dashboard and artifacts follow; the numbers equal a one-pass evaluator over
the stitched labels."""

from __future__ import annotations

import math

import numpy as np
import pytest
from prefect.artifacts import Artifact

from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.metrics import PanopticEvaluator
from flows.report import headline_keys, read_report_table
from storage.run import RunStore
from tasks.methods import get_pipeline
from tests.helpers.label_request import req
from tests.model_helpers import make_checkpoint

P = get_pipeline()  # the DS-Net stages


FAST_SHIFT = {"kind": "dynamic_shift", "n_seeds": 300, "bandwidths": [0.2, 1.8, 3.4]}


@pytest.mark.slow
def test_label_flow_scores_reports_and_publishes(prefect_api_url, synth_log, tmp_path):
    from flows.label import label_dataset

    ckpt = make_checkpoint(tmp_path / "tiny", seed=0)
    stages = {"align": {"scans": 1}, "infer": {"checkpoint": str(ckpt)}, "shift": {"clusterer": FAST_SHIFT}}
    root = tmp_path / "run"
    summary = label_dataset(req(str(synth_log), str(root), None, stages, {"block_size": 4}))
    assert {(r["sequence"], r["action"]) for r in summary if r["stage"] == "score"} == {
        ("00", "fresh"),
        ("01", "fresh"),
    }
    store = RunStore(root)
    from tasks.run_config import read_run

    used = read_run(store).pipeline()  # k = 1: tracked ids (``track``), then refined (the default)
    assert used.labels == "refine" and "track" in used
    reader = SemanticKittiReader(synth_log)
    ref = PanopticEvaluator(load_label_map("semantic-kitti"))
    for seq in ("00", "01"):
        arrays = store.arrays(seq, used[used.labels].contract)
        for i, frame in enumerate(reader.frames(seq)):
            ref.add(reader.labels(frame), arrays.read_item(i)["label"], frame.frame_id, seq)
    want = ref.result()
    run = read_report_table(store, "score_run").to_pylist()[0]
    for key in headline_keys():
        v = want.values.get(key, math.nan)  # the nuScenes-only metrics: null here
        assert (run[key] is None and math.isnan(v)) or run[key] == v, key
    assert run["frames"] == 12 and run["model_card"].startswith("tiny@")
    stages_timed = {t["stage"] for t in read_report_table(store, "stage_timings").to_pylist()}
    assert stages_timed == {"ingest", "align", "infer", "shift", "fuse", "track", "refine", "score"}
    review = read_report_table(store, "review_queue").to_pylist()
    assert review and review[0]["source"] in ("fuse/instances", "track/tracked")
    assert [r["confidence"] for r in review] == sorted(r["confidence"] for r in review)
    assert (root / "dashboard.html").stat().st_size > 10_000
    md = Artifact.get(f"score-summary-{synth_log.name.replace('_', '-')}")
    assert f"Dashboard: `{root / 'dashboard.html'}`" in md.data
    again = label_dataset(req(str(synth_log), str(root), None, stages, {"block_size": 4}))
    assert {r["action"] for r in again if r["stage"] == "score"} == {"skip"}
    frames = np.array(read_report_table(store, "score_sequences")["frames"].to_pylist())
    assert frames.tolist() == [6, 6]

"""``dsnet label --method most`` end to end through the real command line (a random-weight MOST
checkpoint biased to detect cars), exported and scored by ``dsnet eval``; DS-Net-only settings
are refused with the flag's name."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest
from typer.testing import CliRunner

from flows.cli import app
from flows.report.review import review_queue
from flows.report.tables import REPORT_TABLES
from storage.run import RunStore
from tasks.run_config import RunConfig
from tests.flows.conftest import cli
from tests.model_helpers import make_most_checkpoint


def test_label_method_most_then_export_and_eval(synth_log, tmp_path, cli_env):
    ckpt = make_most_checkpoint(tmp_path / "most", cars=True)
    run = tmp_path / "run"
    args = ["label", str(synth_log), "--run", str(run), "--method", "most", "--checkpoint", str(ckpt)]
    res = subprocess.run(cli(*args, "--scans", "2", "--sequences", "00"), env=cli_env, capture_output=True,
                         text=True, timeout=600)  # fmt: skip
    assert res.returncode == 0, res.stdout + res.stderr
    store = RunStore(run)
    config = store.read_run_config()
    assert config["method"] == "most" and config["stages"]["most"]["scans"] == 2
    pipeline = RunConfig.of(config).pipeline()
    assert pipeline.names() == ["ingest", "align", "most", "track", "refine", "score"]  # refine by default
    assert store.read_manifest("00", "refine").status == "done" and pipeline.labels == "refine"
    _most_confidence_and_review(store, pipeline, run, tmp_path)

    runner = CliRunner()
    out = tmp_path / "export"
    res = runner.invoke(app, ["export", str(run), "--format", "semantickitti", "--out", str(out)])
    assert res.exit_code == 0, res.output
    scores = tmp_path / "scores.json"
    res = runner.invoke(
        app, ["eval", "--gt", str(synth_log), "--pred", str(out), "--sequences", "00", "--json", str(scores)]
    )
    assert res.exit_code == 0, res.output
    data = json.loads(scores.read_text())
    assert data["frames"] == 6 and 0 <= data["pq"] <= 1 and 0 <= data["lstq"] <= 1


def test_label_method_most_refuses_dsnet_settings(tmp_path):
    res = CliRunner().invoke(
        app,
        ["label", str(tmp_path), "--run", str(tmp_path / "r"), "--method", "most", "--tta", "4"],
        env={"COLUMNS": "250"},
    )
    assert res.exit_code == 2 and "--tta: not a setting of method most" in res.output


def _most_confidence_and_review(store: RunStore, pipeline, run, tmp_path) -> None:
    """MOST declares no probabilities but instances with detection confidences: every frame gets a
    confidence row (semantic 1, agreement the point-weighted detection confidence), the review
    queue lists its detections and refined tracks, and ``dsnet review export`` ranks its frames."""
    rows = store.read_all(REPORT_TABLES["frame_confidence"]).to_pylist()
    assert sorted(r["index"] for r in rows) == list(range(6))
    det = store.read_table("00", pipeline["most"].table("detections")).to_pydict()
    for r in rows:
        assert r["semantic"] == 1.0 and r["stitch"] == 1.0
        inst = store.arrays("00", pipeline["most"].contract).read_item(r["index"], ["inst"])["inst"]
        assert r["n_points"] == inst.size
        ids, counts = np.unique(inst[inst > 0], return_counts=True)
        conf = {
            i: c
            for v, i, c in zip(det["index"], det["id"], det["confidence"], strict=True)
            if v == r["index"]
        }
        assert r["n_instances"] == ids.size
        if ids.size:
            want = sum(conf[int(i)] * n for i, n in zip(ids, counts, strict=True)) / counts.sum()
            assert r["agreement"] == pytest.approx(want, rel=1e-6)
    assert any(r["n_instances"] for r in rows)  # the biased model detects cars
    queue = store.read_all(REPORT_TABLES["review_queue"]).to_pylist()
    # the random-weight model's instances are all under 30 points: the report's queue leaves them out
    assert queue == review_queue(store, pipeline, ["00"], None, 30) == []
    small = review_queue(store, pipeline, ["00"], None, 100, min_points=1)
    assert {q["source"] for q in small} == {"most/detections", "refine/refine_tracks"}
    assert [q["confidence"] for q in small] == sorted(q["confidence"] for q in small)
    assert sum(q["source"] == "most/detections" for q in small) == sum(n >= 1 for n in det["n_points"])
    res = CliRunner().invoke(app, ["review", "export", str(run), "--top", "2", "--out", str(tmp_path / "rv")])
    assert res.exit_code == 0, res.output
    assert len(json.loads((tmp_path / "rv" / "review.json").read_text())["frames"]) == 2

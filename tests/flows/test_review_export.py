"""Frame confidence for a run without scoring, and ``dsnet review export`` of its least confident
frames (plain runner, k = 2, random-weight tiny checkpoint on the synthetic vlp32 log)."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from dsnet_core.io.semantickitti import SemanticKittiReader
from flows.cli import app
from flows.publish import write_frame_confidence
from flows.report.confidence import frame_confidence_rows
from flows.report.tables import REPORT_TABLES
from storage.run import RunStore
from tasks.infer import dequantise_probs
from tasks.methods import get_pipeline
from tests.helpers.plain_runner import run_stage_plain
from tests.model_helpers import make_checkpoint

P = get_pipeline(refine=False)
STAGES = ("ingest", "align", "infer", "shift", "fuse", "stitch")  # no score stage: no ground truth used


@pytest.fixture(scope="module")
def run(synth_log, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("review")
    ckpt = make_checkpoint(tmp / "ckpt", seed=0)
    store = RunStore(tmp / "run")
    cfg = {
        **P.record(),
        "data": str(synth_log),
        "stages": {
            "align": {"scans": 2},
            "infer": {"checkpoint": str(ckpt)},
            "shift": {"clusterer": {"kind": "dynamic_shift", "n_seeds": 300, "bandwidths": [0.2, 1.8, 3.4]}},
        },
        "options": {"block_size": 3},
    }
    store.write_run_config("r1", cfg)
    for s in STAGES:
        run_stage_plain(store, P, "00", s, cfg, "r1")
    return store, synth_log


def test_frame_confidence_table(run):
    store, _ = run
    assert write_frame_confidence(store, P) == 6  # sequence 00's six frames; 01 was not labelled
    t = store.read_all(REPORT_TABLES["frame_confidence"]).to_pydict()
    assert sorted(t["index"]) == list(range(6)) and t["score"] == sorted(t["score"])
    for k in ("semantic", "agreement", "size", "stitch", "score"):
        assert all(0.0 <= v <= 1.0 for v in t[k])
    row = t["index"].index(0)  # frame 0 belongs to the first volume
    src = store.arrays("00", P["align"].contract).read_item(0, ["source_frame"])["source_frame"]
    probs = dequantise_probs(store.arrays("00", P["infer"].contract).read_item(0, ["probs"])["probs"])
    assert t["semantic"][row] == pytest.approx(float(probs[src == 0].max(axis=1).mean()))
    assert t["n_points"][row] == int((src == 0).sum())


def test_review_export(run, tmp_path):
    store, log = run
    res = CliRunner().invoke(
        app, ["review", "export", str(store.uri), "--top", "3", "--out", str(tmp_path / "rv")]
    )
    assert res.exit_code == 0, res.output
    rows = frame_confidence_rows(store, P, ["00"])[:3]
    manifest = json.loads((tmp_path / "rv" / "review.json").read_text())
    assert [f["frame"] for f in manifest["frames"]] == [r["frame_id"] for r in rows]
    reader, out = SemanticKittiReader(log), SemanticKittiReader(tmp_path / "rv")
    stitch = store.arrays("00", P["stitch"].contract)
    for ref in out.frames("00"):
        index = next(r["index"] for r in rows if r["frame_id"] == ref.frame_id)
        assert np.array_equal(out.scan(ref), reader.scan(reader.frames("00")[index]))
        assert np.array_equal(out.labels(ref), stitch.read_item(index, ["label"])["label"])
    again = CliRunner().invoke(
        app, ["review", "export", str(store.uri), "--top", "3", "--out", str(tmp_path / "rv")]
    )
    assert again.exit_code == 2 and "already holds frames" in again.output


def test_a_zero_point_run_says_it_has_no_points(tmp_path):
    """A log whose scans are all empty (0-byte ``.bin``): labelled through every stage; the review
    export and the dashboard say the run has no points (was: "has `dsnet label` finished?", and
    "stores no per-point probabilities")."""
    from dsnet_core.io.kitti import read_scan
    from dsnet_core.synth import generate_log

    log = tmp_path / "log"
    generate_log(log, sequences=1, frames=3, seed=0, sensor="vlp32")
    for f in [*log.glob("sequences/*/velodyne/*.bin"), *log.glob("sequences/*/labels/*.label")]:
        f.write_bytes(b"")
    assert read_scan(next(log.glob("sequences/00/velodyne/*.bin"))).shape == (0, 4)
    store = RunStore(tmp_path / "run")
    ckpt = make_checkpoint(tmp_path / "ck", seed=0)
    cfg = {**P.record(), "data": str(log), "options": {"block_size": 3},
           "stages": {"align": {"scans": 2}, "infer": {"checkpoint": str(ckpt)}}}  # fmt: skip
    store.write_run_config("r1", cfg)
    for s in P.names():
        run_stage_plain(store, P, "00", s, cfg, "r1")
    res = CliRunner().invoke(app, ["review", "export", store.uri, "--out", str(tmp_path / "rev")])
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert res.output.strip() == (
        f"error: {store.uri}: the run has no points (its 3 frames are empty): nothing to review"
    )
    res = CliRunner().invoke(app, ["dashboard", store.uri, "--out", str(tmp_path / "d.html")])
    assert res.exit_code == 0, res.output
    page = (tmp_path / "d.html").read_text()
    assert "the run has no points: no confidences" in page and "per-point probabilities" not in page

"""A metric added through the registry alone reaches ``dsnet eval``, the score tables and the
dashboard; an export format added through its registry alone reaches ``dsnet export``."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from typer.testing import CliRunner

from dsnet_core.io import kitti
from dsnet_core.io.semantickitti import write_frame
from dsnet_core.metrics.registry import METRICS, Column, Frame, Metric, Setup, register
from flows.cli import app


class ValidShare:
    """Toy metric: the share of points whose ground truth is scored (two integers of state)."""

    def __init__(self, setup: Setup) -> None:
        self.valid = self.points = 0

    def add(self, frame: Frame) -> dict[str, float]:
        self.valid += frame.pq.n_valid
        self.points += frame.cells.n_points
        return {"valid_share": frame.pq.n_valid / max(frame.cells.n_points, 1)}

    def merge(self, other: ValidShare) -> None:
        self.valid += other.valid
        self.points += other.points

    def state(self) -> dict[str, np.ndarray]:
        return {"counts": np.array([self.valid, self.points], dtype=np.int64)}

    def restore(self, state: dict[str, np.ndarray]) -> None:
        self.valid, self.points = (int(x) for x in state["counts"])

    def values(self) -> dict[str, float]:
        return {"valid_share": self.valid / self.points if self.points else float("nan")}

    def class_values(self) -> dict[str, dict[str, float]]:
        return {}


TOY = Metric(
    name="toy_valid_share",
    make=ValidShare,
    columns=(Column("valid_share", "valid share", brief=True, help="scored points / all points"),),
    frame_columns=(Column("valid_share", "valid share"),),
    title="toy",
)


@pytest.fixture
def toy_metric():
    register(TOY)
    yield TOY
    METRICS.pop(TOY.name)


def _log(root) -> tuple:
    rng = np.random.default_rng(1)
    gt_root, pred_root = root / "gt", root / "pred"
    for k in range(2):
        gt = np.concatenate([np.full(300, 40), np.full(100, 10 | (1 << 16)), np.full(100, 0)]).astype(
            np.uint32
        )
        gt = gt[rng.permutation(gt.size)]
        write_frame(gt_root / "sequences" / "08", f"{k:06d}", np.zeros((gt.size, 4), np.float32), gt)
        kitti.write_label(pred_root / "sequences" / "08" / "predictions" / f"{k:06d}.label", gt)
    return gt_root, pred_root


def test_a_registered_metric_reaches_eval(toy_metric, tmp_path):
    gt_root, pred_root = _log(tmp_path)
    out = tmp_path / "s.json"
    res = CliRunner().invoke(
        app, ["eval", "--gt", str(gt_root), "--pred", str(pred_root), "--json", str(out)]
    )
    assert res.exit_code == 0, res.output
    assert "valid share" in res.output and "mIoU (present)" in res.output
    report = json.loads(out.read_text())
    assert report["valid_share"] == pytest.approx(0.8) and report["pq"] == pytest.approx(
        2 / 19
    )  # 2 of 19 classes
    assert report["miou_present"] == 1.0 and report["present_classes"] == 2


def test_a_registered_metric_reaches_the_score_tables_and_the_dashboard(toy_metric, tmp_path, synth_log):
    import pyarrow.parquet as pq

    from flows.dashboard import build_dashboard
    from tests.tasks.oracle_stitch import score_runs

    uris = score_runs(tmp_path, synth_log, {"runA": 0.05}, bev=1)
    run = pq.read_table(f"{uris[0]}/tables/score_run/part-0.parquet").to_pylist()[0]
    seqs = pq.read_table(f"{uris[0]}/tables/score_sequences/part-0.parquet").to_pylist()
    frames = pq.read_table(f"{uris[0]}/tables/frame_metrics").to_pylist()
    assert 0 < run["valid_share"] <= 1 and all(0 < s["valid_share"] <= 1 for s in seqs)
    assert frames and all(0 < f["valid_share"] <= 1 for f in frames)
    assert run["miou_present"] >= run["miou"] and run["pat"] is None
    page = build_dashboard(uris, tmp_path / "dashboard.html").read_text()
    shown = dict(re.findall(r'data-k="([^"]+)" data-v="([^"]*)"', page))
    assert float(shown["run:0:valid_share"]) == run["valid_share"]
    assert float(shown["card:valid_share"]) == run["valid_share"]
    assert float(shown["run:0:miou_present"]) == run["miou_present"] and "mIoU (present)" in page
    assert "run:0:pat" not in shown  # a metric the run's scorer does not compute: no row


def test_an_export_format_registered_alone_reaches_dsnet_export(tmp_path, synth_log):
    from flows.export import final_labels
    from flows.export_formats import EXPORTS, ExportFormat, register_export
    from storage.run import RunStore
    from tests.tasks.oracle_stitch import score_runs

    def write(root, out, sequences, options):
        counts: dict[str, int] = {}
        for seq, _, label in final_labels(RunStore(root), sequences):
            counts[seq] = counts.get(seq, 0) + int(label is not None)
        out.mkdir(parents=True, exist_ok=True)
        (out / f"frames.{options['suffix']}").write_text(json.dumps(counts))
        return counts

    register_export(
        ExportFormat(
            "frame-counts", write, lambda c: [f"counted {sum(c.values())} frames"], "toy", {"suffix": "json"}
        )
    )
    try:
        (uri,) = score_runs(tmp_path, synth_log, {"runA": 0.0}, bev=0)
        out = tmp_path / "out"
        res = CliRunner().invoke(app, ["export", uri, "--out", str(out), "--format", "frame-counts"])
        assert res.exit_code == 0, res.output
        assert "counted 12 frames" in res.output
        assert json.loads((out / "frames.json").read_text()) == {"00": 6, "01": 6}
        bad = CliRunner().invoke(app, ["export", uri, "--out", str(out), "--format", "nope"])
        assert bad.exit_code == 2 and "frame-counts" in bad.output
    finally:
        EXPORTS.pop("frame-counts")

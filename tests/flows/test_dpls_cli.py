"""``dsnet label --method dpls`` end to end through the real command line (ground truth as the user's
semantic prior, a random-weight D-PLS checkpoint), exported and scored by ``dsnet eval``; the prior's
flags are refused for other methods and DS-Net-only flags for dpls, by name."""

from __future__ import annotations

import json
import subprocess

from typer.testing import CliRunner

from flows.cli import app
from storage.run import RunStore
from tasks.run_config import RunConfig
from tests.flows.conftest import cli
from tests.model_helpers import make_dpls_checkpoint, write_gt_prior


def test_label_method_dpls_with_a_user_prior_then_export_and_eval(synth_log, tmp_path, cli_env):
    ckpt = make_dpls_checkpoint(tmp_path / "dpls")
    prior = write_gt_prior(synth_log, tmp_path / "prior", layout="flat")
    run = tmp_path / "run"
    args = ["label", str(synth_log), "--run", str(run), "--method", "dpls", "--checkpoint", str(ckpt),
            "--semantic-prior", str(prior), "--prior-label-map", "semantic-kitti"]  # fmt: skip
    res = subprocess.run(cli(*args, "--scans", "2", "--sequences", "00"), env=cli_env, capture_output=True,
                         text=True, timeout=600)  # fmt: skip
    assert res.returncode == 0, res.stdout + res.stderr
    store = RunStore(run)
    config = store.read_run_config()
    assert config["method"] == "dpls"
    assert config["stages"]["prior"] == {"source": "user", "path": str(prior), "label_map": "semantic-kitti"}
    assert config["stages"]["shift"] == {"clusterer": {"kind": "dbscan"}}
    pipeline = RunConfig.of(config).pipeline()
    assert pipeline.names() == [
        *("ingest", "align", "prior", "dpls", "shift", "fuse", "stitch", "refine", "score")
    ]  # refine by default
    assert store.read_manifest("00", "refine").status == "done"

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
    # the semantics are the (ground-truth) prior's, but for the majority vote inside random-weight instances
    assert data["frames"] == 6 and data["miou"] > 0.9


def test_prior_flags_belong_to_dpls_and_dsnet_flags_do_not(tmp_path):
    runner = CliRunner()
    for extra, message in [
        (["--method", "most", "--semantic-prior", "p"], "--semantic-prior: not a setting of method most"),
        (["--prior-label-map", "x.yaml"], "--prior-label-map: not a setting of method dsnet"),
        (["--method", "dpls", "--tta", "4"], "--tta: not a setting of method dpls"),
        (["--method", "dpls", "--prior-label-map", "x.yaml"], "--prior-label-map: names the label map"),
    ]:
        res = runner.invoke(
            app, ["label", str(tmp_path), "--run", str(tmp_path / "r"), *extra], env={"COLUMNS": "250"}
        )
        assert res.exit_code == 2 and message in res.output, res.output

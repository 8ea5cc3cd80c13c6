"""Artifacts and the scheduled auto-label deployment, against a real local Prefect server."""

from __future__ import annotations

import json
import os
import subprocess
import time

from prefect import flow
from prefect.artifacts import Artifact

from flows.publish import publish
from flows.report import read_report_table
from storage.run import RunStore
from tests.flows.conftest import REPO, cli
from tests.tasks.oracle_stitch import ORACLE, score_runs


def test_publish_writes_dashboard_and_artifacts_with_stable_keys(prefect_api_url, synth_log, tmp_path):
    @flow(name="publish-test", persist_result=False)
    def publish_flow(root: str) -> dict:
        return publish(root, "Synth KITTI", pipeline=ORACLE)

    (uri,) = score_runs(tmp_path, synth_log, {"run": 0.05}, sequences=("00",), block_size=6, bev=1)
    first = publish_flow(uri)
    again = publish_flow(uri)  # a second run: the keys stay, the UI shows the latest
    assert first["scored"] and again["dashboard"] == first["dashboard"] == f"{uri}/dashboard.html"
    assert os.path.getsize(first["dashboard"]) > 10_000
    run = read_report_table(RunStore(uri), "score_run").to_pylist()[0]
    md = Artifact.get("score-summary-synth-kitti")
    assert md.type == "markdown" and f"**PQ {100 * run['pq']:.1f}**" in md.data
    assert f"Dashboard: `{uri}/dashboard.html`" in md.data and "`official`" in md.data
    table = Artifact.get("score-classes-synth-kitti")
    rows = json.loads(table.data) if isinstance(table.data, str) else table.data
    classes = read_report_table(RunStore(uri), "score_classes").to_pylist()
    assert [r["class"] for r in rows] == [c["class"] for c in classes]
    assert rows[0]["PQ"] == round(100 * classes[0]["pq"], 1) and rows[0]["tp"] == classes[0]["tp"]
    assert rows[-1] == {
        "class": classes[-1]["class"],
        "kind": "stuff",
        **{
            k.upper() if k != "iou" else "IoU": round(100 * classes[-1][k], 1)
            for k in ("pq", "sq", "rq", "iou")
        },
        **{k: classes[-1][k] for k in ("tp", "fp", "fn", "gt_points")},  # gt_points: metric ``present``
    }


def _wait_deployment(name: str, proc: subprocess.Popen, timeout: float = 120):
    from prefect.client.orchestration import get_client

    deadline = time.monotonic() + timeout
    with get_client(sync_client=True) as client:
        while True:
            try:
                return client.read_deployment_by_name(name)
            except Exception:
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise
                time.sleep(1)


def test_served_deployment_labels_new_sequences_when_triggered(prefect_api_url, cli_env, synth_log, tmp_path):
    from prefect.deployments import run_deployment

    runs = tmp_path / "runs"
    env = {**cli_env, "PREFECT_RUNNER_POLL_FREQUENCY": "1"}
    args = ("serve", "--watch", str(synth_log), "--runs", str(runs), "--cron", "0 3 * * *", "--name", "synth")
    # no --checkpoint: the bundled model for k = 2 labels, the score stage scores, the dashboard refreshes
    proc = subprocess.Popen(cli(*args), cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        dep = _wait_deployment("auto-label/auto-label-synth", proc)
        assert dep.schedules[0].schedule.cron == "0 3 * * *"
        first = run_deployment("auto-label/auto-label-synth", timeout=300)
        assert first.state.is_completed(), first.state
        store = RunStore(runs)
        for seq in ("00", "01"):
            for stage in ("ingest", "align", "infer", "shift", "fuse", "stitch", "score"):
                assert store.read_manifest(seq, stage).status == "done"
            assert store.read_manifest(seq, "infer").plan["checkpoint"].endswith("tiny-v2-4d")
        tick = Artifact.get("auto-label-synth")
        assert "Labelled 2 sequence(s): 00, 01" in tick.data
        assert f"Dashboard: `{runs}/dashboard.html`" in tick.data and (runs / "dashboard.html").is_file()
        progress = Artifact.get("label-progress")
        assert progress.type == "progress" and float(progress.data) == 100.0
        second = run_deployment("auto-label/auto-label-synth", timeout=300)
        assert second.state.is_completed()
        assert "Labelled 0 sequence(s): none (everything up to date)" in Artifact.get("auto-label-synth").data
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_serve_without_a_server_says_how_to_start_one(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}
    env["PYTHONPATH"] = str(REPO)
    res = subprocess.run(
        cli("serve", "--watch", str(tmp_path), "--runs", str(tmp_path / "r"), "--cron", "* * * * *"),
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
    )
    assert res.returncode == 2 and "prefect server start --host 127.0.0.1" in res.stderr


def test_report_and_dashboard_on_an_s3_store(s3_endpoint, synth_log):
    import fsspec

    root = "s3://dsnet-test/dash"
    (uri,) = score_runs(root, synth_log, {"run": 0.05}, sequences=("00",), block_size=6, bev=1)
    out = publish(uri, "s3 synth", artifacts=False, pipeline=ORACLE)
    assert out["scored"] and out["dashboard"] == f"{uri}/dashboard.html"
    with fsspec.open(out["dashboard"], "rb") as f:
        page = f.read().decode()
    run = read_report_table(RunStore(uri), "score_run").to_pylist()[0]
    assert f'data-k="run:0:pq" data-v="{run["pq"]!r}"' in page

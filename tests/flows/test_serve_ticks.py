"""A scheduled tick labels every healthy sequence: a scan still being written (truncated) leaves its
sequence out of that tick, reported with its reason, and the next tick labels it; a watched folder
that disappears ends the tick failed with one line (was: the whole tick failed on one partial scan,
and a vanished folder gave a 28-line traceback in ``dsnet serve``)."""

from __future__ import annotations

import shutil
import subprocess
import time

import pytest
from prefect.artifacts import Artifact

from flows.request import LabelRequest
from flows.watch import auto_label
from storage.run import RunStore
from tests.flows.conftest import REPO, cli
from tests.logs import make_log


@pytest.fixture
def watched(tmp_path):
    return make_log(tmp_path / "watched", ("00", "01"), n_frames=3, n_ground=300)


def _request(watched, runs) -> dict:
    request = LabelRequest(data=str(watched), root=str(runs), stages={"align": {"scans": 1}}, until="align")
    return request.model_dump(mode="json")  # what the deployment stores


def test_a_partial_scan_leaves_its_sequence_out_of_one_tick_only(prefect_api_url, watched, tmp_path):
    scan = watched / "sequences" / "01" / "velodyne" / "000001.bin"
    whole = scan.read_bytes()
    scan.write_bytes(whole[: len(whole) // 2 + 5])  # still being written
    params = _request(watched, tmp_path / "runs")
    state = auto_label(params, dataset="w", return_state=True)
    assert state.is_completed()
    first = state.result()
    assert first["labelled"] == ["00"] and first["failed"] == ["01"]
    why = first["reasons"]["01"]
    assert why.startswith("ingest: ") and str(scan) in why and "\n" not in why
    assert state.message == f"labelled 1 sequence(s); not labelled, tried again next tick: 01: {why}"
    store = RunStore(tmp_path / "runs")
    assert store.read_manifest("00", "align").status == "done"
    assert store.read_manifest("01", "ingest").status != "done"  # nothing quarantined, nothing done
    tick = Artifact.get("auto-label-w").data
    assert "Labelled 1 sequence(s): 00" in tick and f"- `01`: {why}" in tick
    scan.write_bytes(whole)  # the writer finished
    second = auto_label(params, dataset="w")
    assert second["labelled"] == ["01"] and second["failed"] == [] and second["reasons"] == {}
    frames = store.read_table("01", store_table(store))
    assert frames.num_rows == 3 and set(frames.column("status").to_pylist()) == {"ok"}
    assert auto_label(params, dataset="w")["labelled"] == []  # nothing new or stale


def store_table(store):
    from tasks.methods import get_pipeline

    return get_pipeline()["ingest"].table("frames")


def test_a_watched_folder_that_disappears_fails_the_tick_with_one_line(prefect_api_url, watched, tmp_path):
    params = _request(watched, tmp_path / "runs")
    shutil.rmtree(watched)
    state = auto_label(params, dataset="gone", return_state=True)
    assert state.is_failed()
    assert state.message.startswith("the watched log does not open: ") and str(watched) in state.message
    assert "\n" not in state.message


def test_serve_prints_one_line_per_tick_that_left_something_out(prefect_api_url, cli_env, watched, tmp_path):
    """The served deployment, its runs triggered: the partial scan's tick and the vanished folder's
    tick each give serve one warning line (ScheduleWatch), and no traceback."""
    from prefect.deployments import run_deployment

    from tests.flows.test_serve import _wait_deployment

    scan = watched / "sequences" / "01" / "velodyne" / "000002.bin"
    scan.write_bytes(scan.read_bytes()[:-3])
    env = {**cli_env, "PREFECT_RUNNER_POLL_FREQUENCY": "1"}
    args = ("serve", "--watch", str(watched), "--runs", str(tmp_path / "runs"), "--cron", "0 3 * * *")
    args += ("--name", "ticks", "--scans", "1", "--until", "align", "--check-every", "1")
    log = tmp_path / "serve.log"
    with open(log, "wb") as out:
        proc = subprocess.Popen(cli(*args), cwd=REPO, env=env, stdout=out, stderr=subprocess.STDOUT)
    try:
        _wait_deployment("auto-label/auto-label-ticks", proc)
        assert run_deployment("auto-label/auto-label-ticks", timeout=300).state.is_completed()
        shutil.rmtree(watched)
        assert run_deployment("auto-label/auto-label-ticks", timeout=300).state.is_failed()
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and log.read_text().count("warning: scheduled run") < 2:
            time.sleep(0.5)
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    text = log.read_text()
    assert "Traceback" not in text, text[-4000:]
    warnings = [line for line in text.splitlines() if line.startswith("warning: scheduled run")]
    assert len(warnings) == 2, text[-4000:]
    assert "not labelled, tried again next tick: 01: ingest: " in warnings[0] and str(scan) in warnings[0]
    assert "ended failed: the watched log does not open: " in warnings[1]

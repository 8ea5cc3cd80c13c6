"""The product's first promise, end to end: a real ``prefect server start`` (its scheduler service
included, unlike the temporary test server), ``dsnet serve`` with a one-minute cron, and nothing
else — the watched log must be labelled by the schedule alone.

This caught SQLAlchemy 2.1 (unpinned at the time), with which Prefect 3.8's scheduler fails every
minute ("Can't evaluate bulk DML statement") and no flow run is ever created.
"""

from __future__ import annotations

import os
import subprocess
import time

import pytest

from storage.run import RunStore
from tests.flows.conftest import REPO, cli
from tests.helpers.services import start_prefect_server, stop

pytestmark = pytest.mark.slow


def test_a_watched_log_is_labelled_by_the_schedule_alone(tmp_path):
    from dsnet_core.synth import generate_log

    log = tmp_path / "log"
    generate_log(log, sequences=1, frames=3, seed=0, sensor="vlp32")
    runs = tmp_path / "runs"
    server, url = start_prefect_server(tmp_path / "prefect-home", tmp_path / "server.log")
    env = {
        **os.environ,
        "PYTHONPATH": str(REPO),
        "PREFECT_API_URL": url,
        "PREFECT_HOME": str(tmp_path / "ph"),
    }
    args = ("serve", "--watch", str(log), "--runs", str(runs), "--cron", "* * * * *", "--scans", "1")
    serve_out = tmp_path / "serve.log"
    with open(serve_out, "wb") as out:
        proc = subprocess.Popen(cli(*args), cwd=REPO, env=env, stdout=out, stderr=subprocess.STDOUT)
    try:
        # the scheduler creates runs ahead of time; the next minute's run starts within ~60 s, and the
        # label stages of 3 small frames take well under a minute: 5 minutes is a generous bound
        deadline = time.monotonic() + 300
        store = RunStore(runs)
        done = False
        while time.monotonic() < deadline and not done:
            assert proc.poll() is None, serve_out.read_text()
            m = store.read_manifest("00", "score") if runs.exists() else None
            done = m is not None and m.status == "done"
            time.sleep(2)
        server_log = (tmp_path / "server.log").read_text()
        assert done, (
            f"no scheduled run labelled the log within 5 min\n--- serve:\n{serve_out.read_text()[-3000:]}"
            f"\n--- server:\n{server_log[-3000:]}"
        )
        assert "InvalidRequestError" not in server_log, server_log[-3000:]
        for stage in ("ingest", "align", "infer", "shift", "fuse", "track", "score"):
            assert store.read_manifest("00", stage).status == "done", stage
    finally:
        stop(proc)
        stop(server)

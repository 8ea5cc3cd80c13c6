"""The product's first promise, end to end: a real ``prefect server start`` (its scheduler service
included, unlike the temporary test server), ``dsnet serve`` with a one-minute cron, and nothing
else — the watched log must be labelled by the schedule alone.

This caught SQLAlchemy 2.1 (unpinned at the time), with which Prefect 3.8's scheduler fails every
minute ("Can't evaluate bulk DML statement") and no flow run is ever created.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from storage.run import RunStore
from tests.flows.conftest import REPO, cli

pytestmark = pytest.mark.slow


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def start_prefect_server(home: Path, log: Path) -> tuple[subprocess.Popen, str]:
    """``prefect server start`` on a free loopback port with its own PREFECT_HOME (SQLite there);
    returns the process and its API URL once ``/api/health`` answers."""
    port = _free_port()
    env = {
        **{k: v for k, v in os.environ.items() if not k.startswith("PREFECT_")},
        "PREFECT_HOME": str(home),
        "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
        "PREFECT_UI_ENABLED": "false",
    }
    prefect = Path(sys.executable).with_name("prefect")
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            [str(prefect), "server", "start", "--host", "127.0.0.1", "--port", str(port), "--no-ui"],
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    url = f"http://127.0.0.1:{port}/api"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"prefect server exited: {log.read_text()[-2000:]}")
        try:
            with urllib.request.urlopen(f"{url}/health", timeout=2) as res:
                if res.status == 200:
                    return proc, url
        except OSError:
            time.sleep(0.5)
    _stop(proc)
    raise RuntimeError(f"prefect server did not answer within 120 s: {log.read_text()[-2000:]}")


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
        _stop(proc)
        _stop(server)

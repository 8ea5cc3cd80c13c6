"""The Prefect API and a Dask scheduler that are not there (a closed loopback port) or are something
else (a plain HTTP server): one line naming the address, in seconds, before any server or flow
starts (was: 90-140-line tracebacks, ``serve`` after printing "serving …"; a dead scheduler retried
for 30 s, then a 117-line traceback at 47.5 s)."""

from __future__ import annotations

import http.server
import os
import socket
import subprocess
import sys
import threading
import time

import pytest

from dsnet_core.errors import ServiceError
from flows.services import check_dask_scheduler, check_prefect_api
from tests.flows.conftest import REPO, cli


def _closed_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture(scope="module")
def plain_http():
    """A plain ``http.server`` on loopback: answers HTTP, is neither Prefect nor Dask."""
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
    server.RequestHandlerClass.log_message = lambda *a: None
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    from tests.logs import make_log

    return make_log(tmp_path_factory.mktemp("log"), ("00",), n_frames=2, n_ground=200)


def _dsnet(args: list[str], **env: str) -> tuple[subprocess.CompletedProcess, float]:
    full = {**os.environ, "PYTHONPATH": str(REPO), **env}
    start = time.monotonic()
    res = subprocess.run(cli(*args), env=full, capture_output=True, text=True, timeout=120)
    return res, time.monotonic() - start


def _timed(check, *args):
    start = time.monotonic()
    with pytest.raises(ServiceError) as err:
        check(*args)
    return str(err.value), time.monotonic() - start


def test_a_prefect_api_url_at_a_closed_port(log, tmp_path):
    url = f"http://127.0.0.1:{_closed_port()}/api"
    message, seconds = _timed(check_prefect_api, url)
    assert seconds < 2
    assert message.startswith(f"PREFECT_API_URL {url}: no Prefect API answers (ConnectError: ")
    assert message.endswith("start one (`prefect server start --host 127.0.0.1`) or unset PREFECT_API_URL to "
                            "label with a temporary server")  # fmt: skip
    for args in (
        ["label", str(log), "--run", str(tmp_path / "run"), "--scans", "1"],
        ["serve", "--watch", str(log), "--runs", str(tmp_path / "run"), "--scans", "1"],
    ):
        res, seconds = _dsnet(args, PREFECT_API_URL=url)
        assert res.returncode == 2 and res.stdout == "", res.stdout  # not "serving …"
        assert res.stderr.strip() == f"error: {message}"
        assert seconds < 30  # the interpreter, torch and the model card: was 8-12 s and a traceback
    assert not (tmp_path / "run").exists()


def test_a_prefect_api_url_at_a_server_that_is_not_prefect(plain_http, log, tmp_path):
    url = f"http://{plain_http}/api"
    message, seconds = _timed(check_prefect_api, url)
    assert seconds < 2
    want = f"PREFECT_API_URL {url}: not a Prefect API: GET /health answered 404 File not found, not true"
    assert message == want
    res, _ = _dsnet(["serve", "--watch", str(log), "--runs", str(tmp_path / "run")], PREFECT_API_URL=url)
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr.strip() == f"error: {want}"
    message, _ = _timed(check_prefect_api, f"http://{plain_http}")  # the /api left out
    assert message.endswith("not true (a Prefect server's API URL ends in /api)")


def test_a_real_prefect_api_passes(prefect_api_url):
    check_prefect_api(prefect_api_url)


def test_a_dead_dask_scheduler_fails_within_seconds(log, tmp_path, prefect_api_url):
    address = f"tcp://127.0.0.1:{_closed_port()}"
    message, seconds = _timed(check_dask_scheduler, address)
    assert seconds < 2
    assert message == (
        f"--dask-address {address}: no Dask scheduler answers (Connection refused); start one (`dask "
        "scheduler`, then `dask worker ADDRESS`) or label without --dask-address"
    )
    args = ["label", str(log), "--run", str(tmp_path / "run"), "--scans", "1", "--dask-address", address]
    for env in ({}, {"PREFECT_API_URL": prefect_api_url}):  # a temporary server, or the session's
        res, seconds = _dsnet(args, **env)
        assert res.returncode == 2 and res.stderr.strip() == f"error: {message}", res.stderr[-3000:]
        assert seconds < 20  # was 47.5 s and 117 lines
    assert not (tmp_path / "run").exists()


def test_a_dask_address_that_is_not_a_scheduler(plain_http):
    message, seconds = _timed(check_dask_scheduler, f"tcp://{plain_http}")
    assert seconds < 8  # the handshake's timeout (5 s)
    assert message == (
        f"--dask-address tcp://{plain_http}: something listens there but does not answer as a Dask "
        "scheduler (TimeoutError); check the address and port"
    )
    message, _ = _timed(check_dask_scheduler, "bogus://x")
    assert message.startswith("--dask-address bogus://x: not a Dask address (")


def test_a_live_dask_scheduler_passes(tmp_path):
    port = _closed_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", str(port),
         "--no-dashboard"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                check_dask_scheduler(f"tcp://127.0.0.1:{port}")
                break
            except ServiceError:
                assert proc.poll() is None and time.monotonic() < deadline, "the scheduler did not start"
                time.sleep(0.5)
    finally:
        proc.terminate()
        proc.wait(timeout=30)

"""S3 run stores that cannot be used: an endpoint that does not answer (a closed loopback port),
no credentials, a key the endpoint refuses, a bucket that does not exist. Each is one line naming
the URL and what to check, within a few seconds (was: EndpointConnectionError after 14 s, 28 s
through ``label``; NoCredentialsError and ``PermissionError: Forbidden`` tracebacks)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
import uuid

import pytest

from storage.errors import StoreAccessError
from storage.fs import RootFS
from tests.flows.conftest import REPO, cli

NO_CREDENTIALS = {  # nothing for botocore's chain to find, and no instance-metadata request
    "AWS_EC2_METADATA_DISABLED": "true",
    "AWS_SHARED_CREDENTIALS_FILE": "/nonexistent/credentials",
    "AWS_CONFIG_FILE": "/nonexistent/config",
}


def _closed_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]  # closed when the socket is: nothing listens there


def _env(**changes: str | None) -> dict[str, str]:
    env = {**os.environ, "PYTHONPATH": str(REPO), "AWS_DEFAULT_REGION": "us-east-1"}
    for key, value in changes.items():
        if value is None:
            env.pop(key, None)
        else:
            env[key] = value
    return env


def _dsnet(args: list[str], env: dict[str, str]) -> tuple[subprocess.CompletedProcess, float]:
    start = time.monotonic()
    res = subprocess.run(cli(*args), env=env, capture_output=True, text=True, timeout=120)
    return res, time.monotonic() - start


@pytest.fixture(scope="module")
def strict_s3():
    """A loopback moto server that checks keys (no request without a known key): any key is wrong."""
    port = _closed_port()
    env = {**os.environ, "INITIAL_NO_AUTH_ACTION_COUNT": "0"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert proc.poll() is None and time.monotonic() < deadline, "moto server did not start"
                time.sleep(0.2)
        yield f"http://127.0.0.1:{port}"
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def test_an_endpoint_that_does_not_answer_is_one_line_within_seconds(tmp_path):
    endpoint = f"http://127.0.0.1:{_closed_port()}"
    options = {"endpoint_url": endpoint, "key": "k", "secret": "s"}
    start = time.monotonic()
    with pytest.raises(StoreAccessError) as err:
        RootFS("s3://dsnet-test/run", options).read_bytes("run.json")
    assert time.monotonic() - start < 5
    assert str(err.value) == (
        f"s3://dsnet-test/run: cannot reach the S3 endpoint {endpoint} (EndpointConnectionError); check "
        "AWS_ENDPOINT_URL (or the endpoint_url storage option) and that the service is up"
    )
    env = _env(AWS_ENDPOINT_URL=endpoint, AWS_ACCESS_KEY_ID="k", AWS_SECRET_ACCESS_KEY="s")
    from tests.logs import make_log

    log = make_log(tmp_path / "log", ("00",), n_frames=2, n_ground=200)
    for args in (["status", "s3://dsnet-test/run"], ["label", str(log), "--run", "s3://dsnet-test/run"]):
        res, seconds = _dsnet(args, env)
        assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr[-3000:]
        assert res.stderr.strip() == f"error: {err.value}"
        assert seconds < 20  # mostly the interpreter's start; was 14 s (status) and 28 s (label)


def test_no_credentials_are_one_line(s3_endpoint, tmp_path):
    env = _env(AWS_ACCESS_KEY_ID=None, AWS_SECRET_ACCESS_KEY=None, AWS_PROFILE=None, **NO_CREDENTIALS)
    res, seconds = _dsnet(["status", "s3://dsnet-test/run"], env)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr[-3000:]
    assert res.stderr.strip() == (
        "error: s3://dsnet-test/run: no S3 credentials (Unable to locate credentials): set "
        "AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY (or AWS_PROFILE, or the key and secret storage options)"
    )
    assert seconds < 20


def test_a_refused_key_is_one_line(strict_s3, tmp_path):
    start = time.monotonic()
    with pytest.raises(StoreAccessError) as err:
        RootFS("s3://any/run", {"endpoint_url": strict_s3, "key": "wrong", "secret": "s"}).exists("run.json")
    assert time.monotonic() - start < 5
    assert str(err.value).startswith(f"s3://any/run: the S3 endpoint {strict_s3} refused access (")
    assert str(err.value).endswith(
        "check AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY and the bucket's permissions"
    )
    from tests.logs import make_log

    log = make_log(tmp_path / "log", ("00",), n_frames=2, n_ground=200)
    env = _env(AWS_ENDPOINT_URL=strict_s3, AWS_ACCESS_KEY_ID="wrong", AWS_SECRET_ACCESS_KEY="s")
    res, _ = _dsnet(["label", str(log), "--run", "s3://any/run", "--scans", "1"], env)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr[-3000:]
    assert (
        res.stderr.strip()
        .splitlines()[-1]
        .startswith(f"error: s3://any/run: the S3 endpoint {strict_s3} refused access")
    )
    assert "Flow run" not in res.stderr + res.stdout  # refused before any server or flow started


def test_a_missing_bucket_is_named_and_a_good_store_is_asked_once(s3_endpoint):
    bucket = f"missing-{uuid.uuid4().hex[:8]}"
    with pytest.raises(StoreAccessError, match=f"bucket '{bucket}' does not exist at http://127.0.0.1:"):
        RootFS(f"s3://{bucket}/run").listdir("")
    from storage import remote

    root = RootFS("s3://dsnet-test/asked-once")
    root.write_bytes("a.json", b"{}")
    assert root.read_bytes("a.json") == b"{}"
    asked = len(remote._ANSWERED)
    RootFS("s3://dsnet-test/asked-once/other").exists("x")  # same bucket, options, environment
    assert len(remote._ANSWERED) == asked


def test_a_busy_endpoint_is_asked_again_not_refused(s3_endpoint):
    """503 SlowDown is an answer that comes back: the check asks again (a refused key does not)."""
    from tests.helpers.flaky_s3 import FlakyS3Proxy

    with FlakyS3Proxy(s3_endpoint["AWS_ENDPOINT_URL"], rate=1.0, max_faults=5, seed=0) as proxy:
        RootFS(f"s3://dsnet-test/busy-{uuid.uuid4().hex[:8]}", {"endpoint_url": proxy.url}).check()
    assert proxy.faults == 1  # the first listing answered 503, the second (never two in a row) passed

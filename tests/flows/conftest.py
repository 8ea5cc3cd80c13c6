"""One Prefect server for the whole test session, always shut down (and dying with pytest if killed)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def prefect_api_url():
    from flows.server import prefect_api

    with prefect_api(startup_timeout=120) as url:
        yield url


@pytest.fixture
def cli_env(prefect_api_url):
    """Environment for ``python -m flows.cli`` subprocesses: this checkout, the session's server."""
    env = dict(os.environ)
    env.update(PYTHONPATH=str(REPO), PREFECT_API_URL=prefect_api_url)
    return env


def cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "flows.cli", *args]


@pytest.fixture(scope="session")
def s3_endpoint():
    """A loopback S3 (moto's threaded server); AWS_* variables point s3fs and subprocesses at it."""
    import logging

    import s3fs
    from moto.server import ThreadedMotoServer

    logging.getLogger("werkzeug").setLevel(logging.WARNING)
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    _, port = server.get_host_and_port()
    env = {
        "AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}",
        "AWS_ACCESS_KEY_ID": "test",
        "AWS_SECRET_ACCESS_KEY": "test",
        "AWS_DEFAULT_REGION": "us-east-1",
    }
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    s3fs.S3FileSystem(skip_instance_cache=True).mkdir("dsnet-test")
    try:
        yield env
    finally:
        server.stop()
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@pytest.fixture(scope="session")
def dask_cluster(prefect_api_url, s3_endpoint, tmp_path_factory):
    """``dask scheduler`` and two ``dask worker`` processes on loopback (no nanny: a killed worker
    stays dead), with this checkout, the session's Prefect server and the loopback S3 server."""
    from tests.helpers.cluster import start_cluster

    env = {**os.environ, **s3_endpoint, "PYTHONPATH": str(REPO), "PREFECT_API_URL": prefect_api_url}
    cluster = start_cluster(tmp_path_factory.mktemp("dask"), env, n_workers=2)
    try:
        yield cluster
    finally:
        cluster.stop()

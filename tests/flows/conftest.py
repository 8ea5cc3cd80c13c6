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

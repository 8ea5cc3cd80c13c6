"""Two temporary Prefect servers one after the other in one process (bench scripts, notebooks)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SCRIPT = """
from prefect import flow
from flows.server import prefect_api

@flow
def add_one(x):
    return x + 1

for i in range(2):
    with prefect_api():
        print("result", add_one(i), flush=True)
"""


@pytest.mark.slow
def test_second_temporary_server_gets_a_fresh_events_worker():
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}
    env["PYTHONPATH"] = str(REPO)
    res = subprocess.run(
        [sys.executable, "-c", SCRIPT], cwd=REPO, env=env, capture_output=True, text=True, timeout=300
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["result", "1", "result", "2"]
    # the events worker of the first server must not keep retrying it after it stopped
    assert "Unable to connect" not in res.stderr + res.stdout

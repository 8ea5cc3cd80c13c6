"""A real distributed run: ``dask scheduler`` + two ``dask worker`` processes on loopback, the
session's Prefect server and the loopback S3 server as the store; ``dsnet label --dask-address``
through every stage of a two-sequence log at k = 2, then again with a worker SIGKILLed in the
middle of the model stages. Both export labels byte-identical to a single-process run."""

from __future__ import annotations

import subprocess
import uuid

import pytest

from tests.flows.conftest import REPO, cli
from tests.helpers.kill import stage_started
from tests.model_helpers import make_checkpoint

FAST_SHIFT = '{"kind": "dynamic_shift", "n_seeds": 300, "bandwidths": [0.2, 1.8, 3.4]}'
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    return make_checkpoint(tmp_path_factory.mktemp("ckpt") / "tiny", seed=0)


def _label(env, log, run, ckpt, *extra):
    return [
        *cli("label", str(log), "--run", run, "--scans", "2", "--checkpoint", str(ckpt)),
        *("--clusterer", FAST_SHIFT, "--block-size", "1", *extra),
    ]


def _export(env, run, out) -> dict[str, bytes]:
    res = subprocess.run(
        cli("export", run, "--out", str(out)), cwd=REPO, env=env, capture_output=True, text=True, timeout=300
    )
    assert res.returncode == 0, res.stderr[-3000:]
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*.label"))}


@pytest.fixture(scope="module")
def single_process(synth_log, ckpt, tmp_path_factory, prefect_api_url):
    """Exported labels of a plain (threads, local folder) run: the reference."""
    import os

    env = {**os.environ, "PYTHONPATH": str(REPO), "PREFECT_API_URL": prefect_api_url}
    tmp = tmp_path_factory.mktemp("single")
    run = str(tmp / "run")
    res = subprocess.run(_label(env, synth_log, run, ckpt), cwd=REPO, env=env, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    labels = _export(env, run, tmp / "out")
    assert len(labels) == 12  # 2 sequences × 6 frames
    return labels


def test_every_stage_on_a_two_worker_cluster_over_s3(dask_cluster, synth_log, ckpt, single_process, tmp_path):
    env = dask_cluster.env
    run = f"s3://dsnet-test/dask-{uuid.uuid4().hex[:8]}"
    res = subprocess.run(
        _label(env, synth_log, run, ckpt, "--dask-address", dask_cluster.address),
        cwd=REPO, env=env, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert _export(env, run, tmp_path / "out") == single_process


def test_a_worker_killed_in_the_model_stages_costs_time_not_labels(
    dask_cluster, synth_log, ckpt, single_process, tmp_path
):
    import time

    env = dask_cluster.env
    run = f"s3://dsnet-test/dask-kill-{uuid.uuid4().hex[:8]}"
    proc = subprocess.Popen(
        _label(env, synth_log, run, ckpt, "--dask-address", dask_cluster.address),
        cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        started = stage_started(run, "00", "shift", blocks=1)
        deadline = time.monotonic() + 600
        while not started() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert proc.poll() is None, "the run ended before the model stages: nothing to kill in"
        victim = None
        while victim is None and proc.poll() is None and time.monotonic() < deadline:
            victim = dask_cluster.busy_worker()  # one that holds a block in flight: its work is lost
        assert victim is not None, "no worker was running a block"
        dask_cluster.kill_worker(victim)
        out, _ = proc.communicate(timeout=900)
    finally:
        if proc.poll() is None:
            proc.kill()
        dask_cluster.replace_dead_workers()
    assert proc.returncode == 0, out[-4000:]
    assert _export(env, run, tmp_path / "out") == single_process

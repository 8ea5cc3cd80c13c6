"""A store that cannot be written (disk full, read-only, injected errors): one typed line naming
what could not be written, no retry storm, and the same command resumes once the store is writable
again, to the labels of an undisturbed run."""

from __future__ import annotations

import errno
import os
import subprocess
import uuid

import numpy as np
import pytest
from typer.testing import CliRunner

from flows.cli import app
from tests.flows.conftest import REPO, cli
from tests.helpers.tiny_log import write_tiny_log
from tests.model_helpers import make_checkpoint

FAST = '{"kind": "bfs", "radius": 0.5, "min_size": 5}'


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    return write_tiny_log(tmp_path_factory.mktemp("log"), frames=3)


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    return make_checkpoint(tmp_path_factory.mktemp("ckpt") / "ckpt", seed=3)


def _args(log, run, ckpt):
    return [
        "label",
        str(log),
        "--run",
        str(run),
        "--scans",
        "1",
        "--checkpoint",
        str(ckpt),
        "--clusterer",
        FAST,
    ]


def _labels(run, out) -> list[bytes]:
    res = CliRunner().invoke(app, ["export", str(run), "--out", str(out)])
    assert res.exit_code == 0, res.output
    return [p.read_bytes() for p in sorted(out.rglob("*.label"))]


@pytest.fixture(scope="module")
def reference(prefect_api_url, log, ckpt, tmp_path_factory):
    root = tmp_path_factory.mktemp("ref")
    res = CliRunner().invoke(app, _args(log, root / "run", ckpt))
    assert res.exit_code == 0, res.output
    return _labels(root / "run", root / "out")


def test_an_injected_full_disk_in_the_model_stages_is_one_line_then_resumes(
    prefect_api_url, log, ckpt, reference, tmp_path, monkeypatch
):
    import zarr.storage._local as local

    from storage.fs import RootFS

    real_put, real_write, calls = local._put, RootFS.write_bytes, []

    def full_disk_in_infer(path, value, exclusive=False):
        if "/infer/arrays.zarr/" in str(path) and "/c/" in str(path):
            calls.append(path)
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_put(path, value, exclusive)

    def full_disk_in_infer_chunks(root, rel, data):  # item chunks are written without zarr
        if "/infer/arrays.zarr/" in rel and "/c/" in rel:
            calls.append(rel)
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_write(root, rel, data)

    monkeypatch.setattr(local, "_put", full_disk_in_infer)
    monkeypatch.setattr(RootFS, "write_bytes", full_disk_in_infer_chunks)
    run = tmp_path / "run"
    res = CliRunner().invoke(app, _args(log, run, ckpt))
    assert res.exit_code == 2, res.output
    line = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert line == [
        f"error: {run}/sequences/00/infer: cannot write: no space left on device (errno 28); free space or "
        "fix the permissions (or label into another --run), then run the same command again to resume"
    ]
    assert len(calls) == 1  # not retried: a full disk is no transient hiccup
    monkeypatch.setattr(local, "_put", real_put)  # space freed
    monkeypatch.setattr(RootFS, "write_bytes", real_write)
    res = CliRunner().invoke(app, _args(log, run, ckpt))
    assert res.exit_code == 0, res.output
    assert _labels(run, tmp_path / "out") == reference


@pytest.fixture
def small_tmpfs(tmp_path):
    """A real 400 KB tmpfs (root and a mount namespace that allows it; the injected test above
    covers machines where it does not)."""
    mnt = tmp_path / f"fs-{uuid.uuid4().hex[:6]}"
    mnt.mkdir()
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=400k", "tmpfs", str(mnt)], capture_output=True)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {res.stderr.decode().strip()}")
    yield mnt
    subprocess.run(["umount", "-l", str(mnt)], check=False)


@pytest.mark.slow
def test_a_real_full_then_read_only_store_resumes_to_the_same_labels(
    cli_env, log, ckpt, reference, small_tmpfs, tmp_path
):
    run = small_tmpfs / "run"
    res = subprocess.run(
        cli(*_args(log, run, ckpt)), cwd=REPO, env=cli_env, capture_output=True, text=True, timeout=300
    )
    assert res.returncode == 2, res.stderr[-2000:]
    assert "cannot write: no space left on device (errno 28)" in res.stderr
    assert "Traceback" not in res.stderr + res.stdout
    subprocess.run(["mount", "-o", "remount,ro", str(small_tmpfs)], check=True)
    res = subprocess.run(
        cli(*_args(log, run, ckpt)), cwd=REPO, env=cli_env, capture_output=True, text=True, timeout=300
    )
    assert res.returncode == 2 and "read-only file system (errno 30)" in res.stderr, res.stderr[-2000:]
    subprocess.run(["mount", "-o", "remount,rw,size=64m", str(small_tmpfs)], check=True)
    res = subprocess.run(
        cli(*_args(log, run, ckpt)), cwd=REPO, env=cli_env, capture_output=True, text=True, timeout=300
    )
    assert res.returncode == 0, res.stderr[-2000:]
    assert _labels(run, tmp_path / "out") == reference
    assert np.all([len(b) > 0 for b in reference])


@pytest.mark.slow
def test_transient_s3_errors_are_retried_to_the_same_labels(
    cli_env, s3_endpoint, log, ckpt, reference, tmp_path
):
    from tests.helpers.flaky_s3 import FlakyS3Proxy

    run = f"s3://dsnet-test/flaky-{uuid.uuid4().hex[:8]}"
    with FlakyS3Proxy(s3_endpoint["AWS_ENDPOINT_URL"], rate=0.15, max_faults=40, seed=1) as proxy:
        env = {**cli_env, **s3_endpoint, "AWS_ENDPOINT_URL": proxy.url}
        res = subprocess.run(
            cli(*_args(log, run, ckpt)), cwd=REPO, env=env, capture_output=True, text=True, timeout=600
        )
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    assert proxy.faults >= 10, (proxy.faults, proxy.requests)  # 503 SlowDown answers were met and retried
    assert "Traceback" not in res.stderr
    assert _labels(run, tmp_path / "out") == reference


def test_two_runs_with_different_configs_on_one_store_end_consistent(cli_env, log, ckpt, reference, tmp_path):
    """Two ``dsnet label`` processes on one run folder, k = 1 and k = 2: the locks serialise them,
    and the store ends holding exactly the labels of the run that recorded itself last."""
    k2 = tmp_path / "k2"
    res = CliRunner().invoke(app, [*_args(log, k2 / "run", ckpt), "--scans", "2"])
    assert res.exit_code == 0, res.output
    want = {1: reference, 2: _labels(k2 / "run", k2 / "out")}
    assert want[1] != want[2]
    run = tmp_path / "run"
    procs = [
        subprocess.Popen(
            cli(*_args(log, run, ckpt), "--scans", str(k), "--lock-wait", "300"),
            cwd=REPO,
            env=cli_env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for k in (1, 2)
    ]
    outs = [p.communicate(timeout=600)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    from storage.run import RunStore

    last = RunStore(run).read_run_config()["stages"]["align"]["scans"]
    assert _labels(run, tmp_path / "out") == want[last]

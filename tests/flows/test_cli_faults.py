"""Real `dsnet label` processes: SIGKILL in the middle of align, concurrent runs, S3, orphan servers."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
import uuid

import numpy as np
import pytest

from storage.run import RunStore
from tasks.methods import get_pipeline
from tests.flows.conftest import REPO, cli
from tests.helpers.plain_runner import run_stage_plain, stage_state
from tests.logs import make_log

P = get_pipeline()  # the DS-Net stages

ARGS = ("--scans", "3", "--stride", "1", "--block-size", "1", "--until", "align")  # the store stages only
N_FRAMES = 24
N_VOLUMES = N_FRAMES - 2


@pytest.fixture(scope="module")
def big_log(tmp_path_factory):
    """24 frames of ~12k points: align (22 blocks) takes long enough to be killed in the middle."""
    return make_log(tmp_path_factory.mktemp("biglog"), ("00",), n_frames=N_FRAMES, n_ground=12000)


@pytest.fixture(scope="module")
def reference(big_log, tmp_path_factory):
    """An uninterrupted run of the same stage functions (plain loop), with the stage configs
    ``dsnet label`` records (ingest's model grid included)."""
    from tasks.methods import stage_configs
    from tests.helpers.label_request import req

    store = RunStore(tmp_path_factory.mktemp("ref") / "run")
    stages = req(big_log, store.uri, stages=stage_configs(scans=3, stride=1)).stage_configs(P)
    run = {"data": str(big_log), "stages": stages, "options": {"block_size": 1}}
    store.write_run_config("ref", run)
    for stage in ("ingest", "align"):
        run_stage_plain(store, P, "00", stage, run, "ref")
    return store


def _wait(cond, timeout: float, what: str, proc=None) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return
        if proc is not None and proc.poll() is not None:
            out = proc.stdout.read() if proc.stdout else ""
            pytest.fail(f"process ended (rc {proc.returncode}) before {what}:\n{out[-3000:]}")
        time.sleep(0.02)
    pytest.fail(f"timed out waiting for {what}")


def _assert_same_as_reference(store: RunStore, reference: RunStore) -> None:
    for stage in ("ingest", "align"):
        assert store.read_manifest("00", stage).status == "done"
        assert store.read_manifest("00", stage).fingerprint != ""
    a, b = store.arrays("00", P["align"].contract), reference.arrays("00", P["align"].contract)
    assert a.n_items == b.n_items == N_VOLUMES and a.done().all()
    assert np.array_equal(a.n_points(), b.n_points())
    for name in ("points", "source_frame", "source_index", "labels"):
        assert np.array_equal(a.group[name][:], b.group[name][:]), name
    for stage, table in (("ingest", "frames"), ("align", "volumes")):
        spec = P[stage].table(table)
        assert store.read_table("00", spec).equals(reference.read_table("00", spec))


def _result_files(store: RunStore) -> list[str]:
    """Every object under the store that a reader could take for a result (not hidden, not partial)."""
    fs, root = store.root.fs, store.root.root
    names = [p[len(root) :] for p in fs.find(root)]
    return [
        n for n in names if not any(part.startswith(".") for part in n.split("/")) and ".partial" not in n
    ]


@pytest.mark.parametrize("backend", ["local", pytest.param("s3", marks=pytest.mark.slow)])
def test_sigkill_in_align_then_resume(backend, big_log, reference, cli_env, tmp_path, request):
    env = dict(cli_env)
    if backend == "s3":
        env.update(request.getfixturevalue("s3_endpoint"))
        root = f"s3://dsnet-test/fault-{uuid.uuid4().hex[:8]}"
    else:
        root = str(tmp_path / "run")
    store = RunStore(root)
    proc = subprocess.Popen(
        cli("label", str(big_log), "--run", root, *ARGS),
        cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:

        def align_half_done() -> bool:
            m = store.read_manifest("00", "align")
            return (
                m is not None
                and m.status == "running"
                and len(store.completed_blocks("00", "align", m.fingerprint)) >= 3
            )

        _wait(align_half_done, 180, "align had finished 3 blocks", proc)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    state, _, n_done = stage_state(store, P, "00", "align")
    assert state == "partial" and 3 <= n_done < N_VOLUMES, (state, n_done)
    assert store.read_manifest("00", "ingest").status == "done"
    visible = _result_files(store)
    assert not any("tables/volumes" in n for n in visible)  # align's table is written only when it is done
    assert all(n.endswith("part-0.parquet") for n in visible if "tables/" in n)
    status = subprocess.run(
        cli("status", root), cwd=REPO, env=env, capture_output=True, text=True, timeout=120
    )
    shown = status.stdout.replace("\n", " ").replace("│", "")
    assert "interrupted" in shown and f"{n_done}/{N_VOLUMES}" in shown  # killed: its lock's owner is dead

    rerun = subprocess.run(
        cli("label", str(big_log), "--run", root, *ARGS),
        cwd=REPO, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert rerun.returncode == 0, rerun.stdout[-3000:] + rerun.stderr[-3000:]
    run = RunStore(root).read_run_config()
    record = RunStore(root).root.read_json(f"runs/{run['run_id']}.json")
    actions = {r["stage"]: (r["action"], r["blocks_run"]) for r in record["summary"]}
    assert actions == {"ingest": ("skip", 0), "align": ("resume", N_VOLUMES - n_done)}
    _assert_same_as_reference(RunStore(root), reference)


@pytest.mark.slow
def test_two_simultaneous_runs(big_log, reference, cli_env, tmp_path):
    root = str(tmp_path / "run")
    cmd = cli("label", str(big_log), "--run", root, *ARGS, "--lock-wait", "300")
    procs = [
        subprocess.Popen(
            cmd, cwd=REPO, env=cli_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        for _ in range(2)
    ]
    outs = [p.communicate(timeout=300)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs[0][-2000:] + outs[1][-2000:]
    store = RunStore(root)
    runs = [store.root.read_json(f"runs/{name}") for name in store.root.listdir("runs")]
    actions = sorted(tuple(r["action"] for r in rec["summary"]) for rec in runs)
    # one run did the work; the other waited for its locks and then found everything done
    assert actions == [("fresh", "fresh"), ("skip", "skip")]
    _assert_same_as_reference(store, reference)


def test_second_run_names_the_holder(big_log, cli_env, tmp_path):
    root = tmp_path / "run"
    holder = subprocess.Popen(["sleep", "60"])  # a live process on this host holds the lock
    try:
        lock = root / "sequences/00/ingest/lock.json"
        lock.parent.mkdir(parents=True)
        rec = {"host": os.uname().nodename, "pid": holder.pid, "run_id": "other-run", "acquired": time.time()}
        lock.write_text(json.dumps({**rec, "heartbeat": time.time()}))
        res = subprocess.run(
            cli("label", str(big_log), "--run", str(root), "--until", "align"),
            cwd=REPO, env=cli_env, capture_output=True, text=True, timeout=300,
        )  # fmt: skip
    finally:
        holder.kill()
        holder.wait()
    assert res.returncode == 2
    msg = " ".join(res.stderr.split())
    assert "sequences/00/ingest/lock.json: locked by another run" in msg
    assert "Traceback" not in res.stderr  # Prefect's traceback of the failed flow stays off the terminal
    assert f"pid {holder.pid}, run other-run" in msg
    assert RunStore(root).read_manifest("00", "ingest") is None  # it wrote nothing
    assert not (root / "run.json").exists()  # not even the run record: it never held the locks


def test_a_sequence_name_that_leaves_the_store_is_refused(big_log, cli_env, tmp_path):
    before = sorted(p.relative_to(big_log) for p in big_log.rglob("*"))
    res = subprocess.run(
        cli("label", str(big_log), "--run", str(tmp_path / "run"), "--until", "ingest",
            "--sequences", f"../../{big_log.name}/sequences/00"),
        cwd=REPO, env=cli_env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 2, res.stderr
    assert "not a plain sequence name" in res.stderr and "Traceback" not in res.stderr
    assert sorted(p.relative_to(big_log) for p in big_log.rglob("*")) == before  # nothing written there
    assert not (tmp_path / "run").exists()


def test_a_run_folder_of_another_log_is_refused(big_log, cli_env, tmp_path):
    other = make_log(tmp_path / "other", ("00",), n_frames=2)
    root = tmp_path / "run"
    first = subprocess.run(
        cli("label", str(other), "--run", str(root), "--until", "ingest"),
        cwd=REPO, env=cli_env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert first.returncode == 0, first.stderr[-3000:]
    res = subprocess.run(
        cli("label", str(big_log), "--run", str(root), "--until", "ingest"),
        cwd=REPO, env=cli_env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 2
    msg = " ".join(res.stderr.split())
    assert f"holds runs of the log {other}" in msg and "its own --run folder" in msg
    assert RunStore(root).read_run_config()["data"] == str(other)


@pytest.mark.parametrize("how", ["ctrl-c", "sigterm"])
def test_ctrl_c_or_sigterm_stops_cleanly_and_the_run_resumes(big_log, reference, tmp_path, how):
    """Ctrl-C at a terminal signals the whole foreground process group: the temporary Prefect
    server (in its own session) must outlive the flow's last state report, and dsnet exits with one
    line, no traceback; SIGTERM to dsnet alone takes the same way out. The rerun resumes to the
    uninterrupted run's volumes."""
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}
    env.update(PYTHONPATH=str(REPO), PREFECT_HOME=str(tmp_path / "prefect-home"))
    root = tmp_path / "run"
    # Ctrl-C's default disposition, as at a terminal: a test run started as a background job of a
    # non-interactive shell (`.ci/run &`) inherits SIGINT ignored, and Python then installs no
    # KeyboardInterrupt handler, so dsnet would run to the end (rc 0)
    proc = subprocess.Popen(
        cli("label", str(big_log), "--run", str(root), *ARGS), cwd=REPO, env=env,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    store = RunStore(root)

    def align_started() -> bool:
        m = store.read_manifest("00", "align") if (root / "run.json").exists() else None
        return m is not None and len(store.completed_blocks("00", "align", m.fingerprint)) >= 1

    try:
        _wait(align_started, 180, "align had started", proc)
        t0 = time.monotonic()
        if how == "ctrl-c":
            os.killpg(proc.pid, signal.SIGINT)  # what the terminal does
        else:
            proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=60)
        took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, out[-3000:]
    assert "error: interrupted" in out and "run the same command again to resume" in out
    assert "Traceback" not in out and "ConnectError" not in out, out[-3000:]
    assert took < 30, took
    res = subprocess.run(
        cli("label", str(big_log), "--run", str(root), *ARGS), cwd=REPO, env=env,
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    got, want = store.arrays("00", P["align"].contract), reference.arrays("00", P["align"].contract)
    for i in range(N_VOLUMES):
        assert np.array_equal(got.read_item(i)["points"], want.read_item(i)["points"])


def _children(pid: int) -> list[tuple[int, str]]:
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                cmd = f.read().replace(b"\0", b" ").decode()
        except (OSError, ValueError, IndexError):
            continue
        if ppid == pid:
            out.append((int(entry), cmd))
    return out


@pytest.mark.slow
def test_killed_cli_leaves_no_prefect_server(tmp_path):
    log = make_log(tmp_path / "log", ("00",), n_frames=3)
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}
    env.update(PYTHONPATH=str(REPO), PREFECT_HOME=str(tmp_path / "prefect-home"))
    proc = subprocess.Popen(
        cli("label", str(log), "--run", str(tmp_path / "run"), "--until", "align"), cwd=REPO, env=env,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    servers: list[int] = []

    def server_started() -> bool:
        servers[:] = [pid for pid, cmd in _children(proc.pid) if "uvicorn" in cmd]
        return bool(servers)

    try:
        _wait(server_started, 120, "the temporary Prefect server to start", proc)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    _wait(lambda: not os.path.exists(f"/proc/{servers[0]}") or _zombie(servers[0]), 30, "the server to exit")


def _zombie(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


@pytest.mark.slow
def test_local_dask_cluster(cli_env, tmp_path):
    log = make_log(tmp_path / "log", ("00", "01"), n_frames=5)
    root = tmp_path / "run"
    res = subprocess.run(
        cli("label", str(log), "--run", str(root), "--scans", "2", "--workers", "2", "--until", "align"),
        cwd=REPO, env=cli_env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    store = RunStore(root)
    for seq in ("00", "01"):
        assert store.read_manifest(seq, "align").status == "done"
        assert store.arrays(seq, P["align"].contract).done().all()


def test_describe_names_frames_over_labels_point_limit(synth_log, monkeypatch):
    """A frame over `dsnet label`'s default --max-points is named by `describe` with the option
    (the limit lowered here in place of a 10-million-point scan)."""
    from typer.testing import CliRunner

    from dsnet_core.io.semantickitti import SemanticKittiReader
    from flows.cli import app

    reader = SemanticKittiReader(synth_log)
    sizes = {r.frame_id: reader.scan(r).shape[0] for r in reader.frames("00")}
    frame, n = max(sizes.items(), key=lambda kv: kv[1])
    monkeypatch.setattr("tasks.ingest.MAX_POINTS", n)  # at the limit: nothing said
    res = CliRunner().invoke(app, ["describe", str(synth_log), "--sequences", "00"])
    assert res.exit_code == 0 and "--max-points" not in res.output, res.output
    monkeypatch.setattr("tasks.ingest.MAX_POINTS", n - 1)
    res = CliRunner().invoke(app, ["describe", str(synth_log), "--sequences", "00"])
    assert res.exit_code == 0, res.output
    want = (
        f"sequence 00: frame {frame} has {n} points, over `dsnet label`'s --max-points limit ({n - 1}): "
        "label refuses it (--max-points N raises the limit, about 1.3 GB of memory per million points; "
        "--on-error skip quarantines such frames)"
    )
    assert want in " ".join(res.output.split())  # rich wraps the line at the terminal width

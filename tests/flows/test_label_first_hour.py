"""What a new user meets at ``dsnet label`` (#33): bad input refused before any server starts, a
rerun with nothing to do answered from the manifests without one, a closing summary with the
scores, the dashboard and the next command, and progress counted in frames."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.flows.conftest import REPO, cli
from tests.model_helpers import make_checkpoint

SERVER_LINE = "starting a temporary Prefect server"
FAST_SHIFT = '{"kind": "dynamic_shift", "n_seeds": 300, "bandwidths": [0.2, 1.8, 3.4]}'


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}
    return {**env, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", **extra}


def _run(*args, cwd=REPO, **env) -> subprocess.CompletedProcess:
    return subprocess.run(cli(*map(str, args)), cwd=cwd, env=_env(**env), capture_output=True, text=True)


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["no-such-log", "--run", "r"], "no-such-log: no such file or folder"),
        (["LOG", "--run", "r", "--until", "bogus"], "unknown stage 'bogus'"),
        (["LOG", "--run", "r", "--scans", "0"], "--scans 0: Input should be greater than or equal to 1"),
        (["LOG", "--run", "r", "--device", "bogus"], "--device 'bogus': expected cpu, cuda or cuda:N"),
        (["LOG", "--run", "r", "--method", "bogus"], "unknown method 'bogus'"),
        (["LOG", "--run", "r", "--method", "most", "--tta", "2"], "--tta: not a setting of method most"),
        (["LOG", "--run", "r", "--checkpoint", "no-such-ckpt"], "no model card"),
    ],
)
def test_bad_input_is_one_line_before_any_server_starts(synth_log, tmp_path, args, said):
    args = [str(synth_log) if a == "LOG" else a for a in args]
    res = _run("label", *args, cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert said in res.stderr and res.stderr.count("\n") == 1, res.stderr
    assert SERVER_LINE not in res.stderr and not (tmp_path / "r").exists()


def test_a_rerun_with_nothing_to_do_needs_no_server_and_both_end_with_a_summary(
    prefect_api_url, synth_log, tmp_path
):
    ckpt = make_checkpoint(tmp_path / "ckpt")
    run = tmp_path / "runs" / "r1"
    args = ["label", synth_log, "--run", run, "--sequences", "00", "--scans", "1", "--checkpoint", ckpt]
    args += ["--clusterer", FAST_SHIFT]
    first = _run(*args, PREFECT_API_URL=prefect_api_url)
    assert first.returncode == 0, first.stderr[-2000:]
    lines = first.stdout.splitlines()
    assert "labelled 6 frames of 1 sequence(s) in" in lines[-5], lines
    assert lines[-4].startswith("  per stage: ingest ") and " infer " in lines[-4] and " score " in lines[-4]
    assert lines[-3].startswith("  scores (official, 6 frames): PQ ") and " LSTQ " in lines[-3]
    assert lines[-2] == f"  dashboard: {run}/dashboard.html"
    assert lines[-1] == f"  next: dsnet export {run} --out predictions   (dsnet status {run} for every stage)"

    again = _run(*args)  # no PREFECT_API_URL: a server would be a temporary one, announced
    assert again.returncode == 0, again.stderr[-2000:]
    assert SERVER_LINE not in again.stderr
    assert again.stdout.splitlines()[0].startswith(f"nothing to do: every stage of every sequence in {run}")
    assert again.stdout.splitlines()[1:] == lines[-3:]

    status = _run("status", run)  # the headline scores there too (#33.5)
    assert status.returncode == 0 and lines[-3].strip() in status.stdout.splitlines(), status.stdout

    # from another working directory, the log given relative to it, the run folder still takes
    # its own log (#33.3: the run records where the log is, not the path as typed)
    relative = os.path.relpath(synth_log, run.parent)
    moved = _run(*[{run: "r1", synth_log: relative}.get(a, a) for a in args], cwd=run.parent)
    assert moved.returncode == 0 and moved.stdout.startswith("nothing to do"), moved.stderr[-2000:]

    # "nothing to do" only where the report, the run config and every done flag are intact too:
    # a run that answers it rewrites none of them (found by tests/flows/test_fuzz.py)
    table = run / "tables" / "label_frames" / "part-0.parquet"
    data = bytearray(table.read_bytes())
    data[len(data) // 2] ^= 16  # same size: only its digest tells
    table.write_bytes(bytes(data))
    (run / "run.json").unlink()
    done = next((run / "sequences" / "00" / "refine" / "arrays.zarr" / "done" / "c").iterdir())
    flag = bytearray(done.read_bytes())
    flag[3] ^= 4
    done.write_bytes(bytes(flag))
    repaired = _run(*args, PREFECT_API_URL=prefect_api_url)
    assert repaired.returncode == 0 and not repaired.stdout.startswith("nothing to do"), repaired.stderr[
        -2000:
    ]
    assert "refine " in repaired.stdout.splitlines()[-4]  # the damaged item's stage ran again
    assert (run / "run.json").exists()
    verified = _run("status", run, "--verify")
    assert verified.returncode == 0 and "damaged" not in verified.stdout, verified.stdout


def test_progress_counts_items_as_blocks_run(synth_log, tmp_path):
    """Each item a block computes in this process is reported (the CLI's bars count frames)."""
    from storage.run import RunStore
    from tasks.methods import get_pipeline
    from tests.helpers.plain_runner import ITEM_LISTENERS, run_stage_plain

    seen: list[tuple[str, str]] = []
    pipeline = get_pipeline()
    run = {"data": str(synth_log), "options": {"block_size": 4}}
    store = RunStore(tmp_path / "run")
    store.write_run_config("r1", run)
    ITEM_LISTENERS.append(lambda seq, stage: seen.append((seq, stage)))
    try:
        for stage in ("ingest", "align"):
            run_stage_plain(store, pipeline, "00", stage, run, "r1")
    finally:
        ITEM_LISTENERS.clear()
    assert seen == [("00", "ingest")] * 6 + [("00", "align")] * 6


@pytest.mark.skipif(sys.platform != "linux", reason="the help is rendered alike everywhere; one check")
def test_label_help_groups_its_options_and_names_the_extra():
    res = _run("label", "--help", COLUMNS="80")
    assert res.returncode == 0
    for panel in ("Input", "Method", "Model", "Run", "Scale-out"):
        assert f"─ {panel} " in res.stdout, panel
    assert "[odometry] extra" in res.stdout  # not eaten as markup
    assert "``" not in _run("train", "dsnet", "--help", COLUMNS="80").stdout


def test_the_summary_of_a_store_without_scores_says_so(tmp_path):
    from flows.commands.label_report import run_report

    lines = run_report(str(tmp_path / "nothing"), [], 0.1)
    assert lines[0].startswith("nothing to do") and lines[1].startswith("  no ground truth scored")
    assert Path(tmp_path / "nothing").exists() is False

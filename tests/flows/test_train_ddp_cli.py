"""``dsnet train`` under a real ``torchrun`` with two gloo processes: SIGKILL of the whole job (the
launcher and both ranks) after the first epoch's checkpoint, then ``--resume`` ends with the weights
of an uninterrupted two-process run, byte for byte."""

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.helpers.tiny_log import write_tiny_log

REPO = Path(__file__).resolve().parents[2]
SCHEDULE = {"semantic": 3, "offset": 1, "shift": 1}


def ddp_train(log: Path, out: Path, *extra) -> tuple[list[str], dict[str, str]]:
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2"]
    cmd += ["-m", "flows.cli", "train", "dsnet", str(log), "--out", str(out), "--stage", "all"]
    cmd += ["--epochs", ",".join(f"{k}={v}" for k, v in SCHEDULE.items()), "--grid", "24,32,8"]
    cmd += ["--lr", "0.01", *map(str, extra)]  # augmentation on: per-rank draws must resume too
    return cmd, {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}


def epochs_done(ckpt: Path) -> int:
    try:
        return sum(json.loads((ckpt / "card.json").read_text())["epochs"].values())
    except (FileNotFoundError, json.JSONDecodeError):
        return 0


def descendants(pid: int) -> list[int]:
    """Processes below ``pid`` (torchrun starts each rank in a session of its own, so a process
    group kill would miss them)."""
    parents: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            parents.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], [pid]
    while todo:
        children = parents.get(todo.pop(), [])
        out += children
        todo += children
    return out


def weights(ckpt: Path) -> dict[str, bytes]:
    return {name: (ckpt / name).read_bytes() for name in ("model.safetensors", "shift.safetensors")}


@pytest.mark.slow
@pytest.mark.timeout(900)
@pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="finds the ranks through /proc")
def test_killed_two_process_run_resumes_to_the_uninterrupted_weights(tmp_path):
    log = write_tiny_log(tmp_path / "log", frames=3)
    straight, ckpt = tmp_path / "straight", tmp_path / "killed"
    cmd, env = ddp_train(log, straight)
    done = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.count("wrote checkpoint") == 1  # the final lines from rank 0 only

    cmd, env = ddp_train(log, ckpt)
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.time() + 600
    while epochs_done(ckpt) < 1 and proc.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    ranks = descendants(proc.pid)
    assert proc.poll() is None and len(ranks) >= 2, proc.communicate()[1].decode()[-3000:]
    for pid in [proc.pid, *ranks]:  # the launcher first, so that it does not react to the ranks
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    proc.communicate(timeout=60)
    killed = json.loads((ckpt / "card.json").read_text())
    assert 1 <= sum(killed["epochs"].values()) < sum(SCHEDULE.values())

    cmd, env = ddp_train(log, ckpt, "--resume")
    resumed = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert f"resuming from {ckpt}" in resumed.stderr
    card = json.loads((ckpt / "card.json").read_text())
    assert card["epochs"] == SCHEDULE and card["training_data"]["train_config"]["world_size"] == 2
    assert weights(ckpt) == weights(straight)
    expected = json.loads((straight / "card.json").read_text())["metrics"]
    strip = [{k: v for k, v in m.items() if k != "seconds"} for m in card["metrics"]]
    assert strip == [{k: v for k, v in m.items() if k != "seconds"} for m in expected]

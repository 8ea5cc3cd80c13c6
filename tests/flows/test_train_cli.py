"""``dsnet train`` as a real subprocess: SIGKILL mid-training, then --resume continues."""

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


def cli(*args):
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    return [sys.executable, "-m", "flows.cli", "train", *map(str, args)], env


def epochs_done(ckpt: Path) -> int:
    try:
        return json.loads((ckpt / "card.json").read_text())["epochs"].get("semantic", 0)
    except (FileNotFoundError, json.JSONDecodeError):
        return 0


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_sigkill_then_resume(tmp_path):
    log = write_tiny_log(tmp_path / "log", frames=2)
    ckpt = tmp_path / "ckpt"
    common = ["--out", ckpt, "--stage", "semantic", "--epochs", "semantic=4", "--grid", "24,32,8"]
    common += ["--no-augment", "--lr", "0.01"]
    cmd, env = cli(log, *common)
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.time() + 600
    while epochs_done(ckpt) < 1 and proc.poll() is None and time.time() < deadline:
        time.sleep(0.2)
    assert proc.poll() is None, proc.communicate()[1].decode()[-2000:]
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL
    killed_card = json.loads((ckpt / "card.json").read_text())
    done = killed_card["epochs"]["semantic"]
    assert 1 <= done < 4

    # without --resume the existing checkpoint is refused
    cmd, env = cli(log, *common)
    refused = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True)
    assert refused.returncode == 2 and "already holds a checkpoint: pass --resume" in refused.stderr

    cmd, env = cli(log, *common, "--resume")
    resumed = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert "wrote checkpoint" in resumed.stdout and f"resuming from {ckpt}" in resumed.stderr
    card = json.loads((ckpt / "card.json").read_text())
    assert card["epochs"] == {"semantic": 4}
    # the epochs before the kill are kept as they were; training continued after them
    assert card["metrics"][:done] == killed_card["metrics"]
    assert [m["epoch"] for m in card["metrics"]] == [1, 2, 3, 4]
    rows = (ckpt / "metrics.csv").read_text().splitlines()
    assert len(rows) == 5


def _train_files(ckpt: Path) -> dict[str, bytes]:
    return {name: (ckpt / name).read_bytes() for name in ("model.safetensors", "shift.safetensors")}


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_kills_at_random_moments_resume_to_bit_identical_weights(tmp_path):
    """Three SIGKILLs at seeded random moments across all three stages (semantic, offset, shift),
    each followed by --resume: the final weights equal an uninterrupted run's, byte for byte."""
    import random

    log = write_tiny_log(tmp_path / "log", frames=2)
    common = ["--stage", "all", "--epochs", "semantic=3,offset=2,shift=2", "--grid", "24,32,8"]
    common += ["--lr", "0.01"]
    straight = tmp_path / "straight"
    cmd, env = cli(log, "--out", straight, *common)
    t0 = time.monotonic()
    res = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=900)
    total = time.monotonic() - t0
    assert res.returncode == 0, res.stderr[-2000:]

    ckpt = tmp_path / "killed"
    rng = random.Random(20)
    kills = 0
    for attempt in range(3):
        args = ["--out", ckpt, *common, *(["--resume"] if attempt else [])]
        cmd, env = cli(log, *args)
        proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            proc.wait(timeout=rng.uniform(0.2, 0.9) * total)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGKILL)
            kills += 1
        proc.communicate(timeout=600)
    cmd, env = cli(log, "--out", ckpt, *common, "--resume")
    resumed = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=900)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert kills >= 1
    assert _train_files(ckpt) == _train_files(straight)

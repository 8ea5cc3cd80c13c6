"""Every method's trainer on the shared skeleton resumes a SIGKILL to the weights an uninterrupted
run ends with, byte for byte (DS-Net's is ``test_train_cli.py``; here MOST and D-PLS, which had no
commit log before the skeleton)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.helpers.tiny_log import write_tiny_log
from tests.model_helpers import TEST_CONFIG, make_checkpoint

REPO = Path(__file__).resolve().parents[2]
GRID = ",".join(str(c) for c in TEST_CONFIG.grid.size)


def _cmd(method: str, *args) -> tuple[list[str], dict]:
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    return [sys.executable, "-m", "flows.cli", "train", method, *map(str, args)], env


def _committed(ckpt: Path) -> int:
    """Epochs over all stages that a resume would find (a committed, not yet moved epoch counts)."""
    for card in (ckpt / ".pending" / "card.json", ckpt / "card.json"):
        if card.is_file() and (card.parent == ckpt or (ckpt / ".pending" / "COMMIT").is_file()):
            try:
                return sum(json.loads(card.read_text())["epochs"].values())
            except (json.JSONDecodeError, KeyError):
                return 0
    return 0


def _weights(ckpt: Path) -> bytes:
    return (ckpt / "model.safetensors").read_bytes()


CASES = {
    "most": lambda tmp: ["--epochs", "detect=2,member=2", "--scans", "2", "--grid", GRID],
    "dpls": lambda tmp: ["--epochs", "4", "--init-from", make_checkpoint(tmp / "parent", seed=3)],
}


@pytest.mark.slow
@pytest.mark.timeout(1200)
@pytest.mark.parametrize("method", sorted(CASES))
def test_a_killed_training_resumes_to_the_uninterrupted_weights(method, tmp_path):
    log = write_tiny_log(tmp_path / "log", frames=3, n=1500)
    common = [log, *CASES[method](tmp_path), "--lr", "0.01", "--no-augment"]
    straight = tmp_path / "straight"
    cmd, env = _cmd(method, *common, "--out", straight)
    done = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    total = sum(json.loads((straight / "card.json").read_text())["epochs"].values())

    killed = tmp_path / "killed"
    cmd, env = _cmd(method, *common, "--out", killed)
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 600
    while _committed(killed) < 1 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert proc.poll() is None, f"the run ended before the kill: {proc.stderr.read().decode()[-2000:]}"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    landed = _committed(killed)
    assert 1 <= landed < total

    cmd, env = _cmd(method, *common, "--out", killed, "--resume")
    resumed = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=900)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert sum(json.loads((killed / "card.json").read_text())["epochs"].values()) == total
    assert _weights(killed) == _weights(straight)

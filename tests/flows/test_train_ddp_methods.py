"""``dsnet train most|dpls`` under a real ``torchrun`` with two gloo processes: data-parallel through
the trainer skeleton alone (sharded epochs, DDP-averaged gradients, rank 0 writes). A two-process
run stopped after its first stage (or epoch) and resumed ends with the weights of an uninterrupted
two-process run, byte for byte; the card records the two processes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers.tiny_log import write_tiny_log
from tests.model_helpers import TEST_CONFIG, make_checkpoint

REPO = Path(__file__).resolve().parents[2]
GRID = ",".join(str(c) for c in TEST_CONFIG.grid.size)
CASES = {  # (common flags, the epochs of the first part, the epochs in all)
    "most": (lambda tmp: ["--scans", "2", "--grid", GRID], "detect=1", "detect=1,member=1"),
    "dpls": (lambda tmp: ["--init-from", make_checkpoint(tmp / "parent", seed=3)], "1", "2"),
}


def torchrun(method: str, *args) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2"]
    cmd += ["-m", "flows.cli", "train", method, *map(str, args)]
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    return subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)


@pytest.mark.slow
@pytest.mark.timeout(1200)
@pytest.mark.parametrize("method", sorted(CASES))
def test_two_process_training_resumes_to_the_uninterrupted_weights(method, tmp_path):
    log = write_tiny_log(tmp_path / "log", frames=4, n=1500)
    flags, first, total = CASES[method]
    common = [log, *flags(tmp_path), "--lr", "0.01", "--no-augment"]
    straight, parted = tmp_path / "straight", tmp_path / "parted"
    done = torchrun(method, *common, "--epochs", total, "--out", straight)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.count("checkpoint") == 1  # the final line from rank 0 only
    part = torchrun(method, *common, "--epochs", first, "--out", parted)
    assert part.returncode == 0, part.stderr[-3000:]
    rest = torchrun(method, *common, "--epochs", total, "--out", parted, "--resume")
    assert rest.returncode == 0, rest.stderr[-3000:]
    card = json.loads((parted / "card.json").read_text())
    assert card["training_data"]["train_config"]["world_size"] == 2
    assert card["epochs"] == json.loads((straight / "card.json").read_text())["epochs"]
    assert (parted / "model.safetensors").read_bytes() == (straight / "model.safetensors").read_bytes()

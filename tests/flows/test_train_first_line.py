"""Issue 40: `dsnet train most L --preset reference` printed nothing for minutes while its first
(CPU-slow, width-32) step ran. Now every trainer on the skeleton logs what it trains before its
first step (trainer, device, width, parameters, steps per epoch), and the command's progress bar is
shown at ``0/steps`` before that step (the callback's ``start``). A tiny preset here: the reference
preset is never trained in tests."""

from __future__ import annotations

import logging
import os
import subprocess
import sys

import pytest

from tests.helpers.tiny_log import write_tiny_log

FAST = ["--preset", "tiny", "--grid", "24,32,8", "--scans", "2", "--threads", "1", "--no-augment"]


class Recorder:
    """A step callback with ``start``: records both, in order, and the log as the first step ends."""

    def __init__(self, caplog) -> None:
        self.calls: list[tuple] = []
        self.caplog, self.log_at_first_step = caplog, None

    def start(self, stage: str, epoch: int, steps: int) -> None:
        self.calls.append(("start", stage, epoch, steps))

    def __call__(self, stage: str, epoch: int, step: int, total: int, loss: float) -> None:
        if self.log_at_first_step is None:
            self.log_at_first_step = [r.getMessage() for r in self.caplog.records]
        self.calls.append(("step", stage, epoch, step, total))


def test_training_says_what_it_trains_before_its_first_step(tmp_path, caplog):
    from tasks.methods import get_method

    method = get_method("most")
    log = write_tiny_log(tmp_path / "log", frames=2)
    options = method.TrainOptions(
        data=log, out=tmp_path / "ck", epochs="detect=1", preset="tiny", grid="24,32,8", scans=2,
        threads=1, augment=False,
    )  # fmt: skip
    bars = Recorder(caplog)
    with caplog.at_level(logging.INFO, logger="dsnet_core.train.skeleton"):
        method.train(options, bars)
    steps = [c for c in bars.calls if c[0] == "step" and c[1] == "detect"]
    assert bars.calls[0] == ("start", "detect", 1, steps[0][4]) and steps[0][3] == 1
    first = [m for m in bars.log_at_first_step if m.startswith("training ")]
    assert len(first) == 1, bars.log_at_first_step
    assert first[0].startswith("training MostTrainer on cpu: width ")
    assert f"detect epoch 1 of 1: {steps[0][4]} steps per epoch (batch 1)" in first[0]


@pytest.mark.timeout(300)
def test_the_first_line_comes_before_the_first_epoch_ends(tmp_path):
    """Through the command, as a user sees it (stderr of a subprocess)."""
    log = write_tiny_log(tmp_path / "log", frames=2)
    repo = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    env = {**os.environ, "PYTHONPATH": repo, "OMP_NUM_THREADS": "1"}
    args = ["train", "most", str(log), "--out", str(tmp_path / "ck"), "--epochs", "detect=1", *FAST]
    res = subprocess.run(
        [sys.executable, "-m", "flows.cli", *args], cwd=repo, env=env, capture_output=True, text=True,
        timeout=280,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    lines = res.stderr.splitlines()
    first = next(i for i, ln in enumerate(lines) if " INFO training MostTrainer on cpu: width " in ln)
    ended = next(i for i, ln in enumerate(lines) if "detect epoch 1:" in ln)
    assert first < ended and "steps per epoch" in lines[first]

"""``dsnet train most``: the two stages from the command line, resumed stage by stage,
the MOST card, and DS-Net-only flags refused by name."""

from __future__ import annotations

import json

import pytest
import torch
from typer.testing import CliRunner

from flows.cli import app
from tests.helpers.tiny_log import write_tiny_log

FAST = ["--preset", "tiny", "--grid", "24,32,8", "--scans", "2", "--threads", "1", "--no-augment"]


@pytest.fixture(autouse=True)
def one_thread():
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


def test_train_most_detect_then_member_resumed(tmp_path):
    log = write_tiny_log(tmp_path / "log", frames=3)
    out = tmp_path / "most"
    runner = CliRunner()
    res = runner.invoke(app, ["train", "most", str(log), "--out", str(out), "--epochs", "detect=1", *FAST])
    assert res.exit_code == 0, res.output
    card = json.loads((out / "card.json").read_text())
    assert card["format"] == "most-checkpoint/1" and card["epochs"] == {"detect": 1}
    assert card["training_data"]["train_config"]["scans"] == 2
    assert card["architecture"]["backbone"]["grid"]["size"] == [24, 32, 8]
    again = ["train", "most", str(log), "--out", str(out), "--epochs", "detect=1,member=1", *FAST]
    res = runner.invoke(app, again)
    assert res.exit_code == 2 and "already holds a checkpoint" in res.output
    res = runner.invoke(app, [*again, "--resume"])
    assert res.exit_code == 0, res.output
    card = json.loads((out / "card.json").read_text())
    assert card["epochs"] == {"detect": 1, "member": 1}
    assert [m["stage"] for m in card["metrics"]] == ["detect", "member"] and "val_member_acc" in card[
        "metrics"
    ][-1]
    assert "wrote MOST checkpoint" in res.output


def test_train_most_refuses_dsnet_flags(tmp_path):
    res = CliRunner().invoke(
        app,
        ["train", "most", "x", "--out", str(tmp_path / "o"), "--amp", "bf16", "--patience", "2"],
    )
    assert res.exit_code == 2 and "No such option: --amp" in res.output  # only MOST's own options exist


def test_train_most_refuses_torchrun(tmp_path, monkeypatch):
    monkeypatch.setenv("WORLD_SIZE", "2")  # as torchrun sets it: MOST's trainer is single-process
    res = CliRunner().invoke(app, ["train", "most", "x", "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "most trains in one process" in res.output
    assert not (tmp_path / "o").exists()

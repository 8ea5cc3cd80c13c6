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
    # --amp is the trainer skeleton's (every method has it); --patience is DS-Net's own
    assert res.exit_code == 2 and "No such option: --patience" in res.output


def test_the_step_options_are_every_trainers(tmp_path):
    """The skeleton's step options come to ``dsnet train most`` and ``dpls`` as to ``dsnet``,
    generated from the same fields, and become the trainer config's fields of the same names."""
    from dsnet_core.train.most import MostTrainConfig
    from dsnet_core.train.skeleton import StepConfig, config_from
    from tasks.methods import METHODS

    for method in METHODS.values():
        res = CliRunner().invoke(app, ["train", method.name, "--help"], terminal_width=200)
        assert res.exit_code == 0
        for flag in ("--amp", "--batch-size", "--grad-clip", "--schedule"):
            assert flag in res.output, (method.name, flag)
    options = METHODS["most"].TrainOptions(out=tmp_path, amp="bf16", batch_size=2, grad_clip=1.5)
    cfg = config_from(MostTrainConfig, options.model_dump(), epochs={"detect": 1, "member": 0})
    assert StepConfig.of(cfg) == StepConfig(batch_size=2, amp="bf16", grad_clip=1.5)
    assert (cfg.scans, cfg.seed, cfg.epochs) == (3, 0, {"detect": 1, "member": 0})


def test_a_single_process_method_refuses_torchrun(tmp_path, monkeypatch):
    from tasks.methods import METHODS

    monkeypatch.setattr(type(METHODS["most"]), "data_parallel", False)  # a method without DDP
    monkeypatch.setenv("WORLD_SIZE", "2")  # as torchrun sets it
    res = CliRunner().invoke(app, ["train", "most", "x", "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "most trains in one process" in res.output
    assert not (tmp_path / "o").exists()
